"""Where a block side's sidewalk band reaches out to a separately mapped sidewalk, ray by ray.

:func:`~curbside.osmseg.sidewalks.mapped_far_edges_m` casts rays square to each block, every
``RAY_STEP_M``, and finds on each the far edge of the mapped sidewalk (``footway=sidewalk``) beside
it. Besides the median reach of a side (where at least half its rays meet one), a run of consecutive
rays that meet it over at least ``MIN_RUN_M`` gets a polygon whose outer edge follows the far edge
from ray to ray: a sidewalk that swings out along part of a block, or one mapped along only part of
it, lies in the band there and not elsewhere.
"""

from __future__ import annotations

import numpy as np
import shapely

from curbside.osmseg.overlay import substrings
from curbside.osmseg.streets import ray_origins

#: Spacing (m) of the rays along a block that look for the mapped sidewalk beside it.
RAY_STEP_M = 8.0
#: A run of consecutive rays that meet the mapped sidewalk reaches out to it, ray by ray, when the
#: stretches of the block they stand for are together at least this long (m).
MIN_RUN_M = 24.0


def ray_stretches(lines: np.ndarray, step_m: float = RAY_STEP_M) -> tuple[np.ndarray, np.ndarray]:
    """Each line cut into the stretches that its rays (:func:`~curbside.osmseg.streets.side_distances`)
    stand for, and the line of each stretch.

    A line of length L has max(1, L // ``step_m``) rays, each in the middle of an equal stretch of it,
    so :func:`~curbside.osmseg.streets.side_distances` casts the same rays on the stretches as on the
    line, one per stretch (each is under 2 ``step_m`` long).
    """
    lengths = shapely.length(lines)
    n = np.maximum(1, (lengths // step_m).astype(int))
    line_of = np.repeat(np.arange(len(lines)), n)
    rank = np.arange(len(line_of)) - np.repeat(np.cumsum(n) - n, n)
    stretch_m = lengths[line_of] / n[line_of]
    return substrings(lines, line_of, rank * stretch_m, (rank + 1) * stretch_m), line_of


def reach_polygons(
    stretches: np.ndarray,
    stretch_of: np.ndarray,
    far_m: np.ndarray,
    base_m: np.ndarray,
    territories: np.ndarray,
    min_run_m: float = MIN_RUN_M,
) -> tuple[np.ndarray, np.ndarray]:
    """The reach out to the mapped sidewalk along each run of rays that meet it.

    Parameters
    ----------
    stretches, stretch_of
        :func:`ray_stretches` of the blocks, in order along each block.
    far_m
        Per stretch, shape (n, 2): the far edge its ray meets left and right
        (:func:`~curbside.osmseg.sidewalks.mapped_far_edges_m`); NaN where none.
    base_m
        Per block, shape (n_blocks, 2): the usual depth left and right.
    territories
        Per block, the part of the plane nearer to it than to any other block
        (:func:`~curbside.osmseg.sidewalks.territories`): a ray whose far edge lies outside its
        block's has met another street's sidewalk.
    min_run_m
        A run of consecutive stretches whose rays meet a sidewalk counts when at least this long and
        when one of its rays reaches beyond ``base_m``.

    Returns
    -------
    polygons : numpy.ndarray
        Per run, the polygon from the centreline out to the far edge its rays meet: through each
        ray's far point, held level to the run's two ends.
    band : numpy.ndarray
        Per run, its block side: ``block`` for the left, ``n_blocks + block`` for the right.
    """
    _, station, tangent = ray_origins(stretches, np.ones(len(stretches), dtype=int))
    normal = np.column_stack([-tangent[:, 1], tangent[:, 0]])
    polygons, bands = [], []
    for side, sign in enumerate((1.0, -1.0)):
        offset = sign * normal * far_m[:, side, None]
        met = np.flatnonzero(~np.isnan(far_m[:, side]))
        far_xy = station[met] + offset[met]
        theirs = met[~shapely.contains_xy(territories[stretch_of[met]], far_xy[:, 0], far_xy[:, 1])]
        far = far_m[:, side].copy()
        far[theirs] = np.nan
        sel, run = _runs(stretches, stretch_of, far, base_m[:, side], min_run_m)
        if len(sel):
            polygons.append(_run_polygons(stretches[sel], run, station[sel], offset[sel]))
            bands.append(side * len(base_m) + stretch_of[sel][np.r_[True, run[1:] != run[:-1]]])
    if not polygons:
        return np.empty(0, dtype=object), np.empty(0, dtype=int)
    return np.concatenate(polygons), np.concatenate(bands)


def _run_polygons(
    stretches: np.ndarray, run: np.ndarray, station: np.ndarray, offset: np.ndarray
) -> np.ndarray:
    """Per run (``run``: 0, 1, ... per stretch, in order), the polygon out along the centreline of its
    ``stretches`` and back through each ray's ``station + offset``, held level to the run's ends."""
    head = np.r_[True, run[1:] != run[:-1]]
    tail = np.r_[run[1:] != run[:-1], True]
    start = shapely.get_coordinates(shapely.get_point(stretches, 0))
    end = shapely.get_coordinates(shapely.get_point(stretches, -1))
    inner, inner_k = shapely.get_coordinates(stretches, return_index=True)
    outer = np.concatenate([start[head] + offset[head], station + offset, end[tail] + offset[tail]])
    along = 3 * np.arange(len(stretches))
    outer_along = np.concatenate([along[head], along + 1, along[tail] + 2])
    # Out along the centreline, back along the far edge.
    key = np.concatenate([np.arange(len(inner)), -outer_along])
    part = np.repeat([0, 1], [len(inner), len(outer)])
    ring_of = np.concatenate([run[inner_k], run[head], run, run[tail]])
    order = np.lexsort((key, part, ring_of))
    rings = shapely.linearrings(np.concatenate([inner, outer])[order], indices=ring_of[order])
    return shapely.make_valid(shapely.polygons(rings), method="structure", keep_collapsed=False)


def _runs(
    stretches: np.ndarray, stretch_of: np.ndarray, far_m: np.ndarray, base_m: np.ndarray, min_run_m: float
) -> tuple[np.ndarray, np.ndarray]:
    """The stretches of one side in runs that count (:func:`reach_polygons`), and their run (0, 1, ...)."""
    met = ~np.isnan(far_m)
    same_line = np.r_[False, stretch_of[1:] == stretch_of[:-1]]
    run = np.cumsum(met & ~(same_line & np.r_[False, met[:-1]])) - 1
    run_m = np.bincount(run[met], weights=shapely.length(stretches[met]))
    beyond = np.bincount(run[met], weights=far_m[met] > base_m[stretch_of[met]]) > 0
    sel = np.flatnonzero(met & np.r_[(run_m >= min_run_m) & beyond, False][run])
    return sel, np.unique(run[sel], return_inverse=True)[1]
