"""GPX tracks: GNSS fixes only (``gnss.csv``), plus timed ``<wpt>`` points as ground truth.

Parsing is gpxpy's (GPX 1.0 and 1.1, namespaces, extensions). Every track point of every track and
segment (and route point) with a time becomes a fix; ``t`` is seconds since the first fix (its UTC
time goes to ``meta["t0_utc"]``; times without a zone are taken as UTC, as GPX requires). GPX has no
accuracy radius, only dilution of precision: ``accuracy_m = hdop * uere_m`` (default 5 m, a
typical user-equivalent range error of a phone receiver) when a point has ``<hdop>``; otherwise the
accuracy is NaN, which the session model treats as an invalid fix (no GNSS update). ``<wpt>``
elements with a ``<time>`` become ``waypoints.csv``, except those farther than 5 km from every fix.

Whole-second ``<time>`` (the usual form) makes two fixes logged within one second share a timestamp;
there the first of each second is kept (a warning counts the others). With sub-second times, fixes
sharing one are an error, as in every format. The file's bytes go to the parser with the encoding
its XML declaration names (``ISO-8859-1`` and the like), UTF-8 by default.
"""

from __future__ import annotations

import codecs
import logging
import re
from pathlib import Path

import gpxpy
import gpxpy.gpx
import pandas as pd

from curbside.errors import CurbsideInputError
from curbside.localize.readers._tidy import drop_far_waypoints, tidy_table
from curbside.localize.session import Session

logger = logging.getLogger(__name__)

#: How errors name the session's columns: a point's ``t`` is quoted as its ``<time>``; points are
#: counted from 1 in file order (track points, then route points).
_NAMES = {"t": "time"}


def _table(points) -> pd.DataFrame:
    rows = [(p.latitude, p.longitude, p.time, p.horizontal_dilution) for p in points]
    table = pd.DataFrame(rows, columns=["lat", "lon", "time", "hdop"])
    table["stamp"] = pd.to_datetime(table["time"], utc=True)
    table["hdop"] = pd.to_numeric(table["hdop"], errors="coerce")
    return table


_DECLARATION = re.compile(rb"""^\s*<\?xml[^>]*?\bencoding\s*=\s*["']([A-Za-z0-9._:-]+)["'][^>]*\?>""")
_BOMS = ((codecs.BOM_UTF8, "utf-8-sig"), (codecs.BOM_UTF16_LE, "utf-16"), (codecs.BOM_UTF16_BE, "utf-16"))


def _decode(data: bytes, path: Path) -> str:
    """The document as text, decoded as its byte-order mark or XML declaration says (else UTF-8).

    gpxpy parses text, not bytes, and would decode as UTF-8 whatever the declaration names; the
    declaration is dropped after decoding so that no parser decodes the text a second time.
    """
    encoding = next((name for bom, name in _BOMS if data.startswith(bom)), None)
    match = _DECLARATION.match(data)
    if encoding is None and match:
        encoding = match.group(1).decode("ascii")
    encoding = encoding or "utf-8"
    try:
        text = data.decode(encoding)
    except LookupError:
        problem = f"not a readable GPX file (unknown encoding {encoding!r} in its XML declaration)"
        raise CurbsideInputError(path, problem) from None
    except UnicodeDecodeError as exc:
        problem = f"not a readable GPX file (not {encoding} text: {exc.reason} at byte {exc.start})"
        raise CurbsideInputError(path, problem) from None
    return re.sub(r"^\s*<\?xml[^>]*\?>", "", text.lstrip("\ufeff"), count=1)


def _parse(path: Path) -> gpxpy.gpx.GPX:
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise CurbsideInputError(path, f"cannot read ({exc.strerror})") from None
    try:
        return gpxpy.parse(_decode(data, path))
    except (gpxpy.gpx.GPXException, ValueError) as exc:
        reason = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise CurbsideInputError(path, f"not a readable GPX file ({reason})") from None


def _one_fix_per_stamp(track: pd.DataFrame, path: Path) -> pd.DataFrame:
    """Keep the first fix of each timestamp when whole-second times make several share one.

    Sub-second times that repeat are left for :func:`tidy_table` to refuse; so is a file where most
    fixes share their time with another, whose times are not the fixes' times.
    """
    track = track.sort_values("t", kind="stable")
    columns = ["t", "lat", "lon", "accuracy_m"]
    distinct = track.drop_duplicates(subset=columns)  # exact duplicates: tidy_table drops and counts them
    shared = distinct["t"].duplicated(keep="first")
    stamps = track["stamp"]
    whole_seconds = bool(((stamps.dt.microsecond == 0) & (stamps.dt.nanosecond == 0)).all())
    if not shared.any() or not whole_seconds or shared.sum() > len(distinct) / 2:
        return track
    logger.warning("%s: %d fix(es) share a whole-second <time> with an earlier one; kept the first fix of "
                   "each second", path, int(shared.sum()))
    return track[~track["t"].duplicated(keep="first")]  # exact duplicates of a kept fix go too


def _near_fixes(waypoints: pd.DataFrame, gnss: pd.DataFrame, path: Path) -> pd.DataFrame | None:
    """Drop (with a warning naming them) the waypoints farther than 5 km from every fix."""
    kept = drop_far_waypoints(waypoints, gnss, path, "<wpt>", "track point")
    return kept if len(kept) else None


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
    track = _one_fix_per_stamp(track, path)
    if track["hdop"].isna().all():
        logger.warning("%s: no <hdop>; every fix has unknown accuracy and counts as invalid", path)
    gnss = tidy_table(track, path, ["t", "lat", "lon", "accuracy_m"], nullable=("accuracy_m",), names=_NAMES,
                      rows="point")

    waypoints = None
    wpt = _table(doc.waypoints)
    wpt = wpt[wpt["stamp"].notna()].copy()
    if len(wpt):
        wpt["t"] = (wpt["stamp"] - t0).dt.total_seconds()
        wpt = tidy_table(wpt, f"{path} <wpt>", ["t", "lat", "lon"], names=_NAMES, rows="<wpt>")
        waypoints = _near_fixes(wpt, gnss, path)
    meta = {"source": {"format": "gpx", "file": path.name}, "t0_utc": t0.isoformat()}
    return Session(name=path.stem, gnss=gnss, waypoints=waypoints, meta=meta)
