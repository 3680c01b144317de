"""GPX tracks: GNSS fixes only (``gnss.csv``), plus timed ``<wpt>`` points as ground truth.

Every ``<trkpt lat lon>`` with a ``<time>`` becomes a fix; ``t`` is seconds since the first fix (its
UTC time goes to ``meta["t0_utc"]``). GPX has no accuracy radius, only dilution of precision:
``accuracy_m = hdop * settings.gpx_uere_m`` (5 m, a typical user-equivalent range error of a phone
receiver) when a point has ``<hdop>``; otherwise the accuracy is NaN, which the session model
treats as an invalid fix (no GNSS update). ``<wpt>`` elements with a ``<time>`` become
``waypoints.csv``. GPX 1.0 and 1.1 are read alike (elements are matched by local name).
"""

from __future__ import annotations

import logging
import xml.etree.ElementTree as ET
from pathlib import Path

import pandas as pd

from curbside import settings
from curbside.errors import CurbsideInputError
from curbside.localize.readers._tidy import tidy_table
from curbside.localize.session import Session

logger = logging.getLogger(__name__)


def _local(tag: str) -> str:
    return tag.rsplit("}", 1)[-1]


def _points(root: ET.Element, name: str) -> pd.DataFrame:
    rows = []
    for el in root.iter():
        if _local(el.tag) != name:
            continue
        children = {_local(c.tag): (c.text or "").strip() for c in el}
        rows.append((el.get("lat"), el.get("lon"), children.get("time"), children.get("hdop")))
    return pd.DataFrame(rows, columns=["lat", "lon", "time", "hdop"])


def read_gpx(path: str | Path) -> Session:
    """Read a GPX file as a GNSS-only session.

    Parameters
    ----------
    path
        The ``.gpx`` file.

    Returns
    -------
    Session
        ``gnss`` (and ``waypoints`` when the file has timed ``<wpt>``), ``meta["t0_utc"]``.

    Raises
    ------
    CurbsideInputError
        Missing file, malformed XML, no track point with a time, non-numeric coordinates.
    """
    path = Path(path)
    if not path.is_file():
        raise CurbsideInputError(path, "no such file")
    try:
        root = ET.parse(path).getroot()
    except ET.ParseError as exc:
        raise CurbsideInputError(path, f"malformed XML ({exc})") from None
    if _local(root.tag) != "gpx":
        raise CurbsideInputError(path, f"root element is <{_local(root.tag)}>, not <gpx>")
    track = _points(root, "trkpt")
    track["stamp"] = pd.to_datetime(track["time"], utc=True, errors="coerce", format="ISO8601")
    untimed = track["stamp"].isna()
    if untimed.any():
        logger.info("%s: dropped %d track point(s) without a valid <time>", path, int(untimed.sum()))
        track = track[~untimed]
    if track.empty:
        raise CurbsideInputError(path, "no <trkpt> with a <time>")
    t0 = track["stamp"].min()
    track["t"] = (track["stamp"] - t0).dt.total_seconds()
    hdop = pd.to_numeric(track["hdop"], errors="coerce")
    track["accuracy_m"] = hdop * settings.gpx_uere_m
    if hdop.isna().all():
        logger.warning("%s: no <hdop>; every fix has unknown accuracy and counts as invalid", path)
    gnss = tidy_table(track, path, ["t", "lat", "lon", "accuracy_m"], nullable=("accuracy_m",))

    waypoints = None
    wpt = _points(root, "wpt")
    wpt["stamp"] = pd.to_datetime(wpt["time"], utc=True, errors="coerce", format="ISO8601")
    wpt = wpt[wpt["stamp"].notna()]
    if len(wpt):
        wpt["t"] = (wpt["stamp"] - t0).dt.total_seconds()
        waypoints = tidy_table(wpt, f"{path} <wpt>", ["t", "lat", "lon"])
    meta = {"source": {"format": "gpx", "file": path.name}, "t0_utc": t0.isoformat()}
    return Session(name=path.stem, gnss=gnss, waypoints=waypoints, meta=meta)
