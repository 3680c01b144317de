"""``osmseg build``: OpenStreetMap -> building, street, crosswalk and sidewalk polygons.

:func:`build_map` picks the source (a file, the bundled extract or Overpass), reads it into an
:class:`~curbside.osmseg.reader.OsmData` and runs the stages, one module each:
:mod:`~curbside.osmseg.buildings`, :mod:`~curbside.osmseg.streets`,
:mod:`~curbside.osmseg.crosswalks`, :mod:`~curbside.osmseg.sidewalks`. Precedence makes the classes
disjoint: buildings (after passages are carved) win over crosswalks, crosswalks over street, and
sidewalks take only what none of the three cover.
"""

from __future__ import annotations

import logging
import math
import sys
from pathlib import Path

import geopandas as gpd
import numpy as np
import pandas as pd
import shapely
from tqdm import tqdm

import curbside
from curbside import settings
from curbside.configio import to_dict
from curbside.errors import CurbsideInputError
from curbside.osmseg.buildings import buildings as derive_buildings
from curbside.osmseg.clipped import covered_bbox
from curbside.osmseg.config import READ_MARGIN_M, SegmentationConfig
from curbside.osmseg.crosswalks import crosswalks as derive_crosswalks
from curbside.osmseg.inputs import BBox, check_bbox
from curbside.osmseg.mapio import MapLayers
from curbside.osmseg.overlay import polygons_only, subtract
from curbside.osmseg.reader import OsmData, bbox_polygon, clip_to_bbox, declared_bounds, read_osm_file
from curbside.osmseg.sidewalks import sidewalk_segments
from curbside.osmseg.streets import carriageways, mapped_sidewalks, share_of_length_inside
from curbside.projection import LocalFrame

log = logging.getLogger(__name__)

#: The WARNING of a map without buildings (the source, where).
NO_BUILDINGS = (
    "%s: the map has no buildings %s: the filter's building likelihood (weight 0 inside a building) "
    "does nothing on it, so no wall ever stops a particle"
)


def _inside(inner: BBox, outer: BBox) -> bool:
    return outer[0] <= inner[0] and outer[1] <= inner[1] and inner[2] <= outer[2] and inner[3] <= outer[3]


def load_osm(bbox: BBox | None, osm_file: str | Path | None) -> tuple[OsmData, BBox | None]:
    """Read the OSM elements for a build: a file, the bundled extract, or Overpass.

    Returns
    -------
    (OsmData, bbox)
        ``bbox`` is the area to clip to: the one asked for (with a file that declares bounds, only
        its part inside them: :func:`~curbside.osmseg.clipped.covered_bbox`), else the bounds the
        file declares (``<bounds>``, PBF header box), else None (the whole file).

    Raises
    ------
    CurbsideInputError
        Bad bbox, or one that lies wholly outside the bounds the file declares (found from the
        file's header before any element is read); Overpass failing (unreachable with a bbox partly
        outside the bundled extract: how far, and the extract's bounds, which build offline).
    """
    if bbox is not None:
        bbox = check_bbox(bbox)
    if osm_file is not None:
        # The header says what the file covers: a bbox outside it is refused before reading.
        covered = None if bbox is None else covered_bbox(bbox, declared_bounds(osm_file), str(osm_file))
        osm = read_osm_file(osm_file, bbox)
        if bbox is None and osm.bounds is not None:
            log.info("clipping to the bounds %s declares: %s", osm.source, osm.bounds)
            return clip_to_bbox(osm, osm.bounds, READ_MARGIN_M), osm.bounds
        if covered is not None and covered != bbox:
            return clip_to_bbox(osm, covered, READ_MARGIN_M), covered
        return osm, bbox
    if bbox is None:
        bbox = settings.default_bbox
    if _inside(bbox, settings.default_extract_bbox):
        return read_osm_file(settings.default_osm_file, bbox), bbox
    from curbside.osmseg.overpass import OverpassUnreachableError, fetch_overpass

    try:
        return fetch_overpass(bbox), bbox
    except OverpassUnreachableError as exc:
        problem = _past_extract(bbox, settings.default_extract_bbox, exc.source)
        if problem is None:
            raise
        raise CurbsideInputError(f"--bbox {_words(bbox)}", problem) from None


def _words(values: BBox) -> str:
    return " ".join(f"{v:.10g}" for v in values)


