"""Read the DataSF 2013 building footprints (TopoJSON tiles) as a building-only map.

The tiles (``bf_ll-3_1.topojson``... from the blech/sf-buildings repository) are read with GDAL's
TopoJSON driver through geopandas. Three properties of the data shape the reader:

- **Inner rings are holes.** TopoJSON, like GeoJSON, makes every ring after a polygon's first one a
  hole, and the data agree: in the four downtown tiles all but 6 of the 6,245 inner rings lie inside
  their outer ring, their median area is 5 m^2 (light wells), the largest are courtyards, and 26 of
  them contain another footprint (a building standing in a courtyard), which only makes sense for
  holes. ``fill_holes=True`` drops them (outer outlines only), e.g. to compare with a source that
  does not map light wells.
- **About a quarter of the rings are invalid** (self-intersections left by the tiles' coordinate
  quantisation). They are repaired with GEOS's ``make_valid(method="structure")``, which keeps the
  areal meaning of outer rings and holes; repair slivers under ``min_area_m2`` (1 m^2) go.
- **Neighbouring tiles overlap:** a footprint that straddles a tile edge is stored in both tiles,
  quantised differently. Polygons from different tiles whose IoU reaches
  ``duplicate_iou`` (0.9) are one building; the copy from the later tile is dropped.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Iterable
from pathlib import Path

import geopandas as gpd
import numpy as np
import shapely

from curbside import __version__, settings
from curbside.errors import CurbsideInputError
from curbside.osmseg.compare import map_extent
from curbside.osmseg.mapio import MapLayers
from curbside.projection import WGS84, utm_crs_for

log = logging.getLogger(__name__)

#: Attribution of the DataSF building footprints.
DATASF_ATTRIBUTION = "Building footprints: City and County of San Francisco, DataSF 2013 (ODC PDDL)"


def _read_tile(path: Path, bbox: tuple[float, float, float, float] | None) -> gpd.GeoSeries:
    if not path.is_file():
        raise CurbsideInputError(path, "no such DataSF tile")
    try:
        gdf = gpd.read_file(path, bbox=bbox)
    except Exception as exc:  # noqa: BLE001 - pyogrio/GDAL raise several types for unreadable files
        reason = str(exc).splitlines()[0].split("; ")[0]
        raise CurbsideInputError(path, f"not readable as TopoJSON ({reason})") from None
    if gdf.crs is not None and not gdf.crs.equals(WGS84):
        raise CurbsideInputError(path, f"expected WGS84 lon/lat, the file declares {gdf.crs.name}")
    geoms = gdf.geometry[gdf.geometry.notna()]
    geoms = geoms[geoms.geom_type.isin(["Polygon", "MultiPolygon"])]
    if len(geoms):
        minx, miny, maxx, maxy = geoms.total_bounds
        if not (-180 <= minx <= maxx <= 180 and -90 <= miny <= maxy <= 90):
            raise CurbsideInputError(path, "coordinates are not WGS84 lon/lat degrees")
    return gpd.GeoSeries(geoms.to_numpy(), crs=WGS84)


def _drop_cross_tile_duplicates(geoms: np.ndarray, tile: np.ndarray, min_iou: float) -> np.ndarray:
    """Mask of the polygons to keep: the first copy of each building seen in several tiles."""
    tree = shapely.STRtree(geoms)
    left, right = tree.query(geoms, predicate="intersects")
    pair = (left < right) & (tile[left] != tile[right])
    left, right = left[pair], right[pair]
    inter = shapely.area(shapely.intersection(geoms[left], geoms[right]))
    union = shapely.area(geoms[left]) + shapely.area(geoms[right]) - inter
    duplicate = inter >= min_iou * union
    keep = np.ones(len(geoms), bool)
    keep[right[duplicate]] = False
    return keep


def _read_tiles(
    paths: list[Path], bbox: tuple[float, float, float, float] | None
) -> tuple[np.ndarray, np.ndarray]:
    """The WGS84 footprints of all tiles (those that intersect ``bbox``) and the tile index of each."""
    if not paths:
        raise CurbsideInputError("TILE", "no DataSF tile given")
    tiles = [_read_tile(p, bbox) for p in paths]
    geoms = np.concatenate([t.to_numpy() for t in tiles])
    tile = np.repeat(np.arange(len(tiles)), [len(t) for t in tiles])
    if bbox is not None:
        inside = shapely.intersects(geoms, shapely.box(*bbox))
        geoms, tile = geoms[inside], tile[inside]
    if len(geoms) == 0:
        where = f" in bbox {list(bbox)}" if bbox is not None else ""
        raise CurbsideInputError(", ".join(p.name for p in paths), f"no building footprint{where}")
    return geoms, tile


def read_datasf(
    paths: str | os.PathLike[str] | Iterable[str | os.PathLike[str]],
    bbox: tuple[float, float, float, float] | None = None,
    *,
    fill_holes: bool = False,
    duplicate_iou: float = 0.9,
    min_area_m2: float = 1.0,
) -> MapLayers:
    """Read DataSF building-footprint tiles into a building-only map.

    Parameters
    ----------
    paths
        One or more TopoJSON tiles (any vector file GDAL reads with polygons in WGS84 also works).
    bbox
        Optional WGS84 ``(west, south, east, north)``: keep the footprints that intersect it (whole,
        not clipped; :func:`curbside.osmseg.compare.compare_maps` clips to the common extent).
    fill_holes
        Drop inner rings (light wells, courtyards) and keep outer outlines only.
    duplicate_iou
        Footprints from different tiles overlapping with at least this IoU are one building twice.
    min_area_m2
        Polygon parts below this area, left by repairing self-intersecting rings, are dropped.

    Returns
    -------
    MapLayers
        Class ``building`` only, in the local UTM CRS. ``meta`` holds ``source`` (tile names),
        ``bbox`` (the given one, else the footprints' bounds), ``attribution``, ``buildings_source``
        (``"datasf"``), ``generator`` and ``params``.

    Raises
    ------
    CurbsideInputError
        A missing or unreadable tile, coordinates that are not lon/lat degrees, or no footprint (in
        the bbox).
    ValueError
        ``duplicate_iou`` outside (0, 1] or a negative ``min_area_m2``.
    """
    if not (0 < duplicate_iou <= 1 and min_area_m2 >= 0):
        raise ValueError(f"need 0 < duplicate_iou <= 1 and min_area_m2 >= 0, got {duplicate_iou}, "
                         f"{min_area_m2}")
    if isinstance(paths, (str, os.PathLike)):
        paths = [paths]
    paths = [Path(p) for p in paths]
    geoms, tile = _read_tiles(paths, bbox)
    west, south, east, north = shapely.total_bounds(geoms)
    crs = utm_crs_for((west + east) / 2, (south + north) / 2)
    metric = gpd.GeoSeries(geoms, crs=WGS84).to_crs(crs).to_numpy()
    n_invalid = int((~shapely.is_valid(metric)).sum())
    metric = shapely.make_valid(metric, method="structure", keep_collapsed=False)
    parts, owner = shapely.get_parts(metric, return_index=True)
    if fill_holes:
        parts = shapely.polygons(shapely.get_exterior_ring(parts))
    big = shapely.area(parts) >= min_area_m2
    parts, part_tile = parts[big], tile[owner[big]]
    keep = _drop_cross_tile_duplicates(parts, part_tile, duplicate_iou)
    log.info(
        "DataSF: %d features -> %d polygons (%d repaired, %d slivers dropped, %d cross-tile duplicates)",
        len(geoms), int(keep.sum()), n_invalid, int((~big).sum()), int((~keep).sum()),
    )
    n = int(keep.sum())
    gdf = gpd.GeoDataFrame(
        {"class": ["building"] * n, "segment_id": [None] * n, "street": [None] * n, "side": [None] * n},
        geometry=parts[keep],
        crs=crs,
    )
    meta = {
        "source": [p.name for p in paths],
        "bbox": list(bbox) if bbox is not None else [float(v) for v in (west, south, east, north)],
        "attribution": DATASF_ATTRIBUTION,
        "buildings_source": "datasf",
        "generator": f"curbside {__version__} (osmseg import-datasf)",
        "params": {"inner_rings": "outer outlines only" if fill_holes else "holes",
                   "duplicate_iou": duplicate_iou, "min_area_m2": min_area_m2},
    }
    return MapLayers(gdf.reset_index(drop=True), meta)


def over_streets_of(buildings: MapLayers, streets_map: MapLayers) -> MapLayers:
    """DataSF's buildings with another map's streets, crosswalks and sidewalks: the map-source comparison's
    third map (the OSM map with its buildings replaced).

    Parameters
    ----------
    buildings
        :func:`read_datasf`'s map.
    streets_map
        A map of the curbside schema (``osmseg build``): every class but ``building`` is kept.

    Returns
    -------
    MapLayers
        In ``streets_map``'s CRS, its extent (:func:`~curbside.osmseg.compare.map_extent`: its ``bbox``,
        else its polygons' bounds) as ``bbox``, ``source`` and ``attribution`` naming both sources,
        ``buildings_source`` ``"datasf"``.
    """
    import pandas as pd

    rest = streets_map.gdf[streets_map.gdf["class"] != "building"]
    gdf = gpd.GeoDataFrame(
        pd.concat([buildings.gdf.to_crs(streets_map.crs), rest], ignore_index=True), crs=streets_map.crs
    )
    meta = {
        **streets_map.meta,
        "bbox": list(map_extent(streets_map)),
        "source": "DataSF 2013 buildings + " + str(streets_map.meta.get("source", "OSM")),
        "buildings_source": "datasf",
        "attribution": "Buildings: DataSF 2013 (ODC PDDL); streets and sidewalks: "
        + str(streets_map.meta.get("attribution") or settings.osm_attribution),
    }
    return MapLayers(gdf, meta)


def read_datasf_over(
    tiles: str | os.PathLike | Iterable[str | os.PathLike],
    streets_map: MapLayers,
    bbox: tuple[float, float, float, float] | None = None,
    *,
    fill_holes: bool = False,
) -> MapLayers:
    """DataSF's buildings read over ``streets_map`` (:func:`over_streets_of`), within ``bbox`` (default:
    the map's extent, so a hand-made map without a metadata ``bbox`` does not get the whole city)."""
    if bbox is None:
        bbox = map_extent(streets_map)
    return over_streets_of(read_datasf(tiles, bbox=bbox, fill_holes=fill_holes), streets_map)
