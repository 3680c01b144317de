"""What the simulator reads from OpenStreetMap: building heights and the mapped pedestrian network.

The map layers (``osmseg build``) keep no heights and no footway centrelines, so the simulator reads
the OSM file itself, once, with :func:`osmnx.features_from_xml`, and caches the two tables it needs
(pickled GeoDataFrames in local UTM) under ``settings.cache_dir / "evaluate"``, keyed by the file's
content hash.
"""

from __future__ import annotations

import hashlib
import logging
import pickle
import re
from dataclasses import dataclass
from pathlib import Path

import geopandas as gpd
import numpy as np
import osmnx as ox
import pandas as pd

from curbside import settings
from curbside.errors import CurbsideInputError
from curbside.io import atomic_path
from curbside.projection import utm_crs_for

log = logging.getLogger(__name__)

_NUMBER = re.compile(r"^\s*([0-9]+(?:\.[0-9]+)?)\s*(m|ft|')?", re.IGNORECASE)


@dataclass
class OsmSource:
    """Buildings with heights and pedestrian ways, in the local UTM CRS.

    Attributes
    ----------
    buildings
        ``geometry`` (polygons), ``height_m`` (from ``height``, else ``building:levels`` times
        ``settings.evaluate_level_height_m``, else ``settings.evaluate_default_height_m``),
        ``osm_id``.
    footways
        ``geometry`` (LineStrings) of ``footway=sidewalk`` and ``footway=crossing`` ways, ``kind``
        (``sidewalk``/``crossing``), ``covered`` (bool), ``osm_id``.
    roads
        Carriageway centrelines (``geometry``, ``name``) used to recognise a mid-block street crossing.
    """

    buildings: gpd.GeoDataFrame
    footways: gpd.GeoDataFrame
    roads: gpd.GeoDataFrame

    @property
    def crs(self):
        """The local metric CRS."""
        return self.buildings.crs


def parse_height_m(height: pd.Series, levels: pd.Series) -> np.ndarray:
    """Building heights in metres from OSM ``height`` and ``building:levels`` strings.

    ``height`` may carry a unit (``"93 m"``, ``"300 ft"``, ``"40'"``); a missing or unparsable height
    falls back to levels, then to the default height.
    """
    out = np.full(len(height), np.nan)
    for i, value in enumerate(height.to_numpy(object)):
        m = _NUMBER.match(str(value)) if isinstance(value, str | int | float) and value == value else None
        if m:
            unit = (m.group(2) or "m").lower()
            out[i] = float(m.group(1)) * (0.3048 if unit in ("ft", "'") else 1.0)
    lv = pd.to_numeric(levels, errors="coerce").to_numpy(float)
    out = np.where(np.isfinite(out), out, lv * settings.evaluate_level_height_m)
    return np.where(np.isfinite(out) & (out > 0), out, settings.evaluate_default_height_m)


def _column(frame: pd.DataFrame, name: str) -> pd.Series:
    return frame[name] if name in frame else pd.Series([None] * len(frame), index=frame.index)


def _read(osm_file: Path) -> OsmSource:
    try:
        feats = ox.features_from_xml(osm_file)
    except Exception as exc:  # noqa: BLE001 - osmnx raises many types for unreadable XML
        raise CurbsideInputError(osm_file, f"not readable as OSM XML ({exc})") from None
    if len(feats) == 0:
        raise CurbsideInputError(osm_file, "no OSM features")
    minx, miny, maxx, maxy = feats.total_bounds
    crs = utm_crs_for((minx + maxx) / 2, (miny + maxy) / 2)
    feats = feats.to_crs(crs)
    ids = [f"{kind[0]}{oid}" for kind, oid in feats.index]
    feats = feats.assign(osm_id=ids).reset_index(drop=True)
    polys = feats.geom_type.isin(["Polygon", "MultiPolygon"])
    is_building = _column(feats, "building").notna() & polys
    underground = _column(feats, "location").astype(str).eq("underground")
    b = feats[is_building & ~underground]
    buildings = gpd.GeoDataFrame(
        {
            "height_m": parse_height_m(_column(b, "height"), _column(b, "building:levels")),
            "osm_id": b["osm_id"].to_numpy(),
        },
        geometry=b.geometry.to_numpy(),
        crs=crs,
    )
    lines = feats[feats.geom_type == "LineString"]
    footway = _column(lines, "footway")
    fw = lines[footway.isin(["sidewalk", "crossing"])]
    footways = gpd.GeoDataFrame(
        {
            "kind": _column(fw, "footway").to_numpy(),
            "covered": _column(fw, "covered").astype(str).eq("yes").to_numpy(),
            "osm_id": fw["osm_id"].to_numpy(),
        },
        geometry=fw.geometry.to_numpy(),
        crs=crs,
    )
    road_classes = settings.evaluate_road_classes
    rd = lines[_column(lines, "highway").isin(road_classes) & ~_column(lines, "tunnel").eq("yes")]
    roads = gpd.GeoDataFrame(
        {"name": _column(rd, "name").to_numpy()}, geometry=rd.geometry.to_numpy(), crs=crs
    )
    log.info(
        "OSM %s: %d buildings, %d footways, %d roads",
        osm_file.name,
        len(buildings),
        len(footways),
        len(roads),
    )
    return OsmSource(buildings, footways, roads)


def load_osm(osm_file: str | Path | None = None) -> OsmSource:
    """Buildings with heights, footways and roads of an OSM file, cached on disk.

    Parameters
    ----------
    osm_file
        ``.osm`` / ``.osm.bz2`` XML; default the bundled downtown San Francisco extract.

    Returns
    -------
    OsmSource
    """
    osm_file = Path(osm_file or settings.default_osm_file)
    if not osm_file.is_file():
        raise CurbsideInputError(osm_file, "no such OSM file")
    digest = hashlib.sha1(osm_file.read_bytes()).hexdigest()[:16]
    cache = Path(settings.cache_dir) / "evaluate" / f"osm-{digest}-v1.pkl"
    if cache.is_file():
        try:
            with cache.open("rb") as fh:
                return pickle.load(fh)
        except (OSError, pickle.UnpicklingError, EOFError, AttributeError):
            log.warning("ignoring unreadable cache %s", cache)
    source = _read(osm_file)
    with atomic_path(cache) as tmp, tmp.open("wb") as fh:
        pickle.dump(source, fh)
    return source
