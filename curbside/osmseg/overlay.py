"""Vectorised polygon overlay helpers shared by the derivation stages.

GEOS overlays cost about the vertex count of both operands, so "many small polygons minus one huge
polygon" is slow. These helpers keep every operand small: a huge polygon is cut into quadtree tiles
once, and differences run only between pairs that an STRtree finds overlapping, in rounds so that
each round is one vectorised shapely call. :func:`substrings` cuts many pieces out of many lines in
one pass, where ``shapely.ops.substring`` takes one line at a time.
"""

from __future__ import annotations

import numpy as np
import shapely
from numpy.typing import ArrayLike


def polygons_only(geoms: ArrayLike, min_area_m2: float = 0.0) -> np.ndarray:
    """The single Polygons inside ``geoms`` (multi-parts and collections exploded), at least
    ``min_area_m2`` large."""
    parts = shapely.get_parts(np.asarray(geoms, dtype=object))
    parts = parts[shapely.get_type_id(parts) == 3]
    return parts[shapely.area(parts) >= min_area_m2] if min_area_m2 > 0 else parts


def quadtree_split(geom: shapely.Geometry, max_vertices: int = 256) -> np.ndarray:
    """Cut a polygonal geometry into disjoint pieces of at most ``max_vertices`` vertices.

    Pieces that are too large are cut into the four quadrants of their bounds, level by level,
    each level one vectorised intersection.

    Returns
    -------
    numpy.ndarray
        Polygons whose union is ``geom``.
    """
    done = []
    todo = polygons_only([geom])
    while len(todo):
        small = shapely.get_num_coordinates(todo) <= max_vertices
        done.append(todo[small])
        big = todo[~small]
        if len(big) == 0:
            break
        b = shapely.bounds(big)
        mx, my = (b[:, 0] + b[:, 2]) / 2, (b[:, 1] + b[:, 3]) / 2
        x0 = np.stack([b[:, 0], mx, b[:, 0], mx], axis=1).ravel()
        x1 = np.stack([mx, b[:, 2], mx, b[:, 2]], axis=1).ravel()
        y0 = np.stack([b[:, 1], b[:, 1], my, my], axis=1).ravel()
        y1 = np.stack([my, my, b[:, 3], b[:, 3]], axis=1).ravel()
        todo = polygons_only(shapely.intersection(np.repeat(big, 4), shapely.box(x0, y0, x1, y1)))
    return np.concatenate(done) if done else np.array([], dtype=object)


def subtract(geoms: np.ndarray, obstacles: np.ndarray) -> np.ndarray:
    """``geoms[i]`` minus every obstacle that overlaps it, for small geometries and obstacles.

    Parameters
    ----------
    geoms
        Polygons to cut.
    obstacles
        Polygons to remove (they may overlap each other).

    Returns
    -------
    numpy.ndarray
        One (possibly empty or multi-part) geometry per input.
    """
    out = np.array(geoms, dtype=object, copy=True)
    obstacles = np.asarray(obstacles, dtype=object)
    if len(out) == 0 or len(obstacles) == 0:
        return out
    geom_i, obst_i = shapely.STRtree(obstacles).query(out, predicate="intersects")
    order = np.argsort(geom_i, kind="stable")
    geom_i, obst_i = geom_i[order], obst_i[order]
    rank = np.arange(len(geom_i)) - np.searchsorted(geom_i, geom_i)
    for r in range(int(rank.max()) + 1 if len(rank) else 0):
        sel = rank == r
        out[geom_i[sel]] = shapely.difference(out[geom_i[sel]], obstacles[obst_i[sel]])
    return out


def subtract_each(
    geoms: np.ndarray, ids: np.ndarray, pair_id: np.ndarray, pair_obstacle: np.ndarray
) -> np.ndarray:
    """``geoms[k]`` minus every ``pair_obstacle[p]`` whose ``pair_id[p] == ids[k]`` (``ids`` sorted).

    Like :func:`subtract`, but with the pairs given instead of found by overlap: one vectorised
    difference per round, a round per obstacle rank.
    """
    out = np.array(geoms, dtype=object, copy=True)
    slot = np.searchsorted(ids, pair_id)
    order = np.argsort(slot, kind="stable")
    slot, obstacles = slot[order], np.asarray(pair_obstacle, dtype=object)[order]
    rank = np.arange(len(slot)) - np.searchsorted(slot, slot)
    for r in range(int(rank.max()) + 1 if len(rank) else 0):
        sel = rank == r
        out[slot[sel]] = shapely.difference(out[slot[sel]], obstacles[sel])
    return out


def substrings(lines: np.ndarray, line_of: np.ndarray, start_m: np.ndarray, end_m: np.ndarray) -> np.ndarray:
    """The part of ``lines[line_of[k]]`` from ``start_m[k]`` to ``end_m[k]`` along it, for each k.

    Parameters
    ----------
    lines
        LineStrings.
    line_of, start_m, end_m
        Per part: its line, and where it starts and ends (0 <= start < end <= the line's length).

    Returns
    -------
    numpy.ndarray
        LineStrings: the two ends and the line's vertices between them.
    """
    xy, idx = shapely.get_coordinates(lines, return_index=True)
    step = np.linalg.norm(np.diff(xy, axis=0), axis=1)
    # A 1 m gap between lines keeps one line's vertices off the next one's stretch of running distance.
    step[idx[1:] != idx[:-1]] = 1.0
    run_m = np.r_[0.0, np.cumsum(step)]
    line_start_m = run_m[np.searchsorted(idx, np.arange(len(lines)))][line_of]
    lo = np.searchsorted(run_m, line_start_m + start_m, side="right")
    inner = np.maximum(np.searchsorted(run_m, line_start_m + end_m, side="left") - lo, 0)
    counts = inner + 2
    first = np.cumsum(counts) - counts
    out = np.empty((int(counts.sum()), 2))
    out[first] = shapely.get_coordinates(shapely.line_interpolate_point(lines[line_of], start_m))
    out[first + counts - 1] = shapely.get_coordinates(shapely.line_interpolate_point(lines[line_of], end_m))
    part = np.repeat(np.arange(len(line_of)), inner)
    rank = np.arange(len(part)) - np.repeat(np.cumsum(inner) - inner, inner)
    out[first[part] + 1 + rank] = xy[lo[part] + rank]
    return shapely.linestrings(out, indices=np.repeat(np.arange(len(line_of)), counts))
