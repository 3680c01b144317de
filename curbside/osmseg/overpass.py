"""Stage 1 (network source): OSM elements of a bbox from Overpass, through osmnx.

osmnx downloads and caches the response (``settings.cache_dir / "overpass"``) and builds a feature
table; :func:`fetch_overpass` converts it into the :class:`~curbside.osmseg.reader.OsmData` that the
pyosmium file reader produces, so the derivation is shared.
"""

from __future__ import annotations

import logging

import geopandas as gpd
import numpy as np
import osmnx as ox
import requests
import shapely
from osmnx._errors import InsufficientResponseError, ResponseStatusCodeError

from curbside import settings
from curbside.errors import CurbsideInputError
from curbside.osmseg.reader import TAG_KEYS, OsmData, clip_to_bbox, frame_for, make_table

log = logging.getLogger(__name__)

#: The Overpass tag query: every building and every highway element.
OVERPASS_TAGS: dict[str, bool] = {"building": True, "highway": True}


def _records(gdf: gpd.GeoDataFrame) -> list[dict[str, str]]:
    keys = [k for k in TAG_KEYS if k in gdf]
    table = gdf[keys].astype(object)
    table = table.where(table.notna(), None)
    return [{k: v for k, v in row.items() if v is not None} for row in table.to_dict("records")]


def features_to_osmdata(features: gpd.GeoDataFrame, bbox: tuple[float, float, float, float]) -> OsmData:
    """Convert an osmnx feature table (WGS84, index ``(element, id)``) into :class:`OsmData`.

    Parameters
    ----------
    features
        As returned by ``osmnx.features_from_bbox``.
    bbox
        (west, south, east, north): sets the UTM zone.
    """
    frame = frame_for(bbox)
    gdf = features.to_crs(frame.crs)
    element = gdf.index.get_level_values(0).astype(str).to_numpy()
    osm_id = gdf.index.get_level_values(1).to_numpy()
    geom_type = gdf.geom_type.to_numpy()
    highway = gdf["highway"].notna().to_numpy() if "highway" in gdf else np.zeros(len(gdf), bool)
    building = gdf["building"].notna().to_numpy() if "building" in gdf else np.zeros(len(gdf), bool)
    geoms = np.asarray(gdf.geometry.values, dtype=object)

    way_mask = (element == "way") & highway & (geom_type == "LineString")
    # osmnx turns closed highway ways tagged area=yes into polygons: keep their outline as the way.
    closed_highway = (element == "way") & highway & ~building & (geom_type == "Polygon")
    rings = shapely.get_exterior_ring(geoms[closed_highway])
    ring_xy, ring_i = shapely.get_coordinates(rings, return_index=True)
    outlines = shapely.linestrings(ring_xy, indices=ring_i) if len(ring_i) else np.array([], dtype=object)
    way_geoms = np.concatenate([geoms[way_mask], outlines])
    ways = make_table(
        np.concatenate([osm_id[way_mask], osm_id[closed_highway]]),
        way_geoms,
        _records(gdf[way_mask]) + _records(gdf[closed_highway]),
        frame.crs,
    )
    area_mask = building & np.isin(geom_type, ["Polygon", "MultiPolygon"])
    prefix = np.where(element[area_mask] == "relation", "r", "w")
    areas = make_table(
        [f"{p}{i}" for p, i in zip(prefix, osm_id[area_mask], strict=True)],
        geoms[area_mask],
        _records(gdf[area_mask]),
        frame.crs,
    )
    node_mask = (element == "node") & highway & (geom_type == "Point")
    if "highway" in gdf:
        node_mask &= (gdf["highway"] == "crossing").to_numpy()
    nodes = make_table(osm_id[node_mask], geoms[node_mask], _records(gdf[node_mask]), frame.crs)
    return OsmData(ways, areas, nodes, source="overpass", timestamp=None)


def fetch_overpass(bbox: tuple[float, float, float, float], *, margin_m: float = 60.0) -> OsmData:
    """Download buildings and highways of a bbox from Overpass (osmnx, cached on disk).

    Parameters
    ----------
    bbox
        (west, south, east, north) WGS84 degrees, already validated.
    margin_m
        The query covers this much more on every side, so that sidewalks at the edge are complete.

    Returns
    -------
    OsmData

    Raises
    ------
    CurbsideInputError
        No OSM data in the area, or the Overpass request failed.
    """
    west, south, east, north = bbox
    pad_lat = margin_m / 111_320.0
    pad_lon = pad_lat / max(np.cos(np.radians((south + north) / 2)), 1e-6)
    query = (west - pad_lon, south - pad_lat, east + pad_lon, north + pad_lat)
    ox.settings.cache_folder = str(settings.cache_dir / "overpass")
    ox.settings.use_cache = True
    log.info("querying Overpass at %s for %s", ox.settings.overpass_url, query)
    try:
        features = ox.features_from_bbox(query, OVERPASS_TAGS)
    except InsufficientResponseError:
        raise CurbsideInputError("overpass", f"no OSM buildings or highways in bbox {list(bbox)}") from None
    except (requests.RequestException, ResponseStatusCodeError) as exc:
        raise CurbsideInputError(
            ox.settings.overpass_url, f"Overpass request failed ({type(exc).__name__})"
        ) from None
    return clip_to_bbox(features_to_osmdata(features, bbox), bbox, margin_m)
