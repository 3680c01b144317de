"""Stage 5: sidewalk segments, one polygon per side of a street per block.

Streets that carry sidewalks (``sidewalk_highways`` of
:class:`~curbside.osmseg.config.SegmentationConfig`) are split into blocks at junctions with other
roads. Each block side gets the band from its centreline out to the curb plus ``sidewalk_depth_m``,
built with a single-sided buffer (positive = left of the OSM way direction). Where bands of different
streets meet at corners, the space goes to the nearest centreline (Voronoi cells of points sampled
along the blocks). The carriageway, buildings and crosswalks are then cut out, which leaves the strip
between the curb and the building line, split wherever a crosswalk crosses it.

Each segment also records ``facing_deg``, the bearing from its street to it: the normal of its block's
centreline, to the left or right as its side says, at the point of the block nearest the segment's
centroid. Only the build has the centreline; from the polygon alone a corner sliver's side can come out
a quarter or half turn off (:mod:`curbside.osmseg.places`).
"""

from __future__ import annotations

import logging

import geopandas as gpd
import numpy as np
import pandas as pd
import shapely

from curbside.osmseg.config import SegmentationConfig
from curbside.osmseg.medians import median_sides
from curbside.osmseg.overlay import subtract
from curbside.osmseg.reach import RAY_STEP_M, ray_stretches, reach_polygons
from curbside.osmseg.streets import MINOR_SERVICES, node_keys, side_buffers, side_distances, sidewalk_sides
from curbside.osmseg.tags import column, is_in

log = logging.getLogger(__name__)

#: A band part beyond the usual depth is kept when it shares this much (m^2) with the usual band.
_MIN_REACH_OVERLAP_M2 = 0.1
#: A block side reaches out as far as the median of its rays where at least this share of them meet
#: the mapped sidewalk.
_MIN_HIT_SHARE = 0.5


def split_at_junctions(roads: gpd.GeoDataFrame, block_ends: np.ndarray) -> gpd.GeoDataFrame:
    """Split each road at vertices it shares with another road of ``block_ends``.

    Parameters
    ----------
    roads
        Roads to split (LineStrings).
    block_ends
        LineStrings whose shared vertices end a block (``roads`` are usually among them).

    Returns
    -------
    geopandas.GeoDataFrame
        One row per piece: ``road`` (row of ``roads``), ``k`` (piece number along the way, from 0)
        and the piece geometry.
    """
    xy, line = shapely.get_coordinates(roads.geometry.values, return_index=True)
    shared = np.isin(node_keys(xy), junction_keys(block_ends))
    first = np.r_[True, line[1:] != line[:-1]]
    last = np.r_[line[1:] != line[:-1], True]
    split = shared & ~first & ~last
    # Pieces before each vertex within its line; a split vertex ends one piece and starts the next.
    split_before = np.cumsum(split) - split
    line_start = np.maximum.accumulate(np.where(first, np.arange(len(line)), 0))
    local = split_before - split_before[line_start]
    copies = 1 + split
    xy2 = np.repeat(xy, copies, axis=0)
    local2 = np.repeat(local, copies) + (np.arange(len(xy2)) - np.repeat(np.cumsum(copies) - copies, copies))
    line2 = np.repeat(line, copies)
    pieces_per_line = np.bincount(line, weights=split, minlength=len(roads)).astype(int) + 1
    offset = np.cumsum(pieces_per_line) - pieces_per_line
    piece = offset[line2] + local2
    geoms = shapely.linestrings(xy2, indices=piece)
    road = np.repeat(np.arange(len(roads)), pieces_per_line)
    k = np.arange(len(road)) - offset[road]
    return gpd.GeoDataFrame({"road": road, "k": k}, geometry=geoms, crs=roads.crs)


