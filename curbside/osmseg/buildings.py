"""Stage 2: impenetrable building footprints, with walkable passages carved out.

A building is a ``building=*`` closed way or multipolygon relation, except structures a pedestrian
walks under or that are not at street level (:data:`NOT_IMPENETRABLE`, underground buildings).
Every street-level highway way that runs through a footprint -- ``tunnel=building_passage``, covered
footways, indoor corridors, platforms and roads through a ground floor such as the Salesforce Transit
Center's bus plaza -- carves a passage as wide as the way out of it. In stations
(:data:`STATION_BUILDINGS`) platforms and building-passage busways and footways carve on every level:
the Transit Center's bus deck, where the paper's paths 5 and 6 ran, is one floor up.
"""

from __future__ import annotations

import geopandas as gpd
import numpy as np
import shapely

from curbside.osmseg.config import SegmentationConfig
from curbside.osmseg.overlay import subtract_each
from curbside.osmseg.streets import carriageway_width, ground_level
from curbside.osmseg.tags import column, first_number, is_in, metres

#: ``building`` values that are not impenetrable: open structures and non-buildings.
NOT_IMPENETRABLE: frozenset[str] = frozenset({"roof", "carport", "canopy", "no", "bridge"})

#: ``building`` values of stations: their platforms, busways and passages carve on every level (a
#: pedestrian on a bus deck walks above its ground floor, and the map has only one level).
STATION_BUILDINGS: frozenset[str] = frozenset({"transportation", "train_station"})

#: ``highway`` values that carve a station on any level (platforms always; the others when mapped as
#: ``tunnel=building_passage``).
STATION_PASSAGE_HIGHWAYS: frozenset[str] = frozenset({"platform", "busway", "footway", "pedestrian",
                                                      "corridor", "service"})  # fmt: skip

#: ``highway`` values that never carve a passage (they connect floors, not ground-floor space).
NON_PASSAGE_HIGHWAYS: frozenset[str] = frozenset({"steps", "elevator", "escalator", "construction",
                                                  "proposed"})  # fmt: skip


def footprint_mask(areas: gpd.GeoDataFrame) -> np.ndarray:
    """Mask of the areas that are impenetrable buildings.

    Excluded: :data:`NOT_IMPENETRABLE` values, ``building:part``, ``location=underground``, and
    ``layer<0`` unless the building also has a positive ``height`` or ``building:levels`` (the
    Salesforce Transit Center is tagged ``layer=-1`` for its underground train box but stands 30 m
    tall). ``building=construction`` stays: building sites are fenced off.
    """
    building = column(areas, "building")
    layer = first_number(column(areas, "layer"))
    levels = first_number(column(areas, "building:levels"))
    above_ground = (metres(column(areas, "height")) > 0) | (levels > 0)
    underground = is_in(column(areas, "location"), ["underground"]) | ((layer < 0) & ~above_ground)
    return (
        building.notna().to_numpy()
        & ~is_in(building, NOT_IMPENETRABLE)
        & column(areas, "building:part").isna().to_numpy()
        & ~underground
        & ~shapely.is_empty(areas.geometry.values)
    )


def passage_ways(ways: gpd.GeoDataFrame, config: SegmentationConfig) -> gpd.GeoDataFrame:
    """Street-level highway ways that may pass through buildings, with their width ``width_m``.

    Roads use their carriageway width; other ways their ``width`` tag, else
    ``config.passage_width_m``.
    """
    mask = ground_level(ways) & ~is_in(column(ways, "highway"), NON_PASSAGE_HIGHWAYS)
    return _with_width(ways[mask], config)


def station_passage_ways(ways: gpd.GeoDataFrame, config: SegmentationConfig) -> gpd.GeoDataFrame:
    """Ways through a station's concourses and bus decks, on any level, with ``width_m``.

    Platforms and busways, and footways mapped as ``tunnel=building_passage``, except bridges.
    """
    highway = column(ways, "highway")
    mask = (
        is_in(highway, STATION_PASSAGE_HIGHWAYS)
        & (is_in(highway, ["platform"]) | is_in(column(ways, "tunnel"), ["building_passage"]))
        & ~(column(ways, "bridge").notna() & (column(ways, "bridge") != "no")).to_numpy()
    )
    return _with_width(ways[mask], config)


def _with_width(candidates: gpd.GeoDataFrame, config: SegmentationConfig) -> gpd.GeoDataFrame:
    road_width, _ = carriageway_width(candidates, config)
    tagged = metres(column(candidates, "width"))
    other_width = np.where(np.isnan(tagged), config.passage_width_m, tagged)
    width = np.where(np.isnan(road_width), other_width, road_width)
    return candidates.assign(width_m=width)


