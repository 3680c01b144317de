"""``localize run``: track one session with the map-aware particle filter.

::

    localize run SESSION [--map MAP] [--mode gnss|inertial|fused] [--particles N]
                 [--jaywalk-weight W] [--seed S] [--save-particles]
                 [--velocity-source auto|file|ronin|pdr] [--no-start-pose] -o OUT

``SESSION`` is anything :func:`curbside.localize.readers.read_any` reads (a SPEC folder, a Sensor
Logger export, ``FILE.h5::TRIAL``, a GPX file). Writes ``OUT/track.csv``, ``OUT/track.geojson``,
``OUT/run.json`` and, with ``--save-particles``, ``OUT/particles.npz``; ``OUT`` appears complete or
not at all. A one-line summary goes to stdout.
"""

from __future__ import annotations

import argparse
import logging

from curbside import settings
from curbside.cli.common import positive_int, unit_interval
from curbside.localize.pipeline import MODES, VELOCITY_SOURCES, track_session
from curbside.localize.readers import read_any
from curbside.localize.track import write_track
from curbside.osmseg.mapio import read_map

logger = logging.getLogger(__name__)


def _run(args: argparse.Namespace) -> int:
    session = read_any(args.session)
    layers = read_map(args.map) if args.map else None
    result = track_session(
        session,
        layers,
        args.mode,
        particles=args.particles,
        jaywalk_weight=args.jaywalk_weight,
        seed=args.seed,
        velocity_source=args.velocity_source,
        use_start_pose=not args.no_start_pose,
        save_particles=args.save_particles,
    )
    run_info = {
        "session": str(args.session),
        "map": str(args.map) if args.map else None,
        "seed": args.seed,
        "particles": args.particles,
        "jaywalk_weight": args.jaywalk_weight,
    }
    write_track(result, args.output, run_info)
    track = result.track
    span = track["t"].iat[-1] - track["t"].iat[0] if len(track) else 0.0
    print(
        f"{args.output}: {len(track)} footsteps over {span:.1f} s, mode {args.mode}, "
        f"velocity {result.velocity_source or '-'}, steps {result.step_source}, "
        f"{result.recoveries} recoveries"
    )
    return 0


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add ``run`` to the ``localize`` sub-commands."""
    parser = subparsers.add_parser(
        "run",
        help="track one session (GNSS only, inertial + map, or fused) and write the track",
        description="Track one session with the map-aware particle filter; writes OUT/track.csv, "
        "OUT/track.geojson and OUT/run.json (and OUT/particles.npz with --save-particles).",
    )
    parser.add_argument("session", help="session folder, Sensor Logger export, FILE.h5::TRIAL or .gpx")
    parser.add_argument("--map", help="map layers GeoJSON (osmseg build); none: no map likelihood")
    parser.add_argument("--mode", choices=MODES, default="fused", help="method (default: fused)")
    parser.add_argument("--particles", type=positive_int, default=settings.default_particles,
                        help=f"number of particles (default {settings.default_particles})")
    parser.add_argument("--jaywalk-weight", type=unit_interval, default=settings.default_jaywalk_weight,
                        help=f"particle weight on street surface (default {settings.default_jaywalk_weight})")
    parser.add_argument("--seed", type=int, default=0, help="random seed (default 0): same seed, same track")
    parser.add_argument("--save-particles", action="store_true", help="also write OUT/particles.npz")
    parser.add_argument("--velocity-source", choices=VELOCITY_SOURCES, default="auto",
                        help="auto: velocity.csv, else RoNIN on imu.csv, else PDR")
    parser.add_argument("--no-start-pose", action="store_true",
                        help="ignore meta.json's start pose; start from the first usable GNSS fix")
    parser.add_argument("-o", "--output", required=True, help="output folder (replaced if it exists)")
    parser.set_defaults(func=_run)
