"""The ``ipin_sf`` session of docs/filter.md ("How far the estimate is from its segment"): a real IPIN 2023
walk moved onto downtown San Francisco.

The walk is ``tests/data/sessions/ipin2023-cut.h5::TrainingTrial01_repetition01`` (32 s of 50 Hz phone
IMU with its quaternion, 1 Hz GNSS, a surveyed start pose), the one the service tests stream. Its fixes
are turned and shifted so that it starts at ``--at`` (UTM zone 10N metres; default 553062 4182750, by
Market and Fremont streets, the point of ``tests/test_serve.py``'s ``walk_on_map``) heading
``--heading-deg`` (default 90, east); the IMU is left as it is (its frame is the phone's), the surveyed
waypoints are dropped (they belong to the venue), and the start pose becomes the new one. Then::

    python benchmarks/ipin_sf_session.py -o ipin_sf
    localize run ipin_sf --map map.geojson --seed 0 -o ipin_sf_run    # map.geojson: make demo's

Usage::

    python benchmarks/ipin_sf_session.py -o SESSION [--at EASTING NORTHING] [--heading-deg DEG]
        [--walk H5::TRIAL] [--overwrite]
"""

from __future__ import annotations

import argparse
import copy
import logging
import math
from pathlib import Path

import numpy as np
import pyproj

from curbside.localize.readers import read_any
from curbside.localize.session import Session, write_session
from curbside.projection import LocalFrame

log = logging.getLogger(__name__)

#: The walk moved: a real IPIN 2023 trial kept in the repository.
WALK = f"{Path(__file__).parents[1] / 'tests' / 'data' / 'sessions' / 'ipin2023-cut.h5'}" \
    "::TrainingTrial01_repetition01"
#: Where it starts by default (UTM 10N, m): by Market and Fremont streets.
START_UTM_M = (553062.0, 4182750.0)


def moved_walk(walk: Session, at_utm_m: tuple[float, float], heading_deg: float) -> Session:
    """``walk`` with its fixes turned and shifted so that its start pose is at ``at_utm_m`` (UTM zone
    10N metres) heading ``heading_deg`` (clockwise from north); no waypoints.

    Parameters
    ----------
    walk
        A session with a start pose (``meta["start"]``: ``lat``, ``lon``, ``heading_deg``, ``t``) and
        ``gnss``.
    at_utm_m
        The new start, easting and northing in metres.
    heading_deg
        The new start heading, degrees clockwise from north.

    Returns
    -------
    curbside.localize.session.Session
        A copy; the IMU is shared, unchanged.
    """
    start = walk.meta["start"]
    here = LocalFrame.around(start["lon"], start["lat"])
    x0, y0 = here.to_xy(start["lon"], start["lat"])
    x, y = here.to_xy(walk.gnss["lon"].to_numpy(), walk.gnss["lat"].to_numpy())
    turn = math.radians(start["heading_deg"] - heading_deg)  # counter-clockwise in east-north
    c, s = math.cos(turn), math.sin(turn)
    there = LocalFrame(pyproj.CRS("EPSG:32610"))
    east, north = at_utm_m
    dx, dy = np.asarray(x) - x0, np.asarray(y) - y0
    lon, lat = there.to_lonlat(east + c * dx - s * dy, north + s * dx + c * dy)
    moved = copy.copy(walk)
    moved.gnss = walk.gnss.assign(lat=lat, lon=lon)
    moved.waypoints = None
    slon, slat = there.to_lonlat(east, north)
    moved.meta = {"start": {"lat": float(slat), "lon": float(slon), "heading_deg": float(heading_deg),
                            "t": start["t"]}}
    return moved


def main(argv: list[str] | None = None) -> int:
    """Write the moved walk as a session folder."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("-o", "--output", required=True, help="the session folder to write")
    parser.add_argument("--walk", default=WALK, help="the walk to move, H5::TRIAL (default: %(default)s)")
    parser.add_argument("--at", nargs=2, type=float, default=START_UTM_M, metavar=("EASTING", "NORTHING"),
                        help="where it starts, UTM zone 10N metres (default: %(default)s)")
    parser.add_argument("--heading-deg", type=float, default=90.0,
                        help="its start heading, degrees clockwise from north (default: %(default)s)")
    parser.add_argument("--overwrite", action="store_true", help="write into a non-empty folder")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    session = moved_walk(read_any(args.walk), tuple(args.at), args.heading_deg)
    write_session(session, args.output, overwrite=args.overwrite, command="benchmarks/ipin_sf_session.py")
    log.info("%s: %s moved to UTM 10N %.0f %.0f, heading %g deg", args.output, args.walk, *args.at,
             args.heading_deg)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