def buildings(
    areas: gpd.GeoDataFrame, ways: gpd.GeoDataFrame, config: SegmentationConfig | None = None
) -> gpd.GeoDataFrame:
    """Impenetrable building footprints with passages carved out.

    Parameters
    ----------
    areas, ways
        Tables of an :class:`~curbside.osmseg.reader.OsmData`.
    config
        Passage widths, island and sliver sizes (default
        :class:`~curbside.osmseg.config.SegmentationConfig`).

    Returns
    -------
    geopandas.GeoDataFrame
        One row per remaining polygon: ``osm_id``, ``carved_m2`` (the area its building's passages
        removed, islands included) and a valid Polygon ``geometry``; no two polygons overlap.
    """
    config = config or SegmentationConfig()
    footprints = areas[footprint_mask(areas)].reset_index(drop=True)
    geoms = shapely.make_valid(footprints.geometry.values)
    station = is_in(column(footprints, "building"), STATION_BUILDINGS)
    carved = np.zeros(len(geoms))
    carvings = (
        (passage_ways(ways, config), np.ones(len(geoms), bool)),
        (station_passage_ways(ways, config), station),
    )
    for passages, which in carvings:
        targets = np.flatnonzero(which)
        if len(passages) == 0 or len(targets) == 0:
            continue
        tree = shapely.STRtree(geoms[targets])
        way_i, _ = tree.query(passages.geometry.values, predicate="intersects")
        if len(way_i) == 0:
            continue
        through = passages.iloc[np.unique(way_i)]
        cut = shapely.buffer(through.geometry.values, through["width_m"].to_numpy() / 2, cap_style="flat")
        cut_union = shapely.union_all(cut)
        hit = targets[np.unique(tree.query(cut_union, predicate="intersects"))]
        before = shapely.area(geoms[hit])
        geoms[hit] = shapely.difference(geoms[hit], cut_union)
        carved[hit] += before - shapely.area(geoms[hit])
    parts, owner = shapely.get_parts(shapely.make_valid(geoms), return_index=True)
    area = shapely.area(parts)
    # Slivers and islands left between passages (the strips between a bus plaza's platforms and
    # busways) are open floor, not walls.
    thickness = 2 * area / np.maximum(shapely.length(parts), 1e-9)
    island = (carved[owner] > 0) & (
        (area < config.passage_island_area_m2) | (thickness < config.passage_island_thickness_m)
    )
    keep = (shapely.get_type_id(parts) == 3) & (area >= config.min_polygon_area_m2) & ~island
    parts, owner = _clean_coverage(parts[keep], owner[keep], config.min_polygon_area_m2)
    return gpd.GeoDataFrame(
        {"osm_id": footprints["osm_id"].to_numpy()[owner], "carved_m2": carved[owner]},
        geometry=parts,
        crs=areas.crs,
    )


def _clean_coverage(
    polygons: np.ndarray, owner: np.ndarray, min_area_m2: float
) -> tuple[np.ndarray, np.ndarray]:
    """Polygons made a clean coverage (no two overlap), with the owner index of each part.

    Parts smaller than ``min_area_m2`` are dropped.

    Mapped buildings overlap (a tower drawn inside its podium, neighbours whose walls cross). Each
    overlap goes to the smaller building (ties: the earlier one): every polygon loses what it shares
    with smaller ones, so nested buildings keep their own outline and id, and the layer's area is the
    area it covers. Pairwise differences between the overlapping pairs only, in vectorised rounds.
    """
    if len(polygons) < 2:
        return polygons, owner
    area = shapely.area(polygons)
    big, small = shapely.STRtree(polygons).query(polygons, predicate="intersects")
    rank = np.lexsort((np.arange(len(polygons)), area))  # by area, then index
    order = np.empty(len(polygons), dtype=np.intp)
    order[rank] = np.arange(len(polygons))
    pairs = order[small] < order[big]
    big, small = big[pairs], small[pairs]
    shared = shapely.area(shapely.intersection(polygons[big], polygons[small])) > 0
    cleaned = np.array(polygons, dtype=object, copy=True)
    big, small = big[shared], small[shared]
    if len(big):
        cut = np.unique(big)
        cleaned[cut] = subtract_each(polygons[cut], cut, big, polygons[small])
    parts, row = shapely.get_parts(shapely.make_valid(cleaned), return_index=True)
    keep = (shapely.get_type_id(parts) == 3) & (shapely.area(parts) >= min_area_m2)
    return parts[keep], owner[row[keep]]
