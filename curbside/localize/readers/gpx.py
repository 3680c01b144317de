"""GPX tracks: GNSS fixes only (``gnss.csv``), plus timed ``<wpt>`` points as ground truth.

Parsing is gpxpy's (GPX 1.0 and 1.1, namespaces, extensions). Every track point of every track and
segment (and route point) with a time becomes a fix; ``t`` is seconds since the first fix (its UTC
time goes to ``meta["t0_utc"]``; times without a zone are taken as UTC, as GPX requires). GPX has no
accuracy radius, only dilution of precision: ``accuracy_m = hdop * uere_m`` (default 5 m, a
typical user-equivalent range error of a phone receiver) when a point has ``<hdop>``; otherwise the
accuracy is NaN, which the session model treats as an invalid fix (no GNSS update). ``<wpt>``
elements with a ``<time>`` become ``waypoints.csv``.
"""

from __future__ import annotations

import logging
from pathlib import Path

import gpxpy
import gpxpy.gpx
import pandas as pd

from curbside.errors import CurbsideInputError
from curbside.localize.readers._tidy import tidy_table
from curbside.localize.session import Session

logger = logging.getLogger(__name__)


def _table(points) -> pd.DataFrame:
    rows = [(p.latitude, p.longitude, p.time, p.horizontal_dilution) for p in points]
    table = pd.DataFrame(rows, columns=["lat", "lon", "time", "hdop"])
    table["stamp"] = pd.to_datetime(table["time"], utc=True)
    table["hdop"] = pd.to_numeric(table["hdop"], errors="coerce")
    return table


def _parse(path: Path) -> gpxpy.gpx.GPX:
    try:
        with path.open(encoding="utf-8") as fh:
            return gpxpy.parse(fh)
    except (gpxpy.gpx.GPXException, ValueError, UnicodeDecodeError) as exc:
        reason = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise CurbsideInputError(path, f"not a readable GPX file ({reason})") from None
    except OSError as exc:
        raise CurbsideInputError(path, f"cannot read ({exc.strerror})") from None


def read_gpx(path: str | Path, *, uere_m: float = 5.0) -> Session:
    """Read a GPX file as a GNSS-only session.

    Parameters
    ----------
    path
        The ``.gpx`` file.
    uere_m
        User-equivalent range error (m): a point's accuracy radius is its ``<hdop>`` times this.

    Returns
    -------
    Session
        ``gnss`` (and ``waypoints`` when the file has timed ``<wpt>``), ``meta["t0_utc"]``.

    Raises
    ------
    CurbsideInputError
        Missing or unreadable file, malformed GPX, no track or route point with a time.
    ValueError
        ``uere_m`` not positive.
    """
    if not uere_m > 0:
        raise ValueError(f"uere_m must be positive, got {uere_m}")
    path = Path(path)
    if not path.is_file():
        raise CurbsideInputError(path, "no such file")
    doc = _parse(path)
    points = [p for trk in doc.tracks for seg in trk.segments for p in seg.points]
    points += [p for rte in doc.routes for p in rte.points]
    if not points and not doc.waypoints:
        raise CurbsideInputError(path, "no track, route or waypoint in it (is it a GPX file?)")
    track = _table(points)
    untimed = track["stamp"].isna()
    if untimed.any():
        logger.info("%s: dropped %d track point(s) without a valid <time>", path, int(untimed.sum()))
        track = track[~untimed]
    if track.empty:
        raise CurbsideInputError(path, "no <trkpt> with a <time>")
    t0 = track["stamp"].min()
    track["t"] = (track["stamp"] - t0).dt.total_seconds()
    track["accuracy_m"] = track["hdop"] * uere_m
    if track["hdop"].isna().all():
        logger.warning("%s: no <hdop>; every fix has unknown accuracy and counts as invalid", path)
    gnss = tidy_table(track, path, ["t", "lat", "lon", "accuracy_m"], nullable=("accuracy_m",))

    waypoints = None
    wpt = _table(doc.waypoints)
    wpt = wpt[wpt["stamp"].notna()].copy()
    if len(wpt):
        wpt["t"] = (wpt["stamp"] - t0).dt.total_seconds()
        waypoints = tidy_table(wpt, f"{path} <wpt>", ["t", "lat", "lon"])
    meta = {"source": {"format": "gpx", "file": path.name}, "t0_utc": t0.isoformat()}
    return Session(name=path.stem, gnss=gnss, waypoints=waypoints, meta=meta)