def _past_extract(bbox: BBox, extract: BBox, url: str) -> str | None:
    """The error for a ``bbox`` partly outside the bundled extract when Overpass (``url``) cannot be
    reached: how far it leaves the extract, and the bounds within which a bbox builds offline. ``None``
    when the two do not overlap (the extract is then no help)."""
    west, south, east, north = bbox
    if west >= extract[2] or east <= extract[0] or south >= extract[3] or north <= extract[1]:
        return None
    m_per_deg_lat = 111_320.0
    m_per_deg_lon = m_per_deg_lat * math.cos(math.radians((south + north) / 2))
    past_m = {
        "west": (extract[0] - west) * m_per_deg_lon, "south": (extract[1] - south) * m_per_deg_lat,
        "east": (east - extract[2]) * m_per_deg_lon, "north": (north - extract[3]) * m_per_deg_lat,
    }  # fmt: skip
    sides = [f"{f'{m:,.0f}' if m >= 1 else 'under 1'} m past its {side} bound"
             for side, m in past_m.items() if m > 0]  # fmt: skip
    reach = " and ".join([", ".join(sides[:-1]), sides[-1]] if len(sides) > 1 else sides)
    within = (max(west, extract[0]), max(south, extract[1]), min(east, extract[2]), min(north, extract[3]))
    return (
        f"reaches past the bundled extract ({reach}), so it needs Overpass ({url}), which cannot be reached "
        f"(no network?); a bbox within the extract's bounds (W S E N: {_words(extract)}) builds offline, "
        f"e.g. --bbox {_words(within)}; or build offline with --osm FILE"
    )


def _layer(cls: str, geoms, crs, min_area_m2: float) -> gpd.GeoDataFrame:
    """Single polygons of one class (multi-part results exploded, slivers under ``min_area_m2`` dropped)."""
    parts = polygons_only(shapely.make_valid(np.asarray(geoms, dtype=object)), min_area_m2)
    return gpd.GeoDataFrame({"class": [cls] * len(parts)}, geometry=parts, crs=crs)


def derive_layers(osm: OsmData, config: SegmentationConfig | None = None) -> gpd.GeoDataFrame:
    """Run the derivation stages on OSM elements.

    Parameters
    ----------
    osm
        Elements in a metric CRS.
    config
        Widths and rules (default :class:`~curbside.osmseg.config.SegmentationConfig`).

    Returns
    -------
    geopandas.GeoDataFrame
        Columns ``class``, ``segment_id``, ``street``, ``side``, ``facing_deg``, ``geometry`` (CRS of
        ``osm``).
    """
    config = config or SegmentationConfig()
    min_area = config.min_polygon_area_m2
    stages = tqdm(total=4, desc="osmseg build", unit="stage", disable=not sys.stderr.isatty(), leave=False)
    with stages:
        blds = derive_buildings(osm.areas, osm.ways, config).geometry.values
        stages.update()
        cways = carriageways(osm.ways, blds, config)
        stages.update()
        walks = derive_crosswalks(osm.ways, osm.nodes, cways, config)
        walks = polygons_only(subtract(walks, blds), min_area)
        through = cways.surface[~cways.minor]
        segments = sidewalk_segments(
            cways.roads, np.concatenate([through, blds, walks]), config=config, buildings=blds,
            mapped=cways.sidewalks,
        )
        stages.update()
        # Sidewalks run on across driveways and parking-aisle mouths.
        minor = subtract(cways.surface[cways.minor], segments.geometry.values)
        # An opened median (refuge) is free space; where a crosswalk crosses it, crosswalk.
        street = subtract(np.concatenate([through, minor]), np.concatenate([blds, walks, cways.refuges]))
        stages.update()
    frames = [
        _layer("building", blds, osm.crs, min_area),
        _layer("street", street, osm.crs, min_area),
        _layer("crosswalk", walks, osm.crs, min_area),
        segments.drop(columns="osm_id").assign(**{"class": "sidewalk"}),
    ]
    gdf = gpd.GeoDataFrame(pd.concat(frames, ignore_index=True), geometry="geometry", crs=osm.crs)
    for col in ("segment_id", "street", "side"):
        if col not in gdf:
            gdf[col] = None
        gdf[col] = gdf[col].astype(object).where(gdf[col].notna(), None)
    gdf["facing_deg"] = gdf["facing_deg"].astype(float)
    return gdf[["class", "segment_id", "street", "side", "facing_deg", "geometry"]]


def _clip_layers(gdf: gpd.GeoDataFrame, window: shapely.Polygon, min_area_m2: float) -> gpd.GeoDataFrame:
    """The layers cut to ``window``: single polygons of at least ``min_area_m2``."""
    gdf = gdf.set_geometry(shapely.intersection(gdf.geometry.values, window))
    gdf = gdf.explode(index_parts=False)
    gdf = gdf[gdf.geom_type == "Polygon"]
    gdf = gdf[gdf.area >= min_area_m2]
    # A sidewalk cut in two by the bbox edge keeps one id per part.
    dup = gdf["segment_id"].notna() & gdf["segment_id"].duplicated(keep=False)
    gdf.loc[dup, "segment_id"] = (
        gdf.loc[dup, "segment_id"] + "." + gdf[dup].groupby("segment_id").cumcount().astype(str)
    )
    return gdf


