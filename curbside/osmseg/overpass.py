"""Stage 1 (network source): OSM elements of a bbox from Overpass, through osmnx.

osmnx downloads and caches the response (``settings.cache_dir / "overpass"``, beside the other
caches of :mod:`curbside.cache`) and builds a feature table; :func:`fetch_overpass` converts it into
the :class:`~curbside.osmseg.reader.OsmData` that the pyosmium file reader produces, so the
derivation is shared.
"""

from __future__ import annotations

import contextlib
import logging
from collections.abc import Iterator
from pathlib import Path

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


def overpass_reachable(url: str, timeout_s: float) -> bool:
    """Whether the Overpass server at ``url`` answers its status query within ``timeout_s``.

    Any HTTP answer counts (a server that lacks the status endpoint is still there).
    """
    try:
        requests.get(f"{url.rstrip('/')}/status", timeout=timeout_s)
    except requests.RequestException as exc:
        log.info("Overpass at %s is unreachable (%s)", url, type(exc).__name__)
        return False
    return True


@contextlib.contextmanager
def _osmnx_settings(**values) -> Iterator[None]:
    """Set ``osmnx.settings`` attributes for one query and restore them after."""
    saved = {name: getattr(ox.settings, name) for name in values}
    for name, value in values.items():
        setattr(ox.settings, name, value)
    try:
        yield
    finally:
        for name, value in saved.items():
            setattr(ox.settings, name, value)


def fetch_overpass(bbox: tuple[float, float, float, float], *, margin_m: float = 60.0) -> OsmData:
    """Download buildings and highways of a bbox from Overpass (osmnx, cached on disk).

    The server is asked for its status first, with ``settings.overpass_connect_timeout_s``: when it
    does not answer (no network), osmnx's rate-limit pause (60 s when the status is unknown) is
    skipped and the query gets the same short timeout, so the build fails in seconds -- or is
    answered from the cache, whose keys do not depend on either timeout.

    Parameters
    ----------
    bbox
        (west, south, east, north) WGS84 degrees, already validated.
    margin_m
        The query covers this much more on every side, so that sidewalks at the edge are complete.

    Returns
    -------
    OsmData
        ``bounds`` is ``bbox``.

    Raises
    ------
    CurbsideInputError
        No OSM data in the area, Overpass unreachable, or the request failed.
    """
    west, south, east, north = bbox
    pad_lat = margin_m / 111_320.0
    pad_lon = pad_lat / max(np.cos(np.radians((south + north) / 2)), 1e-6)
    query = (west - pad_lon, south - pad_lat, east + pad_lon, north + pad_lat)
    url = ox.settings.overpass_url
    reachable = overpass_reachable(url, settings.overpass_connect_timeout_s)
    query_settings = _osmnx_settings(
        cache_folder=str(Path(settings.cache_dir) / "overpass"),
        use_cache=True,
        # The server-side timeout is written into the query (and so into osmnx's cache key): fixed.
        overpass_settings=f"[out:json][timeout:{int(settings.overpass_timeout_s)}]{{maxsize}}",
        requests_timeout=settings.overpass_timeout_s if reachable else settings.overpass_connect_timeout_s,
        overpass_rate_limit=ox.settings.overpass_rate_limit and reachable,
    )
    log.info("querying Overpass at %s for %s", url, query)
    try:
        with query_settings:
            features = ox.features_from_bbox(query, OVERPASS_TAGS)
    except InsufficientResponseError:
        raise CurbsideInputError("overpass", f"no OSM buildings or highways in bbox {list(bbox)}") from None
    except (requests.RequestException, ResponseStatusCodeError) as exc:
        if not reachable:
            problem = "cannot reach the Overpass server (no network?); build offline with --osm FILE"
        else:
            problem = f"Overpass request failed ({type(exc).__name__})"
        raise CurbsideInputError(url, problem) from None
    data = features_to_osmdata(features, bbox)
    data.bounds = bbox
    return clip_to_bbox(data, bbox, margin_m)
