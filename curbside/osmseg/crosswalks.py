"""Stage 4: crosswalk polygons from crossing ways and crossing nodes.

``footway=crossing`` ways are buffered by their ``width`` (else ``crosswalk_width_m``) with
square ends; ``highway=crossing`` nodes on a road that no crossing way passes through become a strip
across the carriageway, perpendicular to the road at the node. Both are clipped to the carriageway
grown by ``crosswalk_overlap_m``, so every crosswalk reaches just past both curbs and joins
the sidewalks there. Unmarked crossings (``crossing=unmarked`` or ``crossing:markings=no``) are
crosswalks or plain street as the caller chooses. The widths and the choice are fields of
:class:`~curbside.osmseg.config.SegmentationConfig`.
"""

from __future__ import annotations

import geopandas as gpd
import numpy as np
import shapely

from curbside.osmseg.config import SegmentationConfig
from curbside.osmseg.overlay import polygons_only
from curbside.osmseg.streets import Carriageways, ground_level, side_buffers
from curbside.osmseg.tags import column, is_in, metres


def _unmarked(table) -> np.ndarray:
    return is_in(column(table, "crossing"), ["unmarked"]) | is_in(column(table, "crossing:markings"), ["no"])


def crossing_ways(ways: gpd.GeoDataFrame, config: SegmentationConfig) -> gpd.GeoDataFrame:
    """Street-level ``footway=crossing`` ways that become crosswalks, with ``width_m``."""
    mask = is_in(column(ways, "footway"), ["crossing"]) & ground_level(ways)
    mask &= ~is_in(column(ways, "crossing"), ["no"])
    if config.unmarked_crossing_as == "street":
        mask &= ~_unmarked(ways)
    out = ways[mask]
    width = metres(column(out, "width"))
    return out.assign(width_m=np.where(np.isnan(width), config.crosswalk_width_m, width))


def crossing_node_strips(
    nodes: gpd.GeoDataFrame,
    cways: Carriageways,
    crossings: gpd.GeoDataFrame,
    config: SegmentationConfig,
    snap_m: float = 1.0,
) -> np.ndarray:
    """Strips across the carriageway at ``highway=crossing`` nodes that no crossing way covers.

    Parameters
    ----------
    nodes
        Tagged nodes of an :class:`~curbside.osmseg.reader.OsmData`.
    cways
        The carriageways (road ways with per-side half-widths).
    crossings
        The crossing ways already turned into crosswalks.
    config
        Crosswalk width and overlap, and what unmarked crossings become.
    snap_m
        A node counts as on a road (or on a crossing way) within this distance.

    Returns
    -------
    numpy.ndarray
        Polygons, one per qualifying node.
    """
    mask = is_in(column(nodes, "highway"), ["crossing"]) & ~is_in(column(nodes, "crossing"), ["no"])
    if config.unmarked_crossing_as == "street":
        mask &= ~_unmarked(nodes)
    points = nodes.geometry.values[mask]
    roads = cways.roads
    if len(points) == 0 or len(roads) == 0:
        return np.array([], dtype=object)
    if len(crossings):
        tree = shapely.STRtree(crossings.geometry.values)
        covered = tree.query(points, predicate="dwithin", distance=snap_m)[0]
        points = np.delete(points, np.unique(covered))
    lines = roads.geometry.values
    point_i, road_i = shapely.STRtree(lines).query_nearest(points, max_distance=snap_m, all_matches=False)
    if len(point_i) == 0:
        return np.array([], dtype=object)
    line = lines[road_i]
    along = shapely.line_locate_point(line, points[point_i])
    a = shapely.get_coordinates(shapely.line_interpolate_point(line, np.maximum(along - 1.0, 0)))
    b = shapely.get_coordinates(shapely.line_interpolate_point(line, along + 1.0))
    tangent = (b - a) / np.maximum(np.linalg.norm(b - a, axis=1, keepdims=True), 1e-9)
    left = np.column_stack([-tangent[:, 1], tangent[:, 0]])
    p = shapely.get_coordinates(points[point_i])
    reach = config.crosswalk_overlap_m + config.crosswalk_width_m
    ends = np.stack(
        [
            p - left * (roads["half_right_m"].to_numpy()[road_i, None] + reach),
            p + left * (roads["half_left_m"].to_numpy()[road_i, None] + reach),
        ],
        axis=1,
    )
    strips = shapely.linestrings(ends.reshape(-1, 2), indices=np.repeat(np.arange(len(p)), 2))
    return shapely.buffer(strips, config.crosswalk_width_m / 2, cap_style="flat")


def crosswalks(
    ways: gpd.GeoDataFrame,
    nodes: gpd.GeoDataFrame,
    cways: Carriageways,
    config: SegmentationConfig | None = None,
) -> np.ndarray:
    """Disjoint crosswalk polygons.

    Parameters
    ----------
    ways, nodes
        Tables of an :class:`~curbside.osmseg.reader.OsmData`.
    cways
        The carriageways from :func:`curbside.osmseg.streets.carriageways`.
    config
        Crosswalk width and overlap, what unmarked crossings become, the sliver size (default
        :class:`~curbside.osmseg.config.SegmentationConfig`).

    Returns
    -------
    numpy.ndarray
        Valid, pairwise disjoint polygons inside the carriageway grown by the curb overlap (buildings
        not yet cut out).
    """
    config = config or SegmentationConfig()
    crossings = crossing_ways(ways, config)
    from_ways = shapely.buffer(
        crossings.geometry.values, crossings["width_m"].to_numpy() / 2, cap_style="square"
    )
    from_nodes = crossing_node_strips(nodes, cways, crossings, config)
    raw = np.concatenate([from_ways, from_nodes])
    if len(raw) == 0:
        return raw
    # Clip to the carriageway of the roads each crosswalk crosses, grown past the curbs.
    roads = cways.roads
    grow = config.crosswalk_overlap_m
    lines = roads.geometry.values
    reach = np.concatenate(
        [
            side_buffers(lines, roads["half_left_m"].to_numpy() + grow),
            side_buffers(lines, -(roads["half_right_m"].to_numpy() + grow)),
        ]
    )
    raw_i, reach_i = shapely.STRtree(reach).query(raw, predicate="intersects")
    clipped = shapely.intersection(raw[raw_i], reach[reach_i])
    return polygons_only(shapely.union_all(clipped), config.min_polygon_area_m2)