def _extent(gdf: gpd.GeoDataFrame) -> BBox:
    """(west, south, east, north) degrees of the layers' extent."""
    minx, miny, maxx, maxy = gdf.total_bounds
    corners_x, corners_y = np.array([minx, maxx, minx, maxx]), np.array([miny, miny, maxy, maxy])
    lon, lat = LocalFrame(gdf.crs).to_lonlat(corners_x, corners_y)
    return float(lon.min()), float(lat.min()), float(lon.max()), float(lat.max())


def build_map(
    bbox: BBox | None = None,
    osm_file: str | Path | None = None,
    *,
    config: SegmentationConfig | None = None,
) -> MapLayers:
    """Derive map layers (building, street, crosswalk, sidewalk) from OpenStreetMap.

    Parameters
    ----------
    bbox
        (west, south, east, north) WGS84 degrees. ``None``: the whole ``osm_file``, or
        ``settings.default_bbox`` when no file is given.
    osm_file
        ``.osm``, ``.osm.bz2``, ``.osm.gz`` or ``.osm.pbf``. ``None``: the bundled extract when the
        bbox lies inside ``settings.default_extract_bbox``, else Overpass. With no
        ``bbox`` the map is clipped to the bounds the file declares, if it declares any.
    config
        Widths and rules (default :class:`~curbside.osmseg.config.SegmentationConfig`).

    Returns
    -------
    MapLayers
        Polygons in local UTM; ``meta`` holds ``source``, ``bbox`` (the area the map covers: with a
        file, the bbox asked for clipped to the bounds the file declares, and then ``bbox_asked``
        too), ``osm_timestamp``, ``generator``, ``attribution``, ``buildings_source`` (``"osm"``),
        ``params`` (``config`` as a dict), ``sidewalk_ways_km`` (the length of the separately mapped
        sidewalks inside the map) and the shares of it inside buildings and inside sidewalk segments,
        ``sidewalk_ways_in_buildings`` and ``sidewalk_ways_in_segments``
        (:func:`~curbside.osmseg.streets.share_of_length_inside`). A map without buildings
        is built with a WARNING: the filter's building likelihood does nothing on it.

    Raises
    ------
    CurbsideInputError
        Bad bbox, missing / unreadable / unsupported file, a bbox wholly outside the bounds the
        file declares, or an area without OSM data.
    """
    config = config or SegmentationConfig()
    osm, clip_bbox = load_osm(bbox, osm_file)
    source = str(osm_file) if osm_file is not None else osm.source
    from_declared_bounds = bbox is None and osm_file is not None and clip_bbox is not None
    where = "in this area"
    if from_declared_bounds:
        where = f"inside the bounds the file declares {list(clip_bbox)}"
    if len(osm.ways) == 0 and len(osm.areas) == 0:
        raise CurbsideInputError(source, f"no highways or buildings {where}")
    gdf = derive_layers(osm, config)
    sidewalk_lines = mapped_sidewalks(osm.ways, config).geometry.values
    if clip_bbox is not None:
        window = bbox_polygon(clip_bbox, osm.crs)
        sidewalk_lines = shapely.intersection(sidewalk_lines, window)
        gdf = _clip_layers(gdf, window, config.min_polygon_area_m2)
    gdf = gdf.reset_index(drop=True)
    if len(gdf) == 0:
        raise CurbsideInputError(source, f"no buildings or streets {where}")
    if not (gdf["class"] == "building").any():
        log.warning(NO_BUILDINGS, source, where)
    if clip_bbox is None:
        clip_bbox = _extent(gdf)
        # The sidewalk ways of a file without bounds run on past the map's polygons.
        sidewalk_lines = shapely.intersection(sidewalk_lines, shapely.box(*gdf.total_bounds))
    asked = None if bbox is None else check_bbox(bbox)
    meta = {
        "source": osm.source,
        "bbox": [round(v, 7) for v in clip_bbox],
        # With a file, the map covers only the part of the bbox asked for inside its bounds.
        **({"bbox_asked": list(asked)} if asked is not None and asked != tuple(clip_bbox) else {}),
        "osm_timestamp": osm.timestamp,
        "generator": f"curbside {curbside.__version__}",
        "attribution": settings.osm_attribution,
        "buildings_source": "osm",
        "params": to_dict(config),
        "sidewalk_ways_in_buildings": round(
            share_of_length_inside(sidewalk_lines, gdf.geometry.values[gdf["class"] == "building"]), 4
        ),
        "sidewalk_ways_in_segments": round(
            share_of_length_inside(sidewalk_lines, gdf.geometry.values[gdf["class"] == "sidewalk"]), 4
        ),
        "sidewalk_ways_km": round(float(shapely.length(sidewalk_lines).sum()) / 1000, 2),
    }
    counts = gdf["class"].value_counts().to_dict()
    log.info("built %s", ", ".join(f"{k}: {v}" for k, v in counts.items()))
    return MapLayers(gdf, meta)
