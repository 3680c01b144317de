"""``localize run``: track one session with the map-aware particle filter.

::

    localize run SESSION [--map MAP] [--mode gnss|inertial|paper|fused] [--particles N]
                 [--jaywalk-weight W] [--seed S] [--set KEY=VALUE ...] [--save-particles]
                 [--lag-s SECONDS] [--velocity-source auto|file|ronin|pdr] [--ronin-weights PT]
                 [--unseen-velocity [on|auto|off]] [--no-start-pose] [--platform P] -o OUT
    localize run --config OUT/run.json -o OUT2          # replay a run exactly

``SESSION`` is anything :func:`curbside.localize.readers.read_any` reads (a SPEC folder, a Sensor
Logger export, ``FILE.h5::TRIAL``, a GPX file). Writes ``OUT/track.csv``, ``OUT/track.geojson``,
``OUT/run.json`` (every parameter) and, with ``--save-particles``, ``OUT/particles.npz``; ``OUT`` appears
complete or not at all. ``--lag-s`` adds the fixed-lag smoother's positions (``smooth_lat, smooth_lon``)
for offline analysis. ``--ronin-weights`` runs RoNIN with other weights than the bundled ones (refused
where the run would not use them). A one-line summary goes to stdout.
"""

from __future__ import annotations

import argparse
import json
import logging
from pathlib import Path
from typing import TYPE_CHECKING

from curbside.cli.common import (
    add_config_options,
    config_overrides,
    non_negative_float,
    positive_int,
    seed,
    set_overrides,
    unit_interval,
)
from curbside.cli.localize_convert import add_platform_option
from curbside.cli.run_replay import (
    add_weights,
    check_replayed_inputs,
    check_replayed_paths,
    input_record,
    recorded_weights,
    replay_config,
)
from curbside.errors import CurbsideInputError
from curbside.localize.runconstants import MODES, VELOCITY_SOURCES

if TYPE_CHECKING:
    import pandas as pd

    from curbside.localize.ronin.model import RoninResNet
    from curbside.localize.runconfig import RunConfig
    from curbside.localize.session import Session
    from curbside.localize.track_result import TrackResult

logger = logging.getLogger(__name__)


def _replayed_info(path: str) -> dict:
    """``run.json``'s contents, checked to hold a ``config`` object."""
    try:
        info = json.loads(Path(path).read_text(encoding="utf-8"))
    except OSError as exc:
        raise CurbsideInputError(path, f"cannot read ({exc.strerror or exc})") from None
    except json.JSONDecodeError as exc:
        raise CurbsideInputError(path, f"not JSON ({exc.msg} at line {exc.lineno})") from None
    if not isinstance(info, dict) or not isinstance(info.get("config"), dict):
        raise CurbsideInputError(path, "not a run.json of localize run (no 'config' object)")
    return info


def _checked_inputs(args: argparse.Namespace) -> tuple[dict, str, str | None]:
    """The replayed ``run.json`` (``{}`` without ``--config``), the session and the map, after the checks
    that need no heavy import: the output folder, then each input's path."""
    from curbside.io import check_output_folder
    from curbside.localize.paths import check_ronin_weights_path, check_source_path
    from curbside.osmseg.inputs import check_map_file

    check_output_folder(args.output, args.overwrite, "localize run")
    info = _replayed_info(args.config) if args.config else {}
    _check_options_used(args, info["config"] if info else {})
    session_path = args.session or info.get("session")
    if not session_path:
        raise CurbsideInputError(
            "localize run", "give a SESSION (or --config with a run.json that names one)"
        )
    map_path = args.map if args.map is not None else info.get("map")
    if args.config:
        check_replayed_paths(info, args.config, session_path, map_path)
    check_source_path(session_path)
    if map_path:
        check_map_file(map_path)
    if args.ronin_weights:
        check_ronin_weights_path(args.ronin_weights)
    return info, session_path, map_path


def _given_mode(args: argparse.Namespace, section: str, replayed: dict) -> tuple[str | None, bool]:
    """The mode of ``unseen_velocity`` or ``familiar_velocity`` (``section``) that the run is given (its
    flag, else ``--set SECTION.mode``, else the replayed configuration's; ``None``: the method's
    default), and whether this command line gives it."""
    recorded = replayed.get(section)
    recorded = recorded.get("mode") if isinstance(recorded, dict) else None
    here = getattr(args, section) or set_overrides(args.set).get(f"{section}.mode")
    return here or recorded, here is not None


