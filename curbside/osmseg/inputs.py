"""The checks of osmseg's inputs that need no heavy import: a bbox, an OSM file's name and size, a map
file's path and first bytes, an output's format.

The console commands call them before they import numpy, geopandas or osmium, so bad input is refused in
a fraction of a second; the readers (:func:`~curbside.osmseg.build.build_map`,
:func:`~curbside.osmseg.reader.read_osm_file`, :func:`~curbside.osmseg.mapio.read_map`,
:func:`~curbside.osmseg.plot.render_map`) call the same functions, so each message has one source.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

from curbside import settings
from curbside.errors import CurbsideInputError

BBox = tuple[float, float, float, float]

#: Orders a bbox is given in by mistake -> indices into it that make (west, south, east, north).
_MISTAKEN_ORDERS = {
    "latitude first (S W N E)": (1, 0, 3, 2),
    "W E S N": (0, 2, 1, 3),
    "S N W E, Nominatim's order": (2, 0, 3, 1),
}

#: File name endings ``--osm`` accepts (pyosmium reads compressed XML itself).
OSM_SUFFIXES: tuple[str, ...] = (".osm", ".osm.bz2", ".osm.gz", ".osm.pbf")

#: osmium's name of each format, by the file name ending that announces it.
OSM_FORMATS = {".osm.pbf": "pbf", ".osm.bz2": "osm.bz2", ".osm.gz": "osm.gz", ".osm": "osm"}

#: What ``osmseg show`` writes, by the output's extension.
FORMATS: dict[str, str] = {".png": "png", ".html": "html", ".htm": "html"}

#: How much of a map file :func:`check_map_file` reads to see that it starts as a JSON object.
_MAP_HEAD_BYTES = 4096
#: A file larger than this that does not start as a JSON object is refused without reading it whole.
_MAP_READ_WHOLE_MAX_BYTES = 8 * 2**20


def _in_order(west: float, south: float, east: float, north: float) -> bool:
    lon_ok = -180 <= west < east <= 180
    return lon_ok and -90 <= south < north <= 90


def _order_hint(values: tuple[float, float, float, float]) -> str:
    """A hint for a bbox that is valid in another order (lat/lon swapped, corners swapped), else ''."""
    for name, order in _MISTAKEN_ORDERS.items():
        fixed = tuple(values[i] for i in order)
        if _in_order(*fixed):
            return f"; it looks like {name}: give W S E N, longitude first: --bbox {_fmt(fixed)}"
    (west, east), (south, north) = sorted(values[0::2]), sorted(values[1::2])
    if _in_order(west, south, east, north):
        return f"; give W S E N, west < east, south < north: --bbox {_fmt((west, south, east, north))}"
    return ""


def _fmt(values: tuple[float, ...]) -> str:
    return " ".join(f"{v:.10g}" for v in values)


def check_bbox(bbox: BBox, source: str = "--bbox") -> BBox:
    """Validate a (west, south, east, north) bbox in WGS84 degrees.

    A bbox that is valid in an order people often give by mistake (latitude first, W E S N,
    Nominatim's S N W E, corners swapped) gets the fixed order in the message.

    Raises
    ------
    CurbsideInputError
        Not four finite numbers, W >= E or S >= N, outside lon/lat ranges, or larger than
        ``settings.max_bbox_area_km2``.
    """
    try:
        west, south, east, north = (float(v) for v in bbox)
    except (TypeError, ValueError):
        raise CurbsideInputError(source, "expected four numbers: west south east north") from None
    if not all(math.isfinite(v) for v in (west, south, east, north)):
        raise CurbsideInputError(source, "coordinates must be finite numbers")
    hint = _order_hint((west, south, east, north))
    if not (-180 <= west <= 180 and -180 <= east <= 180 and -90 <= south <= 90 and -90 <= north <= 90):
        raise CurbsideInputError(source, f"outside the lon/lat range (lon -180..180, lat -90..90){hint}")
    if west >= east:
        raise CurbsideInputError(source, f"west ({west}) must be less than east ({east}){hint}")
    if south >= north:
        raise CurbsideInputError(source, f"south ({south}) must be less than north ({north}){hint}")
    area = bbox_area_km2((west, south, east, north))
    limit = settings.max_bbox_area_km2
    if area > limit:
        raise CurbsideInputError(
            source, f"area {area:,.1f} km^2 is over the {limit:g} km^2 limit (settings.max_bbox_area_km2): "
            "a larger city area takes minutes and GBs of memory to download and build, and Overpass refuses "
            "queries that outgrow its time or memory; split it into smaller bboxes",
        )  # fmt: skip
    return west, south, east, north


def bbox_area_km2(bbox: BBox) -> float:
    """Approximate area of a WGS84 bbox in km^2 (spherical Earth)."""
    west, south, east, north = bbox
    r_km = 6371.0088
    band = math.sin(math.radians(north)) - math.sin(math.radians(south))
    return r_km**2 * math.radians(east - west) * band


def check_osm_file(path: str | Path) -> str:
    """Check an OSM file by its path alone (no byte of it is read) and name its format.

    Parameters
    ----------
    path
        The ``--osm`` file.

    Returns
    -------
    str
        osmium's name of the format its name announces (:data:`OSM_FORMATS`).

    Raises
    ------
    CurbsideInputError
        Missing, a folder, empty, or a name without one of :data:`OSM_SUFFIXES`.
    """
    path = Path(path)
    if not path.exists():
        raise CurbsideInputError(path, "no such OSM file")
    if not path.is_file():
        raise CurbsideInputError(path, "is a folder, not an OSM file" if path.is_dir() else "not a file")
    named = next((fmt for suffix, fmt in OSM_FORMATS.items() if path.name.lower().endswith(suffix)), None)
    if named is None:
        raise CurbsideInputError(
            path, f"unsupported file type; expected one of {', '.join(OSM_SUFFIXES[:4])}"
        )
    if path.stat().st_size == 0:
        raise CurbsideInputError(path, "is empty (0 bytes)")
    return named


def output_format(path: str | Path) -> str:
    """``"png"`` or ``"html"`` from an output file's extension.

    Raises
    ------
    CurbsideInputError
        For any other extension.
    """
    suffix = Path(path).suffix.lower()
    if suffix not in FORMATS:
        raise CurbsideInputError(
            path, f"unsupported output format {suffix or '(none)'!r}; use one of {sorted(FORMATS)}"
        )
    return FORMATS[suffix]


def _check_map_path(path: Path) -> None:
    if path.is_dir():
        raise CurbsideInputError(path, "is a folder, not a map file (a GeoJSON written by `osmseg build`)")
    if not path.is_file():
        raise CurbsideInputError(path, "no such map file")


def _unreadable(path: Path, exc: Exception) -> CurbsideInputError:
    return CurbsideInputError(path, f"not readable as GeoJSON ({exc})")


def map_document(path: str | Path) -> dict:
    """A map file's GeoJSON document, checked to be a FeatureCollection (what :func:`read_map
    <curbside.osmseg.mapio.read_map>` then validates feature by feature).

    Raises
    ------
    CurbsideInputError
        Missing, a folder, unreadable, not JSON, or not a FeatureCollection.
    """
    path = Path(path)
    _check_map_path(path)
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise _unreadable(path, exc) from None
    if not isinstance(doc, dict) or doc.get("type") != "FeatureCollection":
        raise CurbsideInputError(path, "not a GeoJSON FeatureCollection")
    return doc


def check_map_file(path: str | Path) -> None:
    """Check a map file before the slow work: it exists, is a readable file and starts as a JSON object.

    Only the first bytes are read; a file that does not start with ``{`` is then read whole by
    :func:`map_document`, whose refusal names the problem as :func:`~curbside.osmseg.mapio.read_map`
    would, unless it is over 8 MiB (say an OSM extract given as the map), refused at once. The features
    are checked when the map is read.

    Raises
    ------
    CurbsideInputError
        Missing, a folder, unreadable, not JSON, or not a FeatureCollection.
    """
    path = Path(path)
    _check_map_path(path)
    try:
        with open(path, "rb") as fh:
            head = fh.read(_MAP_HEAD_BYTES)
    except OSError as exc:
        raise _unreadable(path, exc) from None
    if not head.lstrip(b" \t\r\n").startswith(b"{"):  # JSON's blanks; a BOM is refused, as by read_map
        if path.stat().st_size > _MAP_READ_WHOLE_MAX_BYTES:  # a .pbf given as --map: not read whole
            raise CurbsideInputError(path, "not a GeoJSON FeatureCollection (it does not start with '{')")
        map_document(path)
