"""The median of a dual carriageway: the side of a one-way road that faces its other half.

OpenStreetMap draws a divided road as two one-way ways of the same name, one per direction, with
the median (planted strip, transit platforms, cable-car tracks) between them. A sidewalk band on
each side of each way would put two sidewalks in that median, where nobody walks along the street:
in downtown San Francisco The Embarcadero's streetcar tracks, Market Street's boarding islands and
Drumm Street's median. :func:`median_sides` finds those
sides so that :func:`curbside.osmseg.sidewalks.sidewalk_segments` leaves them out; the median is
then free space, like a traffic island. :func:`refuge_stretches` finds, with the same probes, where
the halves may give up the parking assumed on those sides because the median would then open to a
real refuge (:func:`curbside.osmseg.streets.open_refuges`).
"""

from __future__ import annotations

from dataclasses import dataclass

import geopandas as gpd
import numpy as np
import pandas as pd
import shapely

from curbside.osmseg.tags import column, is_in

#: ``oneway`` values of a road drawn in its direction of travel, and against it.
ONEWAY_FORWARD = ("yes", "1", "true")
ONEWAY_BACKWARD = ("-1", "reverse")
#: Least angle (deg) between two ways' directions of travel for them to count as opposite halves.
MIN_OPPOSITE_ANGLE_DEG = 150.0
#: Where along each piece (fractions of its length) the square lines are drawn, and how many of them
#: must meet the other half: two of three, so that a piece whose halves meet or part near one end
#: (the wedge of a splitter island) is judged on the rest of it.
PROBE_FRACTIONS = (0.25, 0.5, 0.75)
MIN_PROBES_ACROSS = 2
#: Spacing (m) of the probes that look for where a median opens (:func:`refuge_stretches`).
REFUGE_PROBE_STEP_M = 4.0
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

    At a quarter, half and three quarters of the way along each piece of a one-way road, a line is
    drawn square to it on each side. That side is a median when, for two of the three, the first
    road the line meets is one-way, has the same name (or ``ref`` when unnamed), carries traffic the
    opposite way (at least :data:`MIN_OPPOSITE_ANGLE_DEG` apart), its carriageway edge lies within
    ``max_median_m`` of this piece's, and no building stands between the two (a street split round a
    row of buildings keeps its sidewalks there). A side whose own tags say it has a sidewalk
    (``sidewalk=both|left|right``, ``sidewalk:<side>=yes|separate``) is never a median. Left- and
    right-hand traffic need no setting: both sides are looked at.

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
    facts = _facts(lines, road, roads, buildings)
    medians = np.zeros((len(lines), 2), dtype=bool)
    candidates = np.flatnonzero(facts.is_oneway[road] & pd.notna(facts.names[road]))
    if len(candidates) and max_median_m > 0:
        piece = np.repeat(candidates, len(PROBE_FRACTIONS))
        at_m = shapely.length(lines[piece]) * np.tile(PROBE_FRACTIONS, len(candidates))
        for column_index in (0, 1):
            faces = _faces_other_half(facts, piece, at_m, column_index, max_median_m)
            votes = np.bincount(piece[faces], minlength=len(lines))
            medians[:, column_index] = votes >= MIN_PROBES_ACROSS
    tag_left, tag_right = tagged_sides(roads)
    medians &= ~np.column_stack([tag_left, tag_right])[road]
    return medians[:, 0], medians[:, 1]


def _facts(
    lines: np.ndarray, road: np.ndarray, roads: pd.DataFrame, buildings: np.ndarray | None
) -> _RoadFacts:
    oneway = column(roads, "oneway")
    return _RoadFacts(
        lines=lines,
        road=road,
        travel=np.where(is_in(oneway, ONEWAY_BACKWARD), -1.0, 1.0),
        is_oneway=is_in(oneway, ONEWAY_FORWARD + ONEWAY_BACKWARD),
        names=column(roads, "name").fillna(column(roads, "ref")).to_numpy(),
        half=roads[["half_left_m", "half_right_m"]].to_numpy(),
        tree=shapely.STRtree(lines),
        buildings=None if buildings is None or not len(buildings) else shapely.STRtree(buildings),
    )