def _check_options_used(args: argparse.Namespace, replayed: dict) -> None:
    """Refuse options that would change nothing, before the heavy imports: the filter's options with
    ``--mode gnss`` (no particle filter, no inertial velocity), ``--fix-lag`` with ``--mode inertial`` (no
    fixes), ``--familiar-velocity`` beside ``--unseen-velocity on`` (whose motion model replaces the calm
    one from the start). ``--save-particles`` with ``--mode gnss`` is warned of only: a script that tracks
    a walk in every mode gives it to each (``benchmarks/bench_view.py``). ``replayed``: the ``config`` of
    the run.json ``--config`` replays (``{}``: none).

    Raises
    ------
    CurbsideInputError
        One of these combinations, naming the options and why they do nothing.
    """
    mode = args.mode or replayed.get("mode") or "fused"
    if mode == "gnss" and args.save_particles:  # warned, not refused: scripts give it to every mode
        logger.warning("--save-particles: no particles.npz: --mode gnss runs no particle filter")
    fix_lag = (args.fix_lag or {}).get("fix_lag.mode", "off")
    unused = {
        "--lag-s": bool(args.lag_s),
        "--unseen-velocity": args.unseen_velocity not in (None, "off"),
        "--familiar-velocity": args.familiar_velocity not in (None, "off"),
        "--fix-lag": fix_lag != "off", "--velocity-source": args.velocity_source is not None,
    }
    if mode == "gnss" and any(unused.values()):
        names = [name for name, given in unused.items() if given]
        them = "them" if len(names) > 1 else "it"
        raise CurbsideInputError(
            ", ".join(names), "not used: --mode gnss reports the fixes as they are, with no particle filter "
            f"and no inertial velocity; drop {them}, or choose --mode inertial, paper or fused"
        )
    if mode == "inertial" and fix_lag != "off":
        raise CurbsideInputError("--fix-lag", "not used: --mode inertial tracks without GNSS fixes; drop it, "
                                              "or choose --mode paper or fused")
    (unseen, unseen_here), (familiar, familiar_here) = (
        _given_mode(args, section, replayed) for section in ("unseen_velocity", "familiar_velocity"))
    if (unseen_here or familiar_here) and unseen == "on" and familiar not in (None, "off"):
        raise CurbsideInputError(
            f"--familiar-velocity {familiar}", "not used with --unseen-velocity on: the motion model for a "
            "velocity model new to the phone replaces the calm one from the start; give one of them"
        )


def _run(args: argparse.Namespace) -> int:
    info, session_path, map_path = _checked_inputs(args)
    # the heavy imports, once the cheap checks passed
    from curbside.localize.pipeline import track_session
    from curbside.localize.readers import read_any
    from curbside.localize.runconfig import RunConfig
    from curbside.localize.track import write_track
    from curbside.osmseg.mapio import read_map

    config = None
    if args.config:
        config = RunConfig.from_dict(info["config"], f"{args.config}: config")
        config = replay_config(info, config, args.config, args.mode, args.velocity_source)
    config = _configured(args, config)
    weights = _ronin_weights(args, info, config)
    inputs = input_record(session_path, map_path)
    if args.config:
        check_replayed_inputs(info, args.config, map_path, inputs, weights)
    model = _load_weights(weights)
    platform = args.platform or _replayed_platform(info, session_path)
    session = read_any(session_path, platform=platform)
    _check_weights_used(args, config, session)
    layers = read_map(map_path) if map_path else None
    save_particles = args.save_particles or bool(info.get("save_particles"))
    # The clouds go to disk beside the output as the walk goes, not into memory (nor /tmp, maybe a RAM disk).
    result = track_session(session, layers, config=config, save_particles=save_particles, progress=True,
                           map_name=str(map_path) if map_path else None, ronin_weights=model,
                           spill_dir=args.output)
    run_info = {"session": _absolute(session_path), "map": _absolute(map_path) if map_path else None,
                "save_particles": save_particles,
                "inputs": add_weights(inputs, result.velocity_source, weights)}
    if platform:
        run_info["platform"] = platform
    summary = None
    if session.waypoints is not None:
        run_info["waypoint_error"], scored = _waypoint_score(
            result.track, session.waypoints, session.file_source("waypoints.csv")
        )
        summary = run_info["waypoint_error"] if scored else None
    write_track(result, args.output, run_info, overwrite=args.overwrite)
    _print_summary(args.output, result, summary)
    return 0


