"""Systematic resampling: ``N`` draws at the evenly spaced positions ``(u0 + k) / N`` of the weights' CDF.

The same rule as :func:`filterpy.monte_carlo.systematic_resample` (which draws ``u0`` from numpy's global
generator; here ``u0`` comes from the resampler's own seeded stream), compiled as one merge pass over
the weights that gathers every state row at once into the particle set's spare array; the same kernel
draws ``u0``, makes the weights uniform and writes each new particle's parent to
:attr:`~curbside.localize.filter.particles.ParticleSet.ancestors` (the fixed-lag smoother's genealogy).
"""

from __future__ import annotations

import math

import numba
import numpy as np

from curbside.localize.filter.config import ResampleConfig
from curbside.localize.filter.particles import ParticleSet
from curbside.localize.filter.random import Stream, draw_random


class SystematicResampler:
    """Seeded systematic resampling, every update or when the effective sample size drops.

    Parameters
    ----------
    config
        Policy (``"always"``, the paper's, or ``"ess"``) and ESS threshold.
    rng
        The filter's seeded generator (seeds the resampler's :attr:`stream`: one uniform per
        resampling).
    """

    def __init__(self, config: ResampleConfig, rng: np.random.Generator) -> None:
        self.config = config
        self.stream = Stream(rng)

    def resample(self, particles: ParticleSet, n_eff: float) -> bool:
        """Resample when the policy says so (weights then uniform); return whether it did."""
        if self.config.policy == "ess" and n_eff >= self.config.ess_fraction * len(particles):
            return False
        p = particles
        _resample(p.weights, p.log_weight, self.stream.state, p.state, p.spare, p.ancestors)
        p.swap()
        return True


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _resample(weights, log_weight, rng_state, state, out, ancestors):  # pragma: no cover - compiled
    _systematic_gather(weights, draw_random(rng_state), state, out, ancestors)
    n = weights.shape[0]
    log_weight[:] = -math.log(n)  # as ParticleSet.reset_weights
    weights[:] = 1.0 / n


@numba.njit(cache=True, nogil=True, error_model="numpy")  # no zero-division check in the loop
def _systematic_gather(weights, u0, state, out, ancestors):  # pragma: no cover - compiled
    # One merge pass: position k goes to the first particle whose cumulative weight exceeds it.
    n = weights.shape[0]
    rows = state.shape[0]
    j = 0
    cumulative = weights[0]
    for k in range(n):
        position = (k + u0) / n
        while position >= cumulative and j < n - 1:
            j += 1
            cumulative += weights[j]
        for r in range(rows):
            out[r, k] = state[r, j]
        ancestors[k] = j


def systematic_indices(weights: np.ndarray, u0: float) -> np.ndarray:
    """The numpy oracle: indices drawn at the positions ``(u0 + k) / N`` (tests only)."""
    n = len(weights)
    idx = np.searchsorted(np.cumsum(weights), (np.arange(n) + u0) / n, side="right")
    return np.minimum(idx, n - 1)  # rounding can leave the cumulative sum a hair below 1
