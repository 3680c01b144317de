"""The street-heading likelihood: on a sidewalk, people walk along the street.

A phone's inertial heading is off by a bias, a drift and the odd jump when the phone changes hands;
each particle carries a heading offset that turns the inertial displacement, and the map likelihood
tests that offset only when a wrongly turned particle walks into a wall. Sidewalks say more: a walker
on one moves along its street, one way or the other. When the cloud agrees that it is on a sidewalk
of one direction, this part uses that direction as a measurement of the heading offset. Each particle
is weighed by how parallel its step (the inertial displacement ``d`` turned by its heading offset) is
to the street axis ``a``, with the axial (doubled-angle) von Mises density, so that walking either way
along the street is equally likely::

    log w = log((1 - floor) * exp(k * |d| * cos 2 delta) / I0(k * |d|) + floor)

``delta`` is the angle between the step and ``a``, ``k`` is ``strength_per_m`` and ``|d|`` the step's
length: the evidence grows with the distance walked, not with the number of updates, and a walker
standing still (steps under ``min_step_m``) teaches nothing. The ``floor`` bounds the term (people do
step round an obstacle).

The measurement weighs every particle the same way for the same heading offset, wherever it is. A
per-particle version (each particle against its own nearest sidewalk) was tried first and lost: it
weighs particles on a sidewalk and lets those on a street or in free space off, so the cloud drifts
off the sidewalks while it is learning its heading. So ``a`` is the cloud's: the weighted axial mean of
the axes of the sidewalk segments under the particles (:attr:`MapRaster.segment_axes`), used only when
at least ``min_sidewalk_share`` of the weight is on sidewalk cells (not crossing, not at a plaza), the
axes agree (mean resultant length of the doubled angles at least ``min_axis_agreement``: not at a
corner, where two directions meet), and the cloud's mean step, turned by each particle's offset, runs
within ``max_turn_deg`` of the axis. The last gate is for a walker turning off the street: the cloud is
still on the old sidewalk for a few seconds, and without it the term would favour the particles whose
offset turns the new direction back along the old street, and the cloud would walk on down it.

This is heuristic drift elimination (Borenstein, Ojeda & Kwanmuang 2009; Jiménez et al. 2012, "iHDE"),
which snaps a walker's heading to a building's dominant directions, put as a likelihood on the particle
filter's heading offsets, with the map's own street directions in place of assumed dominant ones.
"""

from __future__ import annotations

import math

import numba
import numpy as np
from scipy import special

from curbside.localize.filter.config import StreetHeadingConfig
from curbside.localize.filter.kernelmath import cell_indices, exp
from curbside.localize.filter.particles import COS, SIN, ParticleSet
from curbside.localize.filter.parts import Update
from curbside.localize.raster import SIDEWALK, MapRaster, RasterLookup


class StreetHeadingLikelihood:
    """Log-likelihood of each particle's heading offset given the street the cloud is on (module doc).

    Parameters
    ----------
    raster
        The map raster; it must have sidewalk segments (:attr:`MapRaster.segment_axes`).
    config
        Strength, floor, shortest step and the two gates.
    """

    def __init__(self, raster: MapRaster, config: StreetHeadingConfig) -> None:
        if raster.segment_axes is None:
            raise ValueError("the street-heading likelihood needs a map with sidewalk segments")
        self.config = config
        lk = RasterLookup(raster)
        self._grid = (lk.padded, lk.padded_segments, lk.index_grid,
                      np.ascontiguousarray(raster.segment_axes, dtype=np.float64))
        self.log_floor = math.log(config.floor)
        self.log_inlier = math.log1p(-config.floor)
        #: The street axis (unit vector) used at the last update, ``None`` when a gate held it back.
        self.last_axis: tuple[float, float] | None = None

    def street_axis(
        self, particles: ParticleSet, step_east: float, step_north: float
    ) -> tuple[float, float] | None:
        """The cloud's street axis ``(east, north)``, or ``None`` when a gate holds (module doc).

        ``step_east, step_north`` is the inertial step's direction (a unit vector): with
        ``max_turn_deg`` under 90 the axis is withheld while the cloud's mean step, turned by each
        particle's heading offset, runs farther than that from it.
        """
        sums = _axis_sums(particles.state, particles.log_weight, *self._grid, step_east, step_north)
        total, on_sidewalk, c2, s2, step_c2, step_s2 = sums
        if total <= 0 or on_sidewalk < self.config.min_sidewalk_share * total:
            return None
        if math.hypot(c2, s2) < self.config.min_axis_agreement * on_sidewalk:
            return None
        angle = 0.5 * math.atan2(s2, c2)
        if self.config.max_turn_deg < 90.0:
            turn = 0.5 * abs(math.remainder(math.atan2(step_s2, step_c2) - 2.0 * angle, 2.0 * math.pi))
            if math.degrees(turn) > self.config.max_turn_deg:
                return None
        return math.cos(angle), math.sin(angle)

    def weigh(self, particles: ParticleSet, update: Update) -> None:
        """Add each particle's street-heading log-likelihood for the step ``update.dx, dy``."""
        self.last_axis = None
        length = math.hypot(update.dx, update.dy)
        if length < self.config.min_step_m:
            return
        axis = self.street_axis(particles, update.dx / length, update.dy / length)
        if axis is None:
            return
        self.last_axis = axis
        kappa = self.config.strength_per_m * length
        log_inlier = self.log_inlier - _log_i0(kappa)
        _add_street_heading(particles.state, particles.log_weight, update.dx / length, update.dy / length,
                            axis[0], axis[1], kappa, log_inlier, self.log_floor)


