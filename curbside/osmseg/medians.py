"""The median of a dual carriageway: the side of a one-way road that faces its other half.

OpenStreetMap draws a divided road as two one-way ways of the same name, one per direction, with
the median (planted strip, transit platforms, cable-car tracks) between them. A sidewalk band on
each side of each way would put two sidewalks in that median, where nobody walks along the street:
in downtown San Francisco The Embarcadero, Market Street's boarding islands, Powell Street's
cable-car tracks, Drumm, Broadway, King and Washington Streets. :func:`median_sides` finds those
sides so that :func:`curbside.osmseg.sidewalks.sidewalk_segments` leaves them out; the median is
then free space, like a traffic island.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import shapely

from curbside.osmseg.tags import column, is_in

#: ``oneway`` values of a road drawn in its direction of travel, and against it.
ONEWAY_FORWARD = ("yes", "1", "true")
ONEWAY_BACKWARD = ("-1", "reverse")
#: Least angle (deg) between two ways' directions of travel for them to count as opposite halves.
MIN_OPPOSITE_ANGLE_DEG = 150.0
#: Tag values that say a side has a sidewalk of its own (then the mapper's word is kept).
_HAS_SIDEWALK = ("yes", "separate")


def _unit(vectors: np.ndarray) -> np.ndarray:
    return vectors / np.maximum(np.hypot(*vectors.T), 1e-9)[:, None]


def _directions(lines: np.ndarray, at_m: np.ndarray) -> np.ndarray:
    """Unit tangent of each line at ``at_m`` along it, over 4 m."""
    length = shapely.length(lines)
    ahead = shapely.line_interpolate_point(lines, np.minimum(at_m + 2.0, length))
    behind = shapely.line_interpolate_point(lines, np.maximum(at_m - 2.0, 0.0))
    return _unit(shapely.get_coordinates(ahead) - shapely.get_coordinates(behind))


def tagged_sides(roads: pd.DataFrame) -> tuple[np.ndarray, np.ndarray]:
    """Whether each road's tags say outright that its left / right side has a sidewalk."""
    main = column(roads, "sidewalk")
    both = is_in(main, ["both"]) | is_in(column(roads, "sidewalk:both"), _HAS_SIDEWALK)
    left = both | is_in(main, ["left"]) | is_in(column(roads, "sidewalk:left"), _HAS_SIDEWALK)
    right = both | is_in(main, ["right"]) | is_in(column(roads, "sidewalk:right"), _HAS_SIDEWALK)
    return left, right


def median_sides(
    lines: np.ndarray,
    road: np.ndarray,
    roads: pd.DataFrame,
    max_median_m: float,
    buildings: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Which side of each piece of road faces the other half of its dual carriageway.

    At the middle of each piece of a one-way road, a line is drawn square to it on each side. That
    side is a median when the first road the line meets is one-way, has the same name (or ``ref``
    when unnamed), carries traffic the opposite way (at least :data:`MIN_OPPOSITE_ANGLE_DEG` apart),
    its carriageway edge lies within ``max_median_m`` of this piece's, and no building stands between
    the two (a street split round a row of buildings keeps its sidewalks there). A side whose own tags
    say it has a sidewalk (``sidewalk=both|left|right``, ``sidewalk:<side>=yes|separate``) is never
    a median. Left- and right-hand traffic need no setting: both sides are looked at.

    Parameters
    ----------
    lines
        Pieces of roads (LineStrings in a metric CRS), e.g. one block each.
    road
        Row of ``roads`` each piece belongs to.
    roads
        The roads, with ``half_left_m`` / ``half_right_m`` (carriageway half-widths) and their tags.
    max_median_m
        Widest median (m, curb to curb) still taken for one; South Park's oval (26 m of park between
        its two halves) is wider and keeps its inner sidewalk.
    buildings
        Building footprints (same CRS), or None.

    Returns
    -------
    (numpy.ndarray, numpy.ndarray)
        Boolean masks over the pieces: left side is a median, right side is a median.
    """
    oneway = column(roads, "oneway")
    travel = np.where(is_in(oneway, ONEWAY_BACKWARD), -1.0, 1.0)
    is_oneway = is_in(oneway, ONEWAY_FORWARD + ONEWAY_BACKWARD)
    names = column(roads, "name").fillna(column(roads, "ref")).to_numpy()
    half = roads[["half_left_m", "half_right_m"]].to_numpy()
    tag_left, tag_right = tagged_sides(roads)
    medians = np.zeros((len(lines), 2), dtype=bool)
    candidates = np.flatnonzero(is_oneway[road] & pd.notna(names[road]))
    if len(candidates) == 0 or max_median_m <= 0:
        return medians[:, 0], medians[:, 1]
    cand_lines = lines[candidates]
    mid_m = shapely.length(cand_lines) / 2
    mid = shapely.get_coordinates(shapely.line_interpolate_point(cand_lines, mid_m))
    tangent = _directions(cand_lines, mid_m)
    left_normal = np.column_stack([-tangent[:, 1], tangent[:, 0]])
    own_road = road[candidates]
    tree = shapely.STRtree(lines)
    for column_index, sign in ((0, 1.0), (1, -1.0)):
        reach = half[own_road, column_index] + max_median_m + half.max()
        start = mid + sign * left_normal * (half[own_road, column_index] + 0.1)[:, None]
        end = mid + sign * left_normal * reach[:, None]
        probes = shapely.linestrings(np.stack([start, end], axis=1))
        probe_i, hit = tree.query(probes, predicate="intersects")
        keep = road[hit] != own_road[probe_i]
        probe_i, hit = probe_i[keep], hit[keep]
        # The first road each probe meets: the nearest hit along the probe.
        near = shapely.distance(shapely.points(start[probe_i]), lines[hit])
        order = np.lexsort((near, probe_i))
        probe_i, hit, near = probe_i[order], hit[order], near[order]
        first = np.r_[True, probe_i[1:] != probe_i[:-1]][: len(probe_i)]
        probe_i, hit = probe_i[first], hit[first]
        other = road[hit]
        centre_gap = shapely.distance(shapely.points(mid[probe_i]), lines[hit])
        at = shapely.line_locate_point(lines[hit], shapely.points(mid[probe_i]))
        their_way = _directions(lines[hit], at) * travel[other][:, None]
        our_way = tangent[probe_i] * travel[own_road[probe_i]][:, None]
        opposite = np.einsum("ij,ij->i", our_way, their_way) <= np.cos(np.radians(MIN_OPPOSITE_ANGLE_DEG))
        curb_gap = centre_gap - half[own_road[probe_i], column_index] - half[other].min(axis=1)
        median = is_oneway[other] & (names[other] == names[own_road[probe_i]]) & opposite
        median &= curb_gap <= max_median_m
        if buildings is not None and len(buildings):
            across = shapely.shortest_line(shapely.points(mid[probe_i]), lines[hit])
            blocked = np.unique(shapely.STRtree(buildings).query(across, predicate="intersects")[0])
            median[blocked] = False
        medians[candidates[probe_i[median]], column_index] = True
    tagged = np.column_stack([tag_left, tag_right])[road]
    medians &= ~tagged
    return medians[:, 0], medians[:, 1]