def territories(pieces: np.ndarray, spacing_m: float = 3.0) -> np.ndarray:
    """For each piece, the part of the plane nearer to it than to any other piece (approximately).

    Voronoi cells of points sampled every ``spacing_m`` along the pieces (never at their shared
    ends), dissolved per piece.
    """
    lengths = shapely.length(pieces)
    n = np.maximum(1, np.ceil(lengths / spacing_m).astype(int))
    idx = np.repeat(np.arange(len(pieces)), n)
    rank = np.arange(len(idx)) - np.repeat(np.cumsum(n) - n, n)
    points = shapely.line_interpolate_point(pieces[idx], (rank + 0.5) / n[idx] * lengths[idx])
    xy = shapely.get_coordinates(points)
    _, unique_first = np.unique(node_keys(xy), return_index=True)
    keep = np.sort(unique_first)
    xy, idx = xy[keep], idx[keep]
    extent = shapely.box(*shapely.total_bounds(pieces)).buffer(200.0)
    cells = shapely.voronoi_polygons(shapely.multipoints(xy), extend_to=extent, ordered=True)
    cells = shapely.get_parts(cells)
    # Dissolve per piece in one call: one row per piece, its cells padded with None.
    order = np.argsort(idx, kind="stable")
    idx, cells = idx[order], cells[order]
    rank = np.arange(len(idx)) - np.searchsorted(idx, idx)
    table = np.full((len(pieces), int(rank.max()) + 1 if len(rank) else 1), None, dtype=object)
    table[idx, rank] = cells
    return dissolve_rows(table)


def dissolve_rows(table: np.ndarray) -> np.ndarray:
    """Union of each row of a (rows, k) object array of polygons (``None`` pads), for a coverage.

    GEOS's coverage union is fast but assumes the polygons of a row neither overlap nor meet at
    unmatched vertices, and GEOS 3.14 refuses such a row ("CoverageUnion cannot process incorrectly
    noded inputs"). Voronoi cells are such a coverage only up to rounding: GEOS clips the cells at
    the diagram's extent one by one, so the shared edges of far-flung or nearly collinear samples
    may not match. Then the overlay union (about 4x slower, no assumption) does the work.
    """
    try:
        return shapely.coverage_union_all(table, axis=1)
    except shapely.errors.GEOSException as exc:
        log.debug("cells are not a clean coverage (%s); dissolving with union_all", exc)
        return shapely.union_all(table, axis=1)


def junction_keys(lines: np.ndarray) -> np.ndarray:
    """:func:`~curbside.osmseg.streets.node_keys` of the vertices two or more lines share."""
    xy, idx = shapely.get_coordinates(lines, return_index=True)
    table = pd.DataFrame({"key": node_keys(xy), "line": idx}).drop_duplicates()
    counts = table.groupby("key").size()
    return counts.index.to_numpy()[counts.to_numpy() >= 2]


def extend_shared_ends(
    lines: np.ndarray,
    length_m: np.ndarray,
    others: np.ndarray | None = None,
    own: np.ndarray | None = None,
    snap_m: float = 15.0,
) -> np.ndarray:
    """Lines prolonged straight by ``length_m`` at every end at a junction; dead ends left alone.

    Parameters
    ----------
    lines
        LineStrings.
    length_m
        Per line, how far to prolong it.
    others, own
        Further lines (the roads) and, per line, the index in ``others`` of the one it is part of:
        an end within ``snap_m`` of another of ``others`` is a junction too (also a road that stops
        at the curb of a cross street instead of at its centreline).
    snap_m
        See ``others``.

    Notes
    -----
    An end is always a junction when another of ``lines`` ends at the same point. A closed line (a
    loop road, a roundabout without another junction) is left alone: its ends meet each other, and
    its band (:func:`~curbside.osmseg.streets.side_buffers`) has no end to prolong.
    """
    xy, idx = shapely.get_coordinates(lines, return_index=True)
    n = np.bincount(idx, minlength=len(lines))
    start = np.cumsum(n) - n
    end = start + n - 1
    tips = np.concatenate([xy[start], xy[end]])
    _, inverse, counts = np.unique(node_keys(tips), return_inverse=True, return_counts=True)
    shared = counts[inverse] >= 2
    if others is not None and own is not None:
        tree = shapely.STRtree(others)
        tip_i, other_i = tree.query(shapely.points(tips), predicate="dwithin", distance=snap_m)
        foreign = other_i != np.tile(own, 2)[tip_i]
        shared[tip_i[foreign]] = True
    shared = shared.reshape(2, -1) & ~shapely.is_closed(lines)

    def prolong(tip: np.ndarray, before: np.ndarray, on: np.ndarray) -> np.ndarray:
        direction = xy[tip] - xy[before]
        direction /= np.maximum(np.linalg.norm(direction, axis=1, keepdims=True), 1e-9)
        return xy[tip] + direction * (length_m * on)[:, None]

    new_start = prolong(start, start + 1, shared[0])
    new_end = prolong(end, end - 1, shared[1])
    # One line's new end and the next line's new start go in at the same index: end first.
    out_xy = np.insert(xy, np.r_[end + 1, start], np.concatenate([new_end, new_start]), axis=0)
    return shapely.linestrings(out_xy, indices=np.repeat(np.arange(len(lines)), n + 2))