def _log_i0(kappa: float) -> float:
    """``log I0(kappa)``, the von Mises normaliser, without overflow."""
    return math.log(float(special.i0e(kappa))) + kappa


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _axis_sums(state, log_weight, padded, padded_segments, grid, axes, ux, uy):  # pragma: no cover - compiled
    # Weights relative to the largest, so the sums stay finite; dead particles (-inf) add nothing.
    n = state.shape[1]
    peak = -np.inf
    for i in range(n):
        peak = max(peak, log_weight[i])
    total = on_sidewalk = c2 = s2 = step_c2 = step_s2 = 0.0
    if not np.isfinite(peak):
        return total, on_sidewalk, c2, s2, step_c2, step_s2
    weight = np.empty(n)
    for i in range(n):  # a loop of its own, with no branch, runs on SIMD lanes
        weight[i] = exp(log_weight[i] - peak)
    cells = cell_indices(state, grid)
    for i in range(n):
        w = weight[i]
        total += w
        cell = cells[i]
        k = padded_segments[cell]
        if padded[cell] == SIDEWALK and k >= 0:
            on_sidewalk += w
            ax, ay = axes[k, 0], axes[k, 1]
            c2 += w * (ax * ax - ay * ay)  # the doubled angle: a and -a are the same axis
            s2 += w * 2.0 * ax * ay
            c, s = state[COS, i], state[SIN, i]
            dx, dy = c * ux - s * uy, s * ux + c * uy  # the step turned by the particle's offset
            step_c2 += w * (dx * dx - dy * dy)
            step_s2 += w * 2.0 * dx * dy
    return total, on_sidewalk, c2, s2, step_c2, step_s2


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _add_street_heading(
    state, log_weight, ux, uy, ax, ay, kappa, log_inlier, log_floor
):  # pragma: no cover - compiled
    # logaddexp(inlier, log_floor) as max + log(sum of exps): the exps in a loop of their own run on
    # SIMD lanes; the C library's log, which keeps a loop scalar, is left to the second loop.
    n = state.shape[1]
    top = np.empty(n)
    total = np.empty(n)
    for i in range(n):
        c, s = state[COS, i], state[SIN, i]
        along = (c * ux - s * uy) * ax + (s * ux + c * uy) * ay  # cos delta
        inlier = log_inlier + kappa * (2.0 * along * along - 1.0)  # cos 2 delta = 2 cos^2 delta - 1
        peak = max(inlier, log_floor)
        top[i] = peak
        total[i] = exp(inlier - peak) + exp(log_floor - peak)
    for i in range(n):
        log_weight[i] += top[i] + math.log(total[i])


def reference_log_likelihood(
    theta: np.ndarray, dx: float, dy: float, axis: tuple[float, float], config: StreetHeadingConfig
) -> np.ndarray:
    """The numpy oracle of :func:`_add_street_heading` for heading offsets ``theta`` (tests only)."""
    length = math.hypot(dx, dy)
    kappa = config.strength_per_m * length
    delta = np.arctan2(dy, dx) + theta - math.atan2(axis[1], axis[0])
    inlier = math.log1p(-config.floor) + kappa * np.cos(2 * delta) - np.log(special.i0(kappa))
    return np.logaddexp(inlier, math.log(config.floor))