def refuge_stretches(
    roads: gpd.GeoDataFrame,
    narrower_half_m: np.ndarray,
    min_refuge_m: float,
    max_median_m: float,
    buildings: np.ndarray | None = None,
    step_m: float = REFUGE_PROBE_STEP_M,
) -> pd.DataFrame:
    """Where a median would open at least ``min_refuge_m`` wide if its halves gave up some width there.

    Every ``step_m`` along each road, on each side whose half-width could narrow, a line is drawn
    square to it as in :func:`median_sides`. Where it meets the other half of the dual carriageway
    (same name, travel opposite, no building between, curbs at most ``max_median_m`` apart), the
    median that would open is the distance between the two centrelines less the narrower half-width
    of each side that faces it. The probes where that is at least ``min_refuge_m`` are joined into
    stretches (each probe stands for ``step_m`` of road around it).

    Parameters
    ----------
    roads
        Road ways (metric CRS) with ``half_left_m`` / ``half_right_m`` and their tags.
    narrower_half_m
        Shape (n, 2): each side's half-width without what it could give up (equal to its half-width
        where it gives up nothing; such sides are not probed).
    min_refuge_m
        Narrowest median that opens (m, curb to curb).
    max_median_m
        Widest median still taken for one (as in :func:`median_sides`).
    buildings
        Building footprints (same CRS), or None.
    step_m
        Spacing of the probes along a road.

    Returns
    -------
    pandas.DataFrame
        One row per stretch: ``road`` (row of ``roads``), ``side`` (0 left, 1 right), ``start_m`` and
        ``end_m`` along the way.
    """
    lines = roads.geometry.values
    facts = _facts(lines, np.arange(len(roads)), roads, buildings)
    length = shapely.length(lines)
    n = np.maximum(1, length // step_m).astype(int)
    probe_road = np.repeat(np.arange(len(roads)), n)
    rank = np.arange(len(probe_road)) - np.repeat(np.cumsum(n) - n, n)
    spacing = length[probe_road] / n[probe_road]
    at_m = (rank + 0.5) * spacing
    frames = [pd.DataFrame({"road": [], "side": [], "start_m": [], "end_m": []}, dtype=float)]
    for side in (0, 1):
        narrows = (narrower_half_m[:, side] < facts.half[:, side]) & (length > 0)
        probed = np.flatnonzero((narrows & facts.is_oneway & pd.notna(facts.names))[probe_road])
        if len(probed) == 0:
            continue
        probe_i, hit, centre_m, facing = _across(facts, probe_road[probed], at_m[probed], side, max_median_m)
        own = probe_road[probed[probe_i]]
        curb_gap = centre_m - facts.half[own, side] - facts.half[hit].min(axis=1)
        opened_m = centre_m - narrower_half_m[own, side] - narrower_half_m[hit, facing]
        opens = np.zeros(len(probe_road), dtype=bool)
        opens[probed[probe_i[(curb_gap <= max_median_m) & (opened_m >= min_refuge_m)]]] = True
        # Runs of consecutive opening probes along one road make one stretch.
        starts = opens & ~np.r_[False, opens[:-1] & (probe_road[1:] == probe_road[:-1])]
        run = np.cumsum(starts)[opens]
        first_at = pd.Series(at_m[opens] - spacing[opens] / 2).groupby(run).min()
        last_at = pd.Series(at_m[opens] + spacing[opens] / 2).groupby(run).max()
        frames.append(pd.DataFrame({
            "road": probe_road[starts], "side": side,
            "start_m": first_at.to_numpy(), "end_m": last_at.to_numpy(),
        }))  # fmt: skip
    return pd.concat(frames, ignore_index=True).astype({"road": int, "side": int})


@dataclass(frozen=True)
class _RoadFacts:
    """What the probes read: the pieces, their roads' direction of travel, names and half-widths."""

    lines: np.ndarray
    road: np.ndarray
    travel: np.ndarray
    is_oneway: np.ndarray
    names: np.ndarray
    half: np.ndarray
    tree: shapely.STRtree
    buildings: shapely.STRtree | None


def _across(
    facts: _RoadFacts, piece: np.ndarray, at_m: np.ndarray, column_index: int, max_median_m: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The probes (``piece``, ``at_m`` along it) whose line square to the side ``column_index``
    (0 left, 1 right) meets the other half of its dual carriageway first (same name, one-way, travel
    opposite, no building between).

    Returns
    -------
    (probe, hit, centre_m, facing)
        Per such probe: its index, the piece it meets, the distance between the two centrelines (m)
        and which side of the piece met faces the probe (0 left, 1 right).
    """
    lines, road, half = facts.lines, facts.road, facts.half
    origin = shapely.get_coordinates(shapely.line_interpolate_point(lines[piece], at_m))
    tangent = _directions(lines[piece], at_m)
    outward = np.column_stack([-tangent[:, 1], tangent[:, 0]]) * (1.0 if column_index == 0 else -1.0)
    own_road = road[piece]
    own_half = half[own_road, column_index]
    start = origin + outward * (own_half + 0.1)[:, None]
    end = origin + outward * (own_half + max_median_m + half.max())[:, None]
    probes = shapely.linestrings(np.stack([start, end], axis=1))
    probe_i, hit = facts.tree.query(probes, predicate="intersects")
    keep = road[hit] != own_road[probe_i]
    probe_i, hit = probe_i[keep], hit[keep]
    # The first road each probe meets: the nearest hit along the probe.
    order = np.lexsort((shapely.distance(shapely.points(start[probe_i]), lines[hit]), probe_i))
    probe_i, hit = probe_i[order], hit[order]
    first = np.r_[True, probe_i[1:] != probe_i[:-1]][: len(probe_i)]
    probe_i, hit = probe_i[first], hit[first]
    other, at_origin = road[hit], shapely.points(origin[probe_i])
    their_at_m = shapely.line_locate_point(lines[hit], at_origin)
    their_drawn = _directions(lines[hit], their_at_m)
    their_way = their_drawn * facts.travel[other][:, None]
    our_way = tangent[probe_i] * facts.travel[own_road[probe_i]][:, None]
    opposite = np.einsum("ij,ij->i", our_way, their_way) <= np.cos(np.radians(MIN_OPPOSITE_ANGLE_DEG))
    same_road = facts.is_oneway[other] & (facts.names[other] == facts.names[own_road[probe_i]])
    faces = same_road & opposite
    if facts.buildings is not None:
        across = shapely.shortest_line(at_origin, lines[hit])
        blocked = facts.buildings.query(across, predicate="intersects")[0]
        faces[np.unique(blocked)] = False
    away = origin[probe_i] - shapely.get_coordinates(shapely.line_interpolate_point(lines[hit], their_at_m))
    facing = np.where(their_drawn[:, 0] * away[:, 1] - their_drawn[:, 1] * away[:, 0] > 0, 0, 1)
    centre_m = shapely.distance(at_origin, lines[hit])
    return probe_i[faces], hit[faces], centre_m[faces], facing[faces]


def _faces_other_half(
    facts: _RoadFacts, piece: np.ndarray, at_m: np.ndarray, column_index: int, max_median_m: float
) -> np.ndarray:
    """For each probe (``piece``, ``at_m`` along it), whether the line square to it on the side
    ``column_index`` (0 left, 1 right) meets the other half of its dual carriageway first, with
    carriageway edges at most ``max_median_m`` apart."""
    probe_i, hit, centre_m, _ = _across(facts, piece, at_m, column_index, max_median_m)
    own_half = facts.half[facts.road[piece[probe_i]], column_index]
    curb_gap = centre_m - own_half - facts.half[facts.road[hit]].min(axis=1)
    out = np.zeros(len(piece), dtype=bool)
    out[probe_i[curb_gap <= max_median_m]] = True
    return out