def mapped_far_edges_m(
    lines: np.ndarray,
    mapped: gpd.GeoDataFrame | None,
    search_m: float,
    blockers: np.ndarray | None = None,
    own_blocker: np.ndarray | None = None,
) -> np.ndarray:
    """How far from each block's centreline the far edge of the mapped sidewalk beside it lies.

    Parameters
    ----------
    lines
        Block centrelines in a metric CRS, or the stretches of them that their rays stand for
        (:func:`~curbside.osmseg.reach.ray_stretches`): then each gets one ray, and its own far edge.
    mapped
        Separately mapped sidewalks with ``width_m``
        (:func:`~curbside.osmseg.streets.mapped_sidewalks`), or None.
    search_m
        Sidewalks further than this from the centreline are not the block's.
    blockers, own_blocker
        Buildings and other roads: a sidewalk behind one is not the block's
        (:func:`~curbside.osmseg.streets.side_distances`).

    Returns
    -------
    numpy.ndarray
        Shape (n, 2), metres to the left and right: the median over rays square to the line, every
        ``RAY_STEP_M``, of the distance to the nearest sidewalk running within about 25 degrees of
        parallel, plus half its width; NaN where fewer than half the rays meet one.
    """
    if mapped is None or len(mapped) == 0:
        return np.full((len(lines), 2), np.nan)
    setback = -mapped["width_m"].to_numpy() / 2
    return side_distances(
        lines, mapped.geometry.values, setback, search_m, parallel_only=True, step_m=RAY_STEP_M,
        blockers=blockers, own_blocker=own_blocker, min_hit_share=_MIN_HIT_SHARE,
    )