def _replayed_platform(info: dict, session_path: str) -> str | None:
    """The ``--platform`` a replayed ``run.json`` records, for a Sensor Logger session only: its
    configuration may be replayed on a session of another format, which takes no platform."""
    from curbside.localize.readers import detect_format

    platform = info.get("platform")
    if platform and detect_format(session_path) != "sensorlogger":
        logger.info("%s is not a Sensor Logger export: the replayed --platform %s does not apply",
                    session_path, platform)
        return None
    return platform


def _configured(args: argparse.Namespace, config: RunConfig | None) -> RunConfig:
    """The run's configuration: the replayed one (or the mode's), with the options given."""
    from curbside.localize.pipeline import resolve_config

    mode = args.mode if (args.mode or config is not None) else "fused"
    config = resolve_config(
        config,
        mode,
        particles=args.particles,
        jaywalk_weight=args.jaywalk_weight,
        seed=args.seed,
        velocity_source=args.velocity_source,
        use_start_pose=False if args.no_start_pose else None,
    )
    config = config.with_overrides(config_overrides(args))
    if args.lag_s is not None:
        config = config.with_overrides({"filter.smoother.lag_s": args.lag_s})
    return config


def _ronin_weights(args: argparse.Namespace, info: dict, config: RunConfig) -> str | None:
    """The RoNIN weights the run would use (``None``: the bundled ones): ``--ronin-weights``, else in a
    replay those the run recorded.

    Raises
    ------
    CurbsideInputError
        ``--ronin-weights`` where the method or the velocity source uses no RoNIN; recorded weights that
        are gone when the replay runs RoNIN.
    """
    source = config.engine.velocity_source
    uses_ronin = config.mode != "gnss" and source in ("auto", "ronin")
    if args.ronin_weights and not uses_ronin:
        why = ("--mode gnss tracks without inertial velocity" if config.mode == "gnss" else
               f"the velocity comes from {'velocity.csv' if source == 'file' else 'PDR'} (velocity source "
               f"{source}); give --velocity-source ronin or auto")
        raise CurbsideInputError("--ronin-weights", f"not used: {why}")
    if args.ronin_weights:
        return args.ronin_weights
    return recorded_weights(info, args.config) if args.config and uses_ronin else None


def _load_weights(weights: str | None) -> RoninResNet | None:
    """The loaded RoNIN model of ``weights`` (``None``: the bundled one, loaded when RoNIN runs): a bad
    file fails now, before the session is read."""
    if weights is None:
        return None
    from curbside.localize.ronin.infer import load_model

    return load_model(weights)


def _check_weights_used(args: argparse.Namespace, config: RunConfig, session: Session) -> None:
    """Refuse ``--ronin-weights`` on a session whose ``velocity.csv``, or whose simulated IMU's PDR (see
    :func:`~curbside.localize.session.warn_if_simulated_imu`), the ``auto`` source would use."""
    if not args.ronin_weights or config.engine.velocity_source != "auto":
        return
    if session.velocity is not None:
        raise CurbsideInputError(
            "--ronin-weights", f"not used: {session.file_source('velocity.csv')} is the velocity under "
            "--velocity-source auto; give --velocity-source ronin to run RoNIN on imu.csv"
        )
    if session.simulated:
        raise CurbsideInputError(
            "--ronin-weights", f"not used: {session.file_source('imu.csv')} is simulated, so "
            "--velocity-source auto tracks with PDR; give --velocity-source ronin to run RoNIN on it anyway"
        )


