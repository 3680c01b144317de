"""What the simulator reads from OpenStreetMap: building heights and the mapped pedestrian network.

The map layers (``osmseg build``) keep no heights and no footway centrelines, so the simulator takes
them from the same reader as ``osmseg build`` (:func:`curbside.osmseg.reader.read_osm_file`, with tag
values parsed by :mod:`curbside.osmseg.tags`) and caches the three tables it needs as GeoParquet
(:mod:`curbside.cache`, kind ``osmsource``), keyed by the file's content and the
:class:`OsmSourceConfig` that made them.
"""

from __future__ import annotations

import json
import logging
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import geopandas as gpd
import numpy as np
import pandas as pd

from curbside import cache, settings
from curbside.configio import to_dict
from curbside.errors import CurbsideInputError
from curbside.osmseg.reader import read_osm_file
from curbside.osmseg.tags import column, first_number, is_in, metres

if TYPE_CHECKING:
    from pyproj import CRS

log = logging.getLogger(__name__)

#: Bumped whenever the tables' content changes, so older cache entries are not reused.
_FORMAT_VERSION = 2
_TABLES = ("buildings", "footways", "roads")


def _check(condition: bool, message: str) -> None:
    if not condition:
        raise ValueError(message)


@dataclass(frozen=True)
class OsmSourceConfig:
    """How the simulator reads heights and roads from OSM tags.

    Attributes
    ----------
    level_height_m
        Storey height used when a building has ``building:levels`` but no ``height`` (metres).
    default_height_m
        Height of a building with neither ``height`` nor ``building:levels`` (metres; ~3 storeys).
    road_classes
        ``highway`` values whose centrelines count as carriageways for mid-block (jaywalk) crossings.
    """

    level_height_m: float = 3.5
    default_height_m: float = 10.0
    road_classes: tuple[str, ...] = (
        "primary", "primary_link", "secondary", "secondary_link", "tertiary", "tertiary_link",
        "residential", "unclassified", "living_street", "service", "busway",
    )  # fmt: skip

    def __post_init__(self) -> None:
        _check(
            self.level_height_m > 0 and self.default_height_m > 0,
            f"heights must be positive, got {self.level_height_m}, {self.default_height_m}",
        )
        _check(
            not isinstance(self.road_classes, str) and all(isinstance(c, str) for c in self.road_classes),
            f"road_classes must be highway class names, got {self.road_classes!r}",
        )


@dataclass
class OsmSource:
    """Buildings with heights and pedestrian ways, in the local UTM CRS.

    Attributes
    ----------
    buildings
        ``geometry`` (polygons), ``height_m`` (from ``height``, else ``building:levels`` times
        :attr:`OsmSourceConfig.level_height_m`, else :attr:`OsmSourceConfig.default_height_m`),
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
    def crs(self) -> CRS:
        """The local metric CRS."""
        return self.buildings.crs


def parse_height_m(height: pd.Series, levels: pd.Series, config: OsmSourceConfig | None = None) -> np.ndarray:
    """Building heights in metres from OSM ``height`` and ``building:levels`` strings.

    ``height`` may carry a unit (``"93 m"``, ``"300 ft"``, ``"40'"``; :func:`~curbside.osmseg.tags.metres`);
    a missing or unparsable height falls back to levels times ``config.level_height_m``, then to
    ``config.default_height_m`` (default :class:`OsmSourceConfig`).
    """
    config = config or OsmSourceConfig()
    out = metres(height)
    out = np.where(np.isfinite(out), out, first_number(levels) * config.level_height_m)
    return np.where(np.isfinite(out) & (out > 0), out, config.default_height_m)


def _read(osm_file: Path, config: OsmSourceConfig) -> dict[str, gpd.GeoDataFrame]:
    osm = read_osm_file(osm_file)
    areas = osm.areas
    underground = is_in(column(areas, "location"), ["underground"])
    b = areas[column(areas, "building").notna().to_numpy() & ~underground]
    buildings = gpd.GeoDataFrame(
        {
            "height_m": parse_height_m(column(b, "height"), column(b, "building:levels"), config),
            "osm_id": b["osm_id"].astype(str).to_numpy(),
        },
        geometry=b.geometry.to_numpy(),
        crs=osm.crs,
    )
    lines = osm.ways
    fw = lines[is_in(column(lines, "footway"), ["sidewalk", "crossing"])]
    footways = gpd.GeoDataFrame(
        {
            "kind": column(fw, "footway").to_numpy(dtype=object),
            "covered": is_in(column(fw, "covered"), ["yes"]),
            "osm_id": [f"w{i}" for i in fw["osm_id"]],
        },
        geometry=fw.geometry.to_numpy(),
        crs=osm.crs,
    )
    tunnel = is_in(column(lines, "tunnel"), ["yes"])
    rd = lines[is_in(column(lines, "highway"), config.road_classes) & ~tunnel]
    roads = gpd.GeoDataFrame(
        {"name": column(rd, "name").to_numpy(dtype=object)}, geometry=rd.geometry.to_numpy(), crs=osm.crs
    )
    log.info(
        "OSM %s: %d buildings, %d footways, %d roads",
        osm_file.name, len(buildings), len(footways), len(roads),
    )
    return {"buildings": buildings, "footways": footways, "roads": roads}


def _strings_as_objects(gdf: gpd.GeoDataFrame) -> gpd.GeoDataFrame:
    """String columns read back from Parquet as plain objects with None where missing."""
    for col in gdf.columns.drop(gdf.geometry.name):
        if not (pd.api.types.is_numeric_dtype(gdf[col]) or pd.api.types.is_bool_dtype(gdf[col])):
            gdf[col] = gdf[col].astype(object).where(gdf[col].notna(), None)
    return gdf


def load_osm(osm_file: str | Path | None = None, config: OsmSourceConfig | None = None) -> OsmSource:
    """Buildings with heights, footways and roads of an OSM file, cached on disk.

    Parameters
    ----------
    osm_file
        ``.osm``, ``.osm.bz2``, ``.osm.gz`` or ``.osm.pbf``; default the bundled downtown San
        Francisco extract.
    config
        Heights and road classes (default :class:`OsmSourceConfig`); part of the cache key.

    Returns
    -------
    OsmSource

    Raises
    ------
    CurbsideInputError
        A missing or unreadable file, or one without highways or buildings.
    """
    config = config or OsmSourceConfig()
    osm_file = Path(osm_file or settings.default_osm_file)
    if not osm_file.is_file():
        raise CurbsideInputError(osm_file, "no such OSM file")
    key = cache.content_key(f"osmsource-v{_FORMAT_VERSION}", osm_file, json.dumps(to_dict(config)))
    tables = cache.cached_frames("osmsource", key, lambda: _read(osm_file, config), _TABLES)
    return OsmSource(*(_strings_as_objects(tables[name]) for name in _TABLES))