def sidewalk_segments(
    roads: gpd.GeoDataFrame,
    obstacles: np.ndarray,
    min_area_m2: float = 2.0,
    config: SegmentationConfig | None = None,
    buildings: np.ndarray | None = None,
    mapped: gpd.GeoDataFrame | None = None,
) -> gpd.GeoDataFrame:
    """Sidewalk segments along the roads that carry sidewalks.

    Parameters
    ----------
    roads
        :attr:`curbside.osmseg.streets.Carriageways.roads` (with ``half_left_m``/``half_right_m``).
    obstacles
        Small polygons a sidewalk may not overlap: carriageway tiles, buildings, crosswalks.
    min_area_m2
        Smaller leftovers (corner slivers) are dropped.
    config
        Which streets carry sidewalks, how deep (default :class:`~curbside.osmseg.config.SegmentationConfig`).
    buildings
        Building footprints: a median (:func:`~curbside.osmseg.medians.median_sides`) has none.
    mapped
        Separately mapped sidewalks (:attr:`curbside.osmseg.streets.Carriageways.sidewalks`): where
        the one beside a block lies beyond the curb plus ``sidewalk_depth_m``, that side's band
        reaches out to its far edge (:func:`mapped_far_edges_m`): the median over the block, and ray
        by ray along a long enough run of rays that meet it (:func:`~curbside.osmseg.reach.reach_polygons`),
        short of buildings and other carriageways.

    Returns
    -------
    geopandas.GeoDataFrame
        ``segment_id`` (``w<way id>-<k>-<L|R>``, ``k`` counting the segments of that side along
        the way), ``street``, ``side`` (``left``/``right``), ``facing_deg`` (:func:`facing_bearings_deg`),
        ``osm_id`` and geometry.
    """
    config = config or SegmentationConfig()
    block_end_mask = ~is_in(column(roads, "service"), MINOR_SERVICES)
    carrying_mask = is_in(column(roads, "highway"), config.sidewalk_highways)
    carrying = roads[carrying_mask].reset_index(drop=True)
    if len(carrying) == 0:
        columns = ("segment_id", "street", "side", "facing_deg", "osm_id")
        return gpd.GeoDataFrame({c: [] for c in columns}, geometry=[], crs=roads.crs)
    pieces = split_at_junctions(carrying, roads.geometry.values[block_end_mask])
    lines = pieces.geometry.values
    road = pieces["road"].to_numpy()
    has_left, has_right = sidewalk_sides(carrying)
    half_m = np.column_stack([carrying["half_left_m"].to_numpy(), carrying["half_right_m"].to_numpy()])
    base = half_m[road] + config.sidewalk_depth_m
    road_row = np.flatnonzero(carrying_mask)[road]
    bands, centrelines, further = _reaching_bands(
        lines, base, mapped, config.mapped_sidewalk_search_m, roads.geometry.values, road_row, buildings,
        own := territories(lines),
    )
    side, piece_of = np.repeat(["left", "right"], len(lines)), np.tile(np.arange(len(lines)), 2)
    median_left, median_right = median_sides(lines, road, carrying, config.max_median_width_m, buildings)
    present = np.concatenate([has_left[road] & ~median_left, has_right[road] & ~median_right])
    bands = shapely.intersection(bands[present], own[piece_of[present]])
    side, piece_of = side[present], piece_of[present]
    signed_base = np.concatenate([base[:, 0], -base[:, 1]])[present]
    parts, part_of = _band_parts(
        subtract(bands, obstacles), min_area_m2, centrelines[present], signed_base, further[present]
    )
    piece = piece_of[part_of]
    way_row = road[piece]
    osm_id = carrying["osm_id"].to_numpy()[way_row]
    along = shapely.line_locate_point(carrying.geometry.values[way_row], shapely.centroid(parts))
    k = pieces["k"].to_numpy()[piece]
    segment_id = _segment_ids(
        pd.DataFrame({"osm_id": osm_id, "row": way_row, "side": side[part_of], "k": k, "along": along})
    )
    names = street_names(carrying, config.street_name_keys)[way_row]
    facing = facing_bearings_deg(parts, lines[piece], side[part_of])
    return gpd.GeoDataFrame(
        {"segment_id": segment_id, "street": names, "side": side[part_of], "facing_deg": facing,
         "osm_id": osm_id},
        geometry=shapely.make_valid(parts),
        crs=roads.crs,
    )