def _print_summary(output: str, result: TrackResult, summary: dict | None) -> None:
    """What the run did, in a few lines: updates, motion models, fix lag, soft walls, waypoint error."""
    from curbside.evaluate.metrics import format_waypoint_summary

    track = result.track
    span = track["t"].iat[-1] - track["t"].iat[0] if len(track) else 0.0
    print(
        f"{output}: {len(track)} updates over {span:.1f} s, mode {result.mode}, "
        f"velocity {result.velocity_source or '-'}, steps {result.step_source}, "
        f"{result.recoveries} recoveries"
        + (f", {result.heading_corrections} heading corrections" if result.heading_corrections else "")
    )
    if result.unseen_velocity_from_s is not None and result.mode != "gnss":
        print(
            f"{output}: from t = {result.unseen_velocity_from_s:.1f} s, the motion model for a velocity "
            "model new to the phone or the place (--unseen-velocity)"
        )
    familiar = result.familiar_velocity
    if familiar is not None and familiar["verdict"] != "not familiar":
        share = float((track["motion"] == "familiar").mean()) if len(track) else 0.0
        change = 100 * (familiar["median_speed_change"] or 0.0)
        window = result.config.familiar_velocity.window_s
        print(
            f"{output}: the velocity's speed changes by {change:.1f} % from one {window:g} s window to "
            f"the next ({familiar['samples']} samples, {familiar['verdict']}): "
            f"{100 * share:.0f} % of the track follows the calm motion model (--familiar-velocity)"
        )
    known = result.ronin_familiarity
    if known is not None and known["familiar"] is not None:
        advice = "" if known["familiar"] else ": its heading and speed may be off; consider --unseen-velocity"
        print(f"{output}: the RoNIN model {'knows' if known['familiar'] else 'does not know'} this recording "
              f"(yaw-equivariance spread {known['spread_mps']:.3f} m/s while walking; unfamiliar above "
              f"{known['unfamiliar_above_mps']:g}){advice}")
    lag = result.fix_lag
    if lag is not None and lag["lag_s"] > 0:
        how = "estimated from the recording" if lag["mode"] == "auto" else "fix_lag.lag_s"
        print(
            f"{output}: the fixes trail the walker by a {lag['lag_s']:g} s lag ({how}): each fix "
            "is moved forward by the inertial motion that lag holds back (fix_lag.*)"
        )
    elif lag is not None and lag["mode"] == "auto":
        print(f"{output}: the fixes do not trail the walker (lag estimated from the recording: 0 s); "
              "they are used as they are")
    configured = result.config.filter.map.wall_tolerance_m
    softer = result.wall_tolerance_m is not None and result.wall_tolerance_m > configured
    if softer or result.walkable_first:
        overlap = (
            "its sidewalks and crosswalks count where they overlap, and " if result.walkable_first else ""
        )
        print(
            f"{output}: the map's buildings stand on part of its sidewalks (another source or year "
            f"than its streets, or misaligned?): {overlap}walls are soft by "
            f"{result.wall_tolerance_m:g} m (filter.map.conflict_*)"
        )
    if summary is not None:
        print(f"{output}: {format_waypoint_summary(summary)}")


def _waypoint_score(track: pd.DataFrame, waypoints: pd.DataFrame, source: str) -> tuple[dict, bool]:
    """The track's error at the surveyed waypoints (:func:`waypoint_summary`), and whether it could be
    scored.

    Scoring is an extra: when it cannot be done (one waypoint, a track of fewer than two estimates) a
    warning says why and the summary scores no waypoint (``n_waypoints`` 0, the figures null in
    ``run.json``), as when no waypoint lies inside the track's time span.
    """
    import pandas as pd

    from curbside.evaluate.metrics import waypoint_errors, waypoint_summary

    try:
        return waypoint_summary(waypoint_errors(track, waypoints)), True
    except CurbsideInputError as exc:
        logger.warning("%s: error at waypoints not scored (%s); the track is written without it",
                       source, exc.problem)
        return waypoint_summary(pd.DataFrame({"error_m": []})), False


