"""Stage 3: carriageway (street-surface) polygons from road centrelines.

Each ground-level motor road is buffered to each side by its half-width (flat ends, one single-sided
buffer per side), junction nodes get a disk of the narrowest meeting half-width so that bends and
crossings close, and everything is unioned. Widths come from ``width``, else ``lanes`` plus parking
and cycle lanes, else the ``highway`` class's default width (all widths: fields of
:class:`~curbside.osmseg.config.SegmentationConfig`). Where a sidewalk is mapped separately
(``footway=sidewalk``) the curb on that side is put half a sidewalk width short of it, so the
carriageway never swallows a mapped sidewalk. A dual carriageway's half gives up the parking assumed
on its median side where the median then opens to a real refuge (:func:`open_refuges`).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import geopandas as gpd
import numpy as np
import pandas as pd
import shapely

from curbside.osmseg.config import SegmentationConfig
from curbside.osmseg.medians import refuge_stretches
from curbside.osmseg.overlay import polygons_only, quadtree_split, substrings, subtract, subtract_each
from curbside.osmseg.tags import column, first_number, is_in, metres

logger = logging.getLogger(__name__)

#: ``service`` values of roads whose carriageway gives way to the sidewalks it crosses.
MINOR_SERVICES = ("driveway", "parking_aisle", "drive-through")

#: ``footway`` values of separately mapped sidewalks.
SIDEWALK_FOOTWAYS = ("sidewalk",)
_PARKING_LANE_VALUES = {"parallel": "parallel", "marked": "parallel", "diagonal": "diagonal",
                        "perpendicular": "perpendicular"}  # fmt: skip
_PARKING_VALUES = {"lane": "lane", "half_on_kerb": "half"}
_PARKING_KEYS = ("parking:lane:both", "parking:lane:left", "parking:lane:right",
                 "parking:both", "parking:left", "parking:right")  # fmt: skip
_NO = ("no", "none")
#: ``junction`` values of roundabouts, whose inner side is the central island.
ROUNDABOUTS = ("roundabout", "circular")


def sidewalk_sides(roads: pd.DataFrame) -> tuple[np.ndarray, np.ndarray]:
    """Whether each road has a sidewalk on its left and right (absent tags: both sides).

    A roundabout (``junction=roundabout|circular``) has none on the side of its central island
    (:func:`island_sides`), whatever its tags say of the outer side. Finding that side needs the
    ways' geometry (``roads`` a GeoDataFrame) only when the table holds a roundabout.
    """
    main = column(roads, "sidewalk")
    both = column(roads, "sidewalk:both")
    left = ~(is_in(main, [*_NO, "right"]) | is_in(both, _NO) | is_in(column(roads, "sidewalk:left"), _NO))
    right = ~(is_in(main, [*_NO, "left"]) | is_in(both, _NO) | is_in(column(roads, "sidewalk:right"), _NO))
    roundabout = is_in(column(roads, "junction"), ROUNDABOUTS)
    if roundabout.any():
        rows = np.flatnonzero(roundabout)
        island = island_sides(roads.geometry.values[roundabout])
        left[rows[island > 0]] = False
        right[rows[island < 0]] = False
    return left, right


def island_sides(arcs: np.ndarray) -> np.ndarray:
    """Which side of each roundabout way its central island lies on: 1 left, -1 right, 0 unknown.

    A roundabout is often several ways (one between each pair of entries, some of them straight
    two-node pieces), drawn anticlockwise where traffic keeps right and clockwise where it keeps
    left. The island's centre is taken as the centroid of the convex hull of the connected ways
    (each way's own hull when it meets no other), and its side is the side of the way, at its middle,
    that the centre lies on. A lone straight way, whose centre lies on it, gets 0.
    """
    arcs = np.asarray(arcs, dtype=object)
    pieces = shapely.get_parts(shapely.union_all(shapely.buffer(arcs, 0.5, quad_segs=1)))
    arc_i, piece_i = shapely.STRtree(pieces).query(arcs, predicate="intersects")
    component = np.zeros(len(arcs), dtype=int)
    component[arc_i] = piece_i
    hulls = shapely.convex_hull(pieces)
    centre = shapely.get_coordinates(shapely.centroid(hulls))[component]
    length = shapely.length(arcs)
    mid = shapely.get_coordinates(shapely.line_interpolate_point(arcs, length / 2))
    ahead = shapely.get_coordinates(shapely.line_interpolate_point(arcs, np.minimum(length / 2 + 1, length)))
    behind = shapely.get_coordinates(shapely.line_interpolate_point(arcs, np.maximum(length / 2 - 1, 0)))
    tangent, away = ahead - behind, centre - mid
    cross = tangent[:, 0] * away[:, 1] - tangent[:, 1] * away[:, 0]
    scale = np.hypot(*tangent.T) * np.hypot(*away.T)
    return np.where(np.abs(cross) > 0.05 * scale, np.sign(cross), 0).astype(int)


def ground_level(ways: pd.DataFrame) -> np.ndarray:
    """Mask of ways at street level: not a bridge or tunnel, ``layer`` 0 or absent, lowest level <= 1.

    ``tunnel=building_passage`` counts as street level (the way passes through a building's ground
    floor).
    """
    layer = first_number(column(ways, "layer"))
    level = first_number(column(ways, "level"))
    tunnel = column(ways, "tunnel")
    bridge = column(ways, "bridge")
    return (
        (np.isnan(layer) | (layer == 0))
        & (np.isnan(level) | (level <= 1))
        & (tunnel.isna() | tunnel.isin(["no", "building_passage"])).to_numpy()
        & (bridge.isna() | (bridge == "no")).to_numpy()
    )


def road_mask(ways: pd.DataFrame, config: SegmentationConfig) -> np.ndarray:
    """Mask of ways that make carriageway: motor-road classes at street level, not areas."""
    return (
        is_in(column(ways, "highway"), config.default_carriageway_width_m)
        & ~is_in(column(ways, "area"), ["yes"])
        & ground_level(ways)
    )


def _lanes(ways: pd.DataFrame) -> np.ndarray:
    lanes = first_number(column(ways, "lanes"))
    directional = np.nansum(
        [first_number(column(ways, k)) for k in ("lanes:forward", "lanes:backward", "lanes:both_ways")],
        axis=0,
    )
    lanes = np.where(np.isnan(lanes) & (directional > 0), directional, lanes)
    lanes[~(lanes > 0)] = np.nan
    return lanes


def _parking_width(ways: pd.DataFrame, config: SegmentationConfig) -> np.ndarray:
    def side(lane_key: str, new_key: str) -> np.ndarray:
        old = column(ways, lane_key).map(_PARKING_LANE_VALUES)
        new = column(ways, new_key).map(_PARKING_VALUES)
        kind = old.where(old.notna(), new)
        widths = {**config.parking_width_m, "half": config.parking_width_m["lane"] / 2}
        return kind.map(widths).fillna(0.0).to_numpy(dtype=float)

    both = side("parking:lane:both", "parking:both")
    left = side("parking:lane:left", "parking:left")
    right = side("parking:lane:right", "parking:right")
    return np.where(both > 0, 2 * both, left + right) + 2 * _assumed_parking_m(ways, config)


def _assumed_parking_m(ways: pd.DataFrame, config: SegmentationConfig) -> np.ndarray:
    """Parking assumed on each side (m): streets with sidewalks and no ``parking*`` tag."""
    tagged = np.zeros(len(ways), dtype=bool)
    for key in _PARKING_KEYS:
        tagged |= column(ways, key).notna().to_numpy()
    urban = is_in(column(ways, "highway"), config.sidewalk_highways)
    return np.where(urban & ~tagged, config.assumed_parking_width_m, 0.0)


def _cycle_lanes(ways: pd.DataFrame) -> np.ndarray:
    def lane(key: str) -> np.ndarray:
        return (column(ways, key) == "lane").to_numpy()

    sided = 2 * lane("cycleway:both") + lane("cycleway:left") + lane("cycleway:right")
    oneway = is_in(column(ways, "oneway"), ["yes", "-1", "1"])
    plain = lane("cycleway") * np.where(oneway, 1, 2)
    return np.where(sided > 0, sided, plain).astype(float)


def carriageway_width(
    ways: pd.DataFrame, config: SegmentationConfig | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Curb-to-curb width of each road way, and whether it came from a tag (``width`` / ``lanes``).

    Parameters
    ----------
    ways
        A table with tag columns (:class:`~curbside.osmseg.reader.OsmData` ``ways``).
    config
        Lane, parking and default widths (default :class:`~curbside.osmseg.config.SegmentationConfig`).

    Returns
    -------
    width_m : numpy.ndarray
        Metres; NaN for ways whose ``highway`` class has no default width.
    tagged : numpy.ndarray
        True where the width came from ``width`` or ``est_width`` (then the building line does not cap it).
    """
    config = config or SegmentationConfig()
    tagged_width = metres(column(ways, "width"))
    est = metres(column(ways, "est_width"))
    tagged_width = np.where(np.isnan(tagged_width), est, tagged_width)
    absurd = tagged_width > config.max_tagged_carriageway_width_m
    if absurd.any():
        first = np.flatnonzero(absurd)[0]
        logger.warning(
            "%d road way(s) tagged wider than %g m (way %s: %.0f m), taken for a tagging error: their "
            "width comes from lanes or their class", int(absurd.sum()), config.max_tagged_carriageway_width_m,
            column(ways, "osm_id").iloc[first], tagged_width[first],
        )
        tagged_width[absurd] = np.nan
    from_lanes = (
        _lanes(ways) * config.lane_width_m
        + _parking_width(ways, config)
        + _cycle_lanes(ways) * config.cycle_lane_width_m
    )
    default = column(ways, "highway").map(config.default_carriageway_width_m).to_numpy(dtype=float)
    estimated = np.where(np.isnan(from_lanes), default, from_lanes)
    width = np.where(np.isnan(tagged_width), estimated, tagged_width)
    return width, ~np.isnan(tagged_width)


def mapped_sidewalks(ways: gpd.GeoDataFrame, config: SegmentationConfig | None = None) -> gpd.GeoDataFrame:
    """Separately mapped sidewalks (``footway=sidewalk``) at street level, with ``width_m``.

    A sidewalk without a ``width`` tag is ``config.mapped_sidewalk_width_m`` wide.
    """
    config = config or SegmentationConfig()
    mask = is_in(column(ways, "footway"), SIDEWALK_FOOTWAYS) & ground_level(ways)
    out = ways[mask]
    width = metres(column(out, "width"))
    return out.assign(width_m=np.where(np.isnan(width), config.mapped_sidewalk_width_m, width))


def share_of_length_inside(lines: np.ndarray, polygons: np.ndarray) -> float:
    """Share of the lines' length that lies inside the polygons (0 without lines).

    With the mapped sidewalks (``footway=sidewalk``) as ``lines``: inside buildings, it is 0 for a
    building layer aligned with them and grows for one drawn across them (misaligned imagery, an import
    offset from hand-traced footways); inside sidewalk segments, it says how much of the city's own
    sidewalk map the segments cover. ``polygons`` must not overlap each other (as the map's buildings
    and segments do not), so the pieces inside them add up.
    """
    lines = np.asarray(lines, dtype=object)
    total = float(shapely.length(lines).sum()) if len(lines) else 0.0
    if total <= 0 or len(polygons) == 0:
        return 0.0
    polygons = np.asarray(polygons, dtype=object)
    line_idx, polygon_idx = shapely.STRtree(polygons).query(lines, predicate="intersects")
    inside = shapely.length(shapely.intersection(lines[line_idx], polygons[polygon_idx]))
    return float(inside.sum()) / total


def side_distances(
    lines: np.ndarray,
    targets: np.ndarray,
    setback_m: np.ndarray,
    search_m: float,
    *,
    parallel_only: bool = False,
    step_m: float = 8.0,
    blockers: np.ndarray | None = None,
    own_blocker: np.ndarray | None = None,
    min_hit_share: float = 0.0,
) -> np.ndarray:
    """Median clearance (m) from each line to the targets on its left and right, NaN if none.

    Casts rays perpendicular to the line every ``step_m`` (at least one, at mid-length), takes the
    nearest target each ray meets within ``search_m`` and subtracts that target's ``setback_m``; the
    median over a line's rays ignores cross streets' sidewalks or a protruding building met near its
    ends.

    Parameters
    ----------
    lines
        Road centrelines.
    targets
        Mapped sidewalk lines or building polygons.
    setback_m
        Per target: how far short of it the curb lies (half the sidewalk width, the least sidewalk
        in front of a building).
    search_m
        Length of the rays.
    parallel_only
        Count only line targets within about 25 degrees of parallel to the road where hit.
    step_m
        Spacing of the rays along the line.
    blockers, own_blocker
        Geometries that stop a ray (buildings, other roads): a target behind the first one a ray
        meets does not count. ``own_blocker`` gives, per line, the index in ``blockers`` of the
        line's own road (-1: none), which does not stop its rays.
    min_hit_share
        A side where fewer than this share of the line's rays meet a target gets NaN.

    Returns
    -------
    numpy.ndarray
        Shape (n, 2): left and right clearance of each line.
    """
    out = np.full((len(lines), 2), np.nan)
    if len(lines) == 0 or len(targets) == 0:
        return out
    n = np.maximum(1, (shapely.length(lines) // step_m).astype(int))
    line_idx, p, tangent = ray_origins(lines, n)
    left_normal = np.column_stack([-tangent[:, 1], tangent[:, 0]])
    tree = shapely.STRtree(targets)
    for side, sign in enumerate((1.0, -1.0)):
        start = p + sign * left_normal * 0.5
        rays = shapely.linestrings(
            np.stack([start, p + sign * left_normal * search_m], axis=1).reshape(-1, 2),
            indices=np.repeat(np.arange(len(p)), 2),
        )
        ray_i, target_i = tree.query(rays, predicate="intersects")
        if len(ray_i) == 0:
            continue
        hits = shapely.intersection(rays[ray_i], targets[target_i])
        hit_m = shapely.distance(shapely.points(p[ray_i]), hits)
        curb = hit_m - setback_m[target_i]
        if blockers is not None:
            own = np.full(len(p), -1) if own_blocker is None else np.asarray(own_blocker)[line_idx]
            curb = np.where(hit_m < _first_block_m(rays, p, blockers, own)[ray_i], curb, np.nan)
        if parallel_only:
            # Only targets running along the road set its curb, not a cross street's sidewalk.
            curb = np.where(_parallel(targets[target_i], p[ray_i], tangent[ray_i]), curb, np.nan)
        per_ray = pd.Series(curb).groupby(ray_i).min().dropna()
        per_line = per_ray.groupby(line_idx[per_ray.index.to_numpy()]).agg(["median", "size"])
        met = per_line["size"].to_numpy() >= min_hit_share * n[per_line.index.to_numpy()]
        out[per_line.index.to_numpy()[met], side] = per_line["median"].to_numpy()[met]
    return out


def ray_origins(lines: np.ndarray, n: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Where :func:`side_distances` casts its rays: ``n`` evenly spaced points along each line.

    Parameters
    ----------
    lines
        LineStrings in a metric CRS.
    n
        Per line, how many points: the k-th lies (k + 1/2) / n of the way along.

    Returns
    -------
    line_idx : numpy.ndarray
        The line of each point.
    xy : numpy.ndarray
        Shape (sum(n), 2).
    tangent : numpy.ndarray
        Unit tangent of the line at each point (its direction over 1 m).
    """
    lengths = shapely.length(lines)
    line_idx = np.repeat(np.arange(len(lines)), n)
    rank = np.arange(len(line_idx)) - np.repeat(np.cumsum(n) - n, n)
    along = (rank + 0.5) / n[line_idx] * lengths[line_idx]
    geoms = lines[line_idx]
    p = shapely.get_coordinates(shapely.line_interpolate_point(geoms, along))
    a = shapely.get_coordinates(shapely.line_interpolate_point(geoms, np.maximum(along - 0.5, 0)))
    b = shapely.get_coordinates(shapely.line_interpolate_point(geoms, along + 0.5))
    tangent = b - a
    tangent /= np.maximum(np.linalg.norm(tangent, axis=1, keepdims=True), 1e-9)
    return line_idx, p, tangent


def _parallel(targets: np.ndarray, xy: np.ndarray, tangent: np.ndarray) -> np.ndarray:
    """Whether each target line runs within about 25 degrees of ``tangent`` where it passes nearest
    ``xy`` (its direction over 1 m either way)."""
    at = shapely.line_locate_point(targets, shapely.points(xy))
    ta = shapely.get_coordinates(shapely.line_interpolate_point(targets, np.maximum(at - 1.0, 0)))
    tb = shapely.get_coordinates(shapely.line_interpolate_point(targets, at + 1.0))
    td = (tb - ta) / np.maximum(np.linalg.norm(tb - ta, axis=1, keepdims=True), 1e-9)
    return np.abs(np.sum(td * tangent, axis=1)) >= 0.9


def _first_block_m(
    rays: np.ndarray, origins: np.ndarray, blockers: np.ndarray, own: np.ndarray
) -> np.ndarray:
    """Per ray, the distance from its origin (xy) to the first of ``blockers`` it meets (inf: none),
    leaving out the blocker ``own`` names per ray."""
    first = np.full(len(rays), np.inf)
    ray_i, block_i = shapely.STRtree(blockers).query(rays, predicate="intersects")
    keep = block_i != own[ray_i]
    ray_i, block_i = ray_i[keep], block_i[keep]
    met = shapely.intersection(rays[ray_i], blockers[block_i])
    met = shapely.distance(shapely.points(origins[ray_i]), met)
    np.minimum.at(first, ray_i, met)
    return first


@dataclass
class Carriageways:
    """Road ways with their per-side half-widths and carriageway polygons.

    Attributes
    ----------
    roads
        The road ways (tag columns, LineString geometry) with ``half_left_m`` / ``half_right_m``
        (left and right of the OSM way direction) and ``mapped_left`` / ``mapped_right`` (a mapped
        sidewalk narrowed that side).
    surface
        The carriageway as disjoint polygons (quadtree tiles of the union), before buildings,
        crosswalks and ``refuges`` are cut out.
    minor
        Per ``surface`` polygon: it belongs only to driveways, parking aisles or drive-throughs
        (:data:`MINOR_SERVICES`), which sidewalks cross.
    sidewalks
        The mapped sidewalks used (``footway=sidewalk`` ways with ``width_m``).
    refuges
        Medians opened by taking the assumed parking off the sides of a dual carriageway that face
        them (:func:`open_refuges`): free space, not street. ``roads``' half-widths and ``surface``
        still include that parking, so crosswalks span a refuge whole and sidewalks keep out of it.
    """

    roads: gpd.GeoDataFrame
    surface: np.ndarray
    minor: np.ndarray
    sidewalks: gpd.GeoDataFrame
    refuges: np.ndarray = field(default_factory=lambda: np.array([], dtype=object))


def carriageways(
    ways: gpd.GeoDataFrame, buildings: np.ndarray | None = None, config: SegmentationConfig | None = None
) -> Carriageways:
    """Carriageway polygons of every street-level motor road.

    Parameters
    ----------
    ways
        Highway ways of an :class:`~curbside.osmseg.reader.OsmData`.
    buildings
        Building footprints. On a side of a street with sidewalks whose width is not tagged, the
        curb stays ``config.min_sidewalk_width_m`` clear of the building line.
    config
        Widths and rules (default :class:`~curbside.osmseg.config.SegmentationConfig`).

    Returns
    -------
    Carriageways
    """
    config = config or SegmentationConfig()
    search = config.mapped_sidewalk_search_m
    roads = ways[road_mask(ways, config)].reset_index(drop=True)
    sidewalks = mapped_sidewalks(ways, config)
    width, tagged = carriageway_width(roads, config)
    half = np.repeat((width / 2)[:, None], 2, axis=1)
    lines = roads.geometry.values
    to_sidewalk = side_distances(
        lines, sidewalks.geometry.values, sidewalks["width_m"].to_numpy() / 2, search, parallel_only=True
    )
    # Mapped sidewalks are often drawn near the building line, not at the curb: they only cap the
    # estimated width, so the carriageway never swallows them.
    mapped = to_sidewalk < half
    half = np.fmin(half, to_sidewalk)
    if buildings is not None and len(buildings):
        to_building = side_distances(
            lines, buildings, np.full(len(buildings), config.min_sidewalk_width_m), search
        )
        # A measured (tagged) width is not second-guessed from the building line.
        walked = np.column_stack(sidewalk_sides(roads)) & (
            is_in(column(roads, "highway"), config.sidewalk_highways) & ~tagged
        )[:, None]
        half = np.where(walked, np.fmin(half, to_building), half)
    half = np.maximum(half, config.min_carriageway_half_width_m)
    roads = roads.assign(
        half_left_m=half[:, 0], half_right_m=half[:, 1], mapped_left=mapped[:, 0], mapped_right=mapped[:, 1]
    )
    parking_m = np.where(tagged | np.isnan(_lanes(roads)), 0.0, _assumed_parking_m(roads, config))
    narrower = np.fmin(half, (width / 2 - parking_m)[:, None])
    narrower = np.maximum(narrower, config.min_carriageway_half_width_m)
    left = side_buffers(lines, half[:, 0])
    right = side_buffers(lines, -half[:, 1])
    refuges = open_refuges(roads, np.concatenate([left, right]), narrower, buildings, config)
    radius = half.min(axis=1)
    minor_road = is_in(column(roads, "service"), MINOR_SERVICES)
    through = ~minor_road
    major = np.concatenate([left[through], right[through], junction_disks(lines[through], radius[through])])
    major_tiles = quadtree_split(shapely.union_all(major))
    minor = np.concatenate([left[minor_road], right[minor_road], junction_disks(lines, radius)])
    minor_tiles = polygons_only(subtract(quadtree_split(shapely.union_all(minor)), major_tiles))
    surface = np.concatenate([major_tiles, minor_tiles])
    if len(sidewalks):
        kept_clear = shapely.buffer(
            sidewalks.geometry.values, sidewalks["width_m"].to_numpy() / 2, cap_style="flat", quad_segs=2
        )
        surface = subtract(surface, kept_clear)
    parts, tile = shapely.get_parts(surface, return_index=True)
    polygon = shapely.get_type_id(parts) == 3
    is_minor = tile[polygon] >= len(major_tiles)
    return Carriageways(roads, parts[polygon], is_minor, sidewalks, refuges)


def open_refuges(
    roads: gpd.GeoDataFrame,
    bands: np.ndarray,
    narrower_half_m: np.ndarray,
    buildings: np.ndarray | None,
    config: SegmentationConfig,
) -> np.ndarray:
    """The median a dual carriageway opens where it gives up the parking assumed on the sides that
    face it.

    A side facing the other half of its dual carriageway narrows to ``narrower_half_m`` along the
    stretches where the median would then be at least ``config.min_refuge_width_m`` wide
    (:func:`~curbside.osmseg.medians.refuge_stretches`); what it gives up there and no other road's
    band covers (a cross street through the median keeps its carriageway) is the refuge.

    Parameters
    ----------
    roads
        Road ways (metric CRS) with ``half_left_m`` / ``half_right_m`` and their tags.
    bands
        Each road's left bands, then its right bands (:func:`side_buffers`).
    narrower_half_m
        Shape (n, 2): each side's half-width without the parking assumed on it.
    buildings
        Building footprints (a median with a building in it is no median), or None.
    config
        ``min_refuge_width_m``, ``max_median_width_m`` and ``min_polygon_area_m2``.

    Returns
    -------
    numpy.ndarray
        The refuges: disjoint polygons.
    """
    stretches = refuge_stretches(
        roads, narrower_half_m, config.min_refuge_width_m, config.max_median_width_m, buildings
    )
    if len(stretches) == 0:
        return np.array([], dtype=object)
    lines, half = roads.geometry.values, roads[["half_left_m", "half_right_m"]].to_numpy()
    road, side = stretches["road"].to_numpy(), stretches["side"].to_numpy()
    pieces = substrings(lines, road, stretches["start_m"].to_numpy(), stretches["end_m"].to_numpy())
    sign = np.where(side == 0, 1.0, -1.0)
    outer = side_buffers(pieces, sign * half[road, side])
    strips = shapely.difference(outer, side_buffers(pieces, sign * narrower_half_m[road, side]))
    slot = side * len(roads) + road
    kept = subtract_each(bands, np.arange(len(bands)), slot, strips)
    opened = shapely.union_all(subtract(strips, kept))
    # The strips' flat ends leave zero-width spikes along the centreline: an opening by 1 cm drops them.
    opened = shapely.buffer(shapely.buffer(opened, -0.01, join_style="mitre"), 0.01, join_style="mitre")
    refuges = polygons_only(opened, config.min_polygon_area_m2)
    logger.info("%d median stretch(es) open %.0f m^2 of refuge", len(stretches), shapely.area(refuges).sum())
    return refuges


def side_buffers(lines: np.ndarray, distance_m: np.ndarray | float) -> np.ndarray:
    """The band on one side of each line: left of its drawing direction for a positive distance.

    A single-sided buffer with flat ends, as ``shapely.buffer(..., single_sided=True)``, except for
    closed lines (roundabouts, loop roads): GEOS buffers those as the polygon they enclose, giving
    that polygon shrunk by the distance on the left and the whole enclosed polygon on the right,
    not a band. Their band is the two-sided buffer cut by the enclosed polygon: its inside for the
    side the ring turns towards (left when drawn anticlockwise), its outside for the other.

    Parameters
    ----------
    lines
        LineStrings in a metric CRS.
    distance_m
        Width of the band per line (or one for all); positive: left, negative: right.

    Returns
    -------
    numpy.ndarray
        One polygon per line.
    """
    lines = np.asarray(lines, dtype=object)
    distance_m = np.broadcast_to(np.asarray(distance_m, dtype=float), lines.shape)
    out = shapely.buffer(lines, distance_m, single_sided=True, quad_segs=2)
    closed = np.flatnonzero(shapely.is_closed(lines) & (shapely.get_num_coordinates(lines) >= 4))
    if len(closed) == 0:
        return out
    xy, idx = shapely.get_coordinates(lines[closed], return_index=True)
    enclosed = shapely.make_valid(shapely.polygons(shapely.linearrings(xy, indices=idx)))
    # A ring that encloses nothing (drawn there and back along itself) keeps GEOS's buffer.
    closed, enclosed = closed[shapely.area(enclosed) > 0], enclosed[shapely.area(enclosed) > 0]
    rings, width = lines[closed], distance_m[closed]
    band = shapely.buffer(rings, np.abs(width), cap_style="flat", quad_segs=2)
    inside = (width > 0) == shapely.is_ccw(rings)
    out[closed] = np.where(inside, shapely.intersection(band, enclosed), shapely.difference(band, enclosed))
    return out


def node_keys(xy: np.ndarray) -> np.ndarray:
    """Hashable keys for vertex positions (1 cm grid), used to find shared nodes."""
    cm = np.round(xy * 100).astype(np.int64)
    return cm[:, 0] * 2_000_000_000 + cm[:, 1]


def junction_disks(lines: np.ndarray, radius_m: np.ndarray) -> np.ndarray:
    """Disks at vertices shared by two or more lines, of the smallest radius among them.

    They fill the wedge that flat-ended buffers leave on the outside of a bend between two ways and
    round the inside of junctions no further than the narrowest street's half-width.
    """
    if len(lines) == 0:
        return np.array([], dtype=object)
    xy, idx = shapely.get_coordinates(lines, return_index=True)
    keys = node_keys(xy)
    frame = pd.DataFrame({"key": keys, "line": idx, "r": radius_m[idx]}).drop_duplicates(["key", "line"])
    grouped = frame.groupby("key", sort=False).agg(n=("line", "size"), r=("r", "min"))
    shared = grouped[grouped["n"] >= 2]
    first = pd.Series(np.arange(len(keys)), index=keys).groupby(level=0).first()
    centres = xy[first.loc[shared.index].to_numpy()]
    return shapely.buffer(shapely.points(centres), shared["r"].to_numpy(), quad_segs=3)