def _reaching_bands(
    lines: np.ndarray,
    base_m: np.ndarray,
    mapped: gpd.GeoDataFrame | None,
    search_m: float,
    roads: np.ndarray,
    road_row: np.ndarray,
    buildings: np.ndarray | None,
    own: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The band of each block side (:func:`_bands`), out to the mapped sidewalk stretch by stretch.

    Returns the bands and their centrelines (left sides, then right sides) and whether each band
    reaches beyond ``base_m``. The rays of :func:`mapped_far_edges_m`, one per stretch of
    :func:`~curbside.osmseg.reach.ray_stretches`, give both the side's median reach (:func:`_bands`)
    and, where a long enough run of them meets the sidewalk inside the block's territory (``own``),
    the outline that follows it (:func:`~curbside.osmseg.reach.reach_polygons`).
    """
    blockers = np.concatenate([roads, [] if buildings is None else buildings])
    stretches, stretch_of = ray_stretches(lines)
    far_ray = mapped_far_edges_m(stretches, mapped, search_m, blockers, road_row[stretch_of])
    far = _median_far_m(far_ray, stretch_of, len(lines))
    bands, centrelines = _bands(lines, base_m, far, roads, road_row)
    reach, band_of = reach_polygons(stretches, stretch_of, far_ray, base_m, own)
    further = (np.fmax(base_m, far) > base_m).T.ravel()
    further[band_of] = True
    return _union_per_row(bands, reach, band_of), centrelines, further


def _median_far_m(far_ray: np.ndarray, stretch_of: np.ndarray, n_lines: int) -> np.ndarray:
    """Per line and side (shape (n_lines, 2)), the median of its rays' ``far_ray``; NaN where fewer
    than half its rays meet a sidewalk."""
    out = np.full((n_lines, 2), np.nan)
    n_rays = np.bincount(stretch_of, minlength=n_lines)
    for side in range(2):
        met = ~np.isnan(far_ray[:, side])
        per_line = pd.Series(far_ray[met, side]).groupby(stretch_of[met]).agg(["median", "size"])
        line = per_line.index.to_numpy()
        enough = per_line["size"].to_numpy() >= _MIN_HIT_SHARE * n_rays[line]
        out[line[enough], side] = per_line["median"].to_numpy()[enough]
    return out


def _union_per_row(geoms: np.ndarray, extra: np.ndarray, row: np.ndarray) -> np.ndarray:
    """``geoms`` with each of ``extra`` unioned into ``geoms[row]``."""
    if len(extra) == 0:
        return geoms
    order = np.argsort(row, kind="stable")
    row, extra = row[order], extra[order]
    rows, first = np.unique(row, return_index=True)
    rank = np.arange(len(row)) - first[np.searchsorted(rows, row)]
    table = np.full((len(rows), int(rank.max()) + 2), None, dtype=object)
    table[:, 0] = geoms[rows]
    table[np.searchsorted(rows, row), rank + 1] = extra
    out = geoms.copy()
    out[rows] = shapely.union_all(table, axis=1)
    return out


def _bands(
    lines: np.ndarray, base_m: np.ndarray, far_m: np.ndarray, roads: np.ndarray, road_row: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """The band of each block side, left sides then right sides, and the centreline it was built on.

    A side reaches ``base_m`` (curb plus sidewalk depth; shape (n, 2), left and right) from the
    block's centreline, or ``far_m`` (:func:`mapped_far_edges_m`) where that is further. Bands run on
    past junction ends (:func:`extend_shared_ends`, with ``roads`` and ``road_row``) so that they also
    cover the outside of bends and corners; the territories then split the overlap. Each side is
    prolonged as far as it reaches, so that a side reaching out to a mapped sidewalk leaves the band
    on the other side as it was.
    """
    reach_m = np.fmax(base_m, far_m)
    prolong_m = base_m.max(axis=1)
    centrelines = np.concatenate(
        [extend_shared_ends(lines, np.fmax(prolong_m, far), roads, road_row) for far in far_m.T]
    )
    return side_buffers(centrelines, np.concatenate([reach_m[:, 0], -reach_m[:, 1]])), centrelines


def _band_parts(
    bands: np.ndarray, min_area_m2: float, centrelines: np.ndarray, base_m: np.ndarray, further: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """The polygons of at least ``min_area_m2`` that make up the bands, and the band of each.

    Of a band that reaches ``further`` than its ``base_m`` (signed: positive left of its centreline),
    the parts that lie wholly beyond that depth are left out: what a building or another carriageway
    cuts off there (the sidewalk of the courtyard or alley behind it) is not this block side's.
    """
    parts, part_of = shapely.get_parts(bands, return_index=True)
    polygonal = (shapely.get_type_id(parts) == 3) & (shapely.area(parts) >= min_area_m2)
    parts, part_of = parts[polygonal], part_of[polygonal]
    reaching = further[part_of]
    near = side_buffers(centrelines[part_of[reaching]], base_m[part_of[reaching]])
    kept = ~reaching
    kept[reaching] = shapely.area(shapely.intersection(parts[reaching], near)) >= _MIN_REACH_OVERLAP_M2
    return parts[kept], part_of[kept]


def street_names(roads: pd.DataFrame, keys: tuple[str, ...] = ("name", "ref")) -> np.ndarray:
    """Each road's name: the first of the tags ``keys`` it has (None if none).

    With the default a road with a number but no name (A38, B 19) is called by its number, as its
    signs say; ``("name:en", "name", "ref")`` prefers English where OSM has it. A value of nothing but
    question marks (``???``: text an export step could not encode, as in the bundled extract's
    ``name:zh``) counts as absent, with a warning.
    """
    names = pd.Series([None] * len(roads), index=roads.index, dtype=object)
    for key in keys:
        values = column(roads, key)
        lost = values.str.fullmatch(r"[?\s]+").fillna(False).astype(bool) if values.notna().any() else None
        if lost is not None and lost.any():
            log.warning(
                "%d way(s) have %s=%r and the like: text lost to an encoding step before the file was "
                "written; read as absent", int(lost.sum()), key, values[lost].iloc[0],
            )
            values = values.where(~lost, None)
        names = names.fillna(values)
    return names.to_numpy(dtype=object)


def facing_bearings_deg(parts: np.ndarray, centrelines: np.ndarray, sides: np.ndarray) -> np.ndarray:
    """Bearing from each part's street to the part (degrees clockwise from the CRS's grid north).

    Parameters
    ----------
    parts
        Sidewalk polygons in a metric CRS.
    centrelines
        The block centreline each part was built from (same length).
    sides
        ``"left"`` or ``"right"`` of the centreline's drawing direction, per part.

    Returns
    -------
    numpy.ndarray
        The centreline's normal on the part's side where the centreline passes nearest the part's
        centroid (its direction over 2 m either way, so a kink does not decide it), rounded to 0.1°;
        NaN for a centreline without length.
    """
    if len(parts) == 0:
        return np.empty(0)
    at = shapely.line_locate_point(centrelines, shapely.centroid(parts))
    length = shapely.length(centrelines)
    ahead = shapely.get_coordinates(shapely.line_interpolate_point(centrelines, np.minimum(at + 2.0, length)))
    behind = shapely.get_coordinates(shapely.line_interpolate_point(centrelines, np.maximum(at - 2.0, 0.0)))
    dx, dy = (ahead - behind).T
    left = np.where(np.asarray(sides) == "left", 1.0, -1.0)
    # The side's normal, (-dy, dx) to the left, as a bearing (clockwise from north: atan2(east, north)).
    bearing = np.degrees(np.arctan2(-dy * left, dx * left)) % 360.0
    return np.where(np.hypot(dx, dy) > 1e-9, np.round(bearing, 1) % 360.0, np.nan)


def _segment_ids(parts: pd.DataFrame) -> np.ndarray:
    """``w<way id>-<n>-<L|R>`` per part, ``n`` numbering the parts of one way side in order along it.

    ``parts`` has ``osm_id``, ``row`` (the way's row), ``side``, ``k`` (its block along the row) and
    ``along`` (the part's position along the row). A way the reader cut where its file lacks nodes has
    several rows: they are numbered on, in order.
    """
    table = parts.sort_values(["osm_id", "side", "row", "k", "along"], kind="stable")
    table["n"] = table.groupby(["osm_id", "side"]).cumcount()
    table = table.sort_index()
    return (
        "w" + table["osm_id"].astype(str) + "-" + table["n"].astype(str)
        + "-" + table["side"].map({"left": "L", "right": "R"})
    ).to_numpy()  # fmt: skip