def _absolute(path: str) -> str:
    """A session or map path as an absolute path (an ``h5::TRIAL`` suffix kept)."""
    file, sep, trial = str(path).partition("::")
    return str(Path(file).resolve()) + sep + trial


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add ``run`` to the ``localize`` sub-commands."""
    parser = subparsers.add_parser(
        "run",
        help="track one session (GNSS only, inertial + map, the paper's filter, or fused)",
        description="Track one session with the map-aware particle filter; writes OUT/track.csv, "
        "OUT/track.geojson, OUT/run.json (every parameter: replay with --config) and, with "
        "--save-particles, OUT/particles.npz. A session with surveyed waypoints (waypoints.csv, an IPIN "
        "trial) also gets the track's error at them and how many of them its 68 % radius (accuracy_m) "
        "held, printed and in run.json.",
        epilog="examples:\n  localize run walk/ --map map.geojson -o out/track\n"
        "  localize run walk/ --map map.geojson --set filter.gnss.sigma_factor=1.0 -o out/t2\n"
        "  localize run walk/ --map map.geojson --lag-s 30 -o out/smooth   # adds smooth_lat, smooth_lon\n"
        "  localize run walk/ --map map.geojson --unseen-velocity -o out/new   # phone surely new to RoNIN\n"
        "  localize run walk/ --map map.geojson --ronin-weights my.pt -o out/mine   # your own RoNIN model\n"
        "  localize run --config out/track/run.json -o out/replay     # the same track, byte for byte",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument(
        "session",
        nargs="?",
        help="session folder, Sensor Logger export, FILE.h5::TRIAL, .gpx, GnssLogger .txt or GetSensorData "
        ".txt (default with --config: the session it names)",
    )
    parser.add_argument("--map", help="map layers GeoJSON (osmseg build); none: no map likelihood")
    add_platform_option(parser)
    _add_method_options(parser)
    parser.add_argument("--save-particles", action="store_true", help="also write OUT/particles.npz")
    parser.add_argument(
        "--lag-s",
        type=non_negative_float,
        default=None,
        metavar="SECONDS",
        help="also estimate each position from the data up to SECONDS later (fixed-lag smoother; "
        "track.csv's smooth_lat, smooth_lon; offline analysis, e.g. 30). Default 0: off",
    )
    parser.add_argument(
        "--velocity-source",
        choices=VELOCITY_SOURCES,
        default=None,
        help="auto (default): velocity.csv, else RoNIN on imu.csv (PDR on one localize simulate made, "
        "which RoNIN reads badly), else PDR",
    )
    parser.add_argument(
        "--ronin-weights",
        metavar="PT",
        help="RoNIN weights .pt with their .json beside (localize train-ronin; default: the bundled model); "
        "refused where the velocity does not come from RoNIN. run.json records them and a replay uses them",
    )
    parser.add_argument(
        "--no-start-pose",
        action="store_true",
        help="ignore meta.json's start pose; start from the first usable GNSS fix",
    )
    parser.add_argument("-o", "--output", required=True,
                        help="output folder: new, empty or a previous curbside output")
    parser.add_argument("--overwrite", action="store_true",
                        help="write into a non-empty folder curbside did not write (keeping its other files)")
    parser.set_defaults(func=_run)


def _add_method_options(parser: argparse.ArgumentParser) -> None:
    """The run's replayed configuration, method, particles, jaywalk weight, seed and ``--set``."""
    parser.add_argument(
        "--config",
        metavar="RUN_JSON",
        help="replay the run recorded in a run.json (its "
        "parameters, session and map; options given here override them)",
    )
    parser.add_argument(
        "--mode",
        choices=MODES,
        default=None,
        help="method: gnss, inertial (RoNIN+PF), paper (the paper's plain GNSS+RoNIN+PF) or "
        "fused (curbside's; the default)",
    )
    parser.add_argument(
        "--particles", type=positive_int, default=None, metavar="N",
        help="number of particles (default 2000; 500 with --mode paper, the paper's)"
    )
    parser.add_argument(
        "--jaywalk-weight",
        type=unit_interval,
        default=None,
        metavar="W",
        help="particle weight in [0, 1] on street surface outside crosswalks (default 0.4); a step across "
        "the street weighs at least filter.map.crossing_weight (0.7; not with --mode paper)",
    )
    parser.add_argument(
        "--seed", type=seed, default=None, help="random seed (default 0): same seed, same track"
    )
    add_config_options(
        parser,
        "set any parameter of run.json's config, e.g. filter.gnss.sigma_factor=1.0 or "
        "engine.fix_association=once (repeatable; `localize parameters` lists them all)",
    )
