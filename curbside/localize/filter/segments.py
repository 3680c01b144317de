"""Which sidewalk segment: the posterior over the map's discrete segments and its mode.

Each particle votes its normalised weight to its nearest sidewalk segment (read from the raster's
nearest-segment grid); particles near no segment vote for none. For 0-1 loss on the segment the Bayes
decision is the segment of largest posterior probability (ties: the lowest index): the answer to "which
side of which street", which the weighted mean of a cloud split across a street is not. The weighted
mean of the particles on that segment is the mode estimate.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numba
import numpy as np

from curbside.localize.filter.kernelmath import cell_indices
from curbside.localize.filter.particles import ParticleSet
from curbside.localize.raster import MapRaster, RasterLookup

_new_tuple = tuple.__new__  # a named tuple from the kernel's tuple, without its constructor's overhead


class SegmentMode(NamedTuple):
    """The posterior mode over sidewalk segments at one update.

    Attributes
    ----------
    segment
        Index of the MAP segment (-1: no particle with positive weight near a sidewalk).
    prob
        Its posterior probability (0 without one).
    x, y
        Weighted mean of its particles (NaN without one).
    """

    segment: int
    prob: float
    x: float
    y: float


class SegmentEstimator:
    """The MAP sidewalk segment of a weighted cloud (see the module docstring).

    Parameters
    ----------
    raster
        A map raster with a nearest-segment grid (``raster.segment_index`` not ``None``).
    n
        Number of particles.
    """

    def __init__(self, raster: MapRaster, n: int) -> None:
        if raster.segment_index is None:
            raise ValueError("the map raster has no sidewalk segments")
        lookup = RasterLookup(raster)
        self.segment_ids = raster.segment_ids
        self._segment_id_str = [str(v) for v in raster.segment_ids]
        self._grid = (lookup.padded_segments, lookup.index_grid)
        self._segment_of = np.empty(n, lookup.padded_segments.dtype)
        self._sums = np.zeros((3, len(raster.segment_ids)))

    def mode(self, particles: ParticleSet) -> SegmentMode:
        """The MAP segment under the current normalised weights."""
        return _new_tuple(
            SegmentMode,
            _segment_mode(particles.weights, particles.state, *self._grid, self._segment_of, self._sums),
        )

    def segment_id(self, segment: int) -> str:
        """The ``segment_id`` string of segment index ``segment``."""
        return self._segment_id_str[segment]


@numba.njit(cache=True, nogil=True)
def _segment_mode(
    weights,
    state,
    padded_segments,
    grid,
    segment_of,
    sums,
):  # pragma: no cover - compiled
    # sums (3, S): weight, weight * x, weight * y per segment; all zeros on entry and on exit (only the
    # touched entries are reset, in the second loop).
    n = weights.shape[0]
    cells = cell_indices(state, grid)
    for i in range(n):
        k = padded_segments[cells[i]]
        segment_of[i] = k
        if k >= 0:
            w = weights[i]
            sums[0, k] += w
            sums[1, k] += w * state[0, i]
            sums[2, k] += w * state[1, i]
    best = -1
    prob = mx = my = 0.0
    for i in range(n):
        k = segment_of[i]
        if k < 0:
            continue
        w = sums[0, k]
        # Each segment is compared once, at its first particle (its sums are then reset to 0).
        if w > prob or (w == prob and w > 0.0 and k < best):
            best = k
            prob = w
            mx = sums[1, k]
            my = sums[2, k]
        sums[0, k] = 0.0
        sums[1, k] = 0.0
        sums[2, k] = 0.0
    if best < 0:
        return -1, 0.0, math.nan, math.nan
    return best, prob, mx / prob, my / prob


def segment_posterior(
    segment_of: np.ndarray, weights: np.ndarray, x: np.ndarray, y: np.ndarray
) -> tuple[np.ndarray, SegmentMode]:
    """The numpy oracle: summed weight per segment index and the mode (tests and analysis).

    Parameters
    ----------
    segment_of
        ``(N,)`` nearest-segment index of each particle, -1 for none.
    weights
        ``(N,)`` normalised weights.
    x, y
        ``(N,)`` particle positions.
    """
    valid = segment_of >= 0
    seg, w = segment_of[valid], weights[valid]
    if len(seg) == 0:
        return np.zeros(0), SegmentMode(-1, 0.0, math.nan, math.nan)
    segment_weights = np.bincount(seg, weights=w)
    best = int(np.argmax(segment_weights))
    prob = float(segment_weights[best])
    if not prob > 0:
        return segment_weights, SegmentMode(-1, 0.0, math.nan, math.nan)
    mx = np.bincount(seg, weights=w * x[valid])[best]
    my = np.bincount(seg, weights=w * y[valid])[best]
    return segment_weights, SegmentMode(best, prob, float(mx / prob), float(my / prob))
