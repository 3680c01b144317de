"""The motion model: each particle moves by the inertial displacement, turned and scaled by its own state.

At an update with inertial displacement ``(dx, dy)`` (metres east/north over the step):

1. a few particles take an abrupt heading-offset jump (probability ``heading_jump_prob`` each, sigma
   ``heading_jump_sigma_deg``): the phone changed hands or went into a pocket, and the inertial heading
   moved by tens of degrees at once. The jumps are a mixture proposal; the likelihoods decide which
   jumped particles survive;
2. every particle's heading offset ``theta`` takes a random-walk increment and its speed scale too;
3. every particle moves by ``(dx, dy)`` rotated by ``theta`` and multiplied by ``scale``, plus isotropic
   position noise of sigma ``max(step_noise_floor_m, step_noise_fraction * |(dx, dy)|)``: the error of
   an inertial step grows with its length, and the floor keeps a standing cloud alive. With
   ``step_noise_across_fraction`` the noise is that sigma along the particle's own step and
   ``max(floor, across_fraction * |(dx, dy)|)`` across it (the same draws, turned onto the step).
   An update more than ``gap_s`` after the previous one leaves the walker's motion over that gap
   unknown (an app stopped, a phone asleep; the engine updates at least every second): its position
   noise is at least ``gap_spread_mps`` times the gap, isotropic, so the cloud says how little is known
   and the next fixes can find the walker.

The predictor owns a :class:`~curbside.localize.filter.random.Stream` seeded from the filter's
generator, and its compiled kernel (:func:`_predict`) draws the normals as it goes, with no buffer:
first the jumps (each particle jumps independently; the gap to the next jumping particle is geometric,
so that costs ``O(jumps)`` draws, not ``O(N)``), then for each particle the normals of ``x``, ``y``,
``theta`` and, with a scale random walk, ``scale``. A second, branch-free loop turns and moves the
particles (:func:`curbside.localize.filter.kernelmath.sincos`: it runs on SIMD lanes).
:func:`reference_draws` replays that order and :func:`reference_predict` is the numpy oracle the tests
compare the kernel with.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from curbside.localize.filter.config import MotionConfig
from curbside.localize.filter.kernelmath import in_range, sincos
from curbside.localize.filter.particles import COS, SCALE, SIN, THETA, ParticleSet, X, Y
from curbside.localize.filter.random import (
    Stream,
    draw_random,
    draw_standard_normal,
    load,
    next_double,
    standard_normal,
    store,
)


class InertialPredictor:
    """Moves particles by inertial displacements (see the module docstring).

    Parameters
    ----------
    config
        Noise parameters.
    n
        Number of particles (the parts' common signature; nothing is allocated per particle).
    rng
        The filter's seeded generator (seeds the predictor's own :attr:`stream`).
    """

    def __init__(self, config: MotionConfig, n: int, rng: np.random.Generator) -> None:
        self.config = config
        self.stream = Stream(rng)

    @property
    def config(self) -> MotionConfig:
        """The noise parameters (a tracker may swap them mid-walk: the per-update constants follow)."""
        return self._config

    @config.setter
    def config(self, config: MotionConfig) -> None:
        self._config = config
        # What predict() passes to the kernel at every update, in radians, computed once per config.
        self._constants = (
            config.step_noise_floor_m,
            config.step_noise_fraction,
            config.step_noise_across_fraction,
            math.radians(config.heading_noise_deg),
            config.scale_noise_per_step,
            config.heading_jump_prob,
            math.radians(config.heading_jump_sigma_deg),
        )

    @property
    def theta_sigma(self) -> float:
        """Heading-offset random walk per update (radians)."""
        return self._constants[3]

    @property
    def scale_sigma(self) -> float:
        """Speed-scale random walk per update."""
        return self._constants[4]

    @property
    def jump_sigma(self) -> float:
        """Sigma of a heading-offset jump (radians)."""
        return self._constants[6]

    def position_sigma(self, dx: float, dy: float) -> float:
        """Position noise sigma (m) of a step with displacement ``(dx, dy)`` (along it, when anisotropic)."""
        return max(self.config.step_noise_floor_m, self.config.step_noise_fraction * math.hypot(dx, dy))

    def across_sigma(self, dx: float, dy: float) -> float:
        """Position noise sigma (m) across the step (the same as :meth:`position_sigma` when isotropic)."""
        across = self.config.step_noise_across_fraction
        if across is None:
            return self.position_sigma(dx, dy)
        return max(self.config.step_noise_floor_m, across * math.hypot(dx, dy))

    def gap_sigma(self, dt_s: float) -> float:
        """Position noise sigma (m) that an update ``dt_s`` after the previous one has at least (0 unless
        ``dt_s`` exceeds ``gap_s``)."""
        return self.config.gap_spread_mps * dt_s if dt_s > self.config.gap_s else 0.0

    def predict(self, particles: ParticleSet, dx: float, dy: float, dt_s: float = 0.0) -> None:
        """Move ``particles`` in place by the step displacement ``(dx, dy)`` metres (east, north) made
        over ``dt_s`` seconds since the previous update."""
        # position_sigma and across_sigma, inline: this is once per footstep.
        floor, fraction, across, theta_sigma, scale_sigma, jump_prob, jump_sigma = self._constants
        length = math.hypot(dx, dy)
        sigma = max(floor, fraction * length)
        sigma_across = sigma if across is None else max(floor, across * length)
        if dt_s > self.config.gap_s:  # the motion over the gap is unknown
            sigma = sigma_across = max(sigma, sigma_across, self.gap_sigma(dt_s))
        _predict(particles.state, self.stream.state, dx, dy, sigma, sigma_across, theta_sigma, scale_sigma,
                 jump_prob, jump_sigma)


@numba.njit(cache=True, nogil=True)
def _predict(
    state, rng_state, dx, dy, sigma_xy, sigma_across, sigma_theta, sigma_scale, jump_prob, jump_sigma
):  # pragma: no cover - compiled
    n = state.shape[1]
    turned = sigma_across != sigma_xy  # anisotropic: the position draws wait for each particle's step
    z_pos = np.empty((2, n if turned else 0))
    s = load(rng_state)
    if jump_prob > 0:
        log_miss = math.log1p(-jump_prob)
        i = -1
        while True:
            u, s = next_double(s)
            gap = math.floor(math.log1p(-u) / log_miss)  # particles skipped before the next jump
            if gap >= n - 1 - i:
                break
            i += 1 + int(gap)
            z, s = standard_normal(s)
            state[THETA, i] += jump_sigma * z
    out_of_range = False
    for i in range(n):  # the draws (one stream: a sequential loop)
        zx, s = standard_normal(s)
        zy, s = standard_normal(s)
        zt, s = standard_normal(s)
        th = state[THETA, i] + sigma_theta * zt
        state[THETA, i] = th
        out_of_range |= not in_range(th)
        if sigma_scale > 0:
            zs, s = standard_normal(s)
            state[SCALE, i] += sigma_scale * zs
        if turned:
            z_pos[0, i], z_pos[1, i] = zx, zy
        else:
            state[X, i] += sigma_xy * zx
            state[Y, i] += sigma_xy * zy
    store(rng_state, s)
    if out_of_range:  # heading offsets beyond a thousand radians: the C library's sine and cosine
        for i in range(n):
            _move(state, i, math.cos(state[THETA, i]), math.sin(state[THETA, i]), dx, dy)
    else:  # no calls, no branches: SIMD
        for i in range(n):
            sn, c = sincos(state[THETA, i])
            _move(state, i, c, sn, dx, dy)
    if turned:
        _add_turned_noise(state, z_pos, dx, dy, sigma_xy, sigma_across)


@numba.njit(cache=True, nogil=True)
def _add_turned_noise(state, z_pos, dx, dy, sigma_along, sigma_across):  # pragma: no cover - compiled
    """Position draws ``z_pos`` along and across each particle's turned step (east if it has none)."""
    length = math.hypot(dx, dy)
    for i in range(state.shape[1]):
        c, sn = state[COS, i], state[SIN, i]
        ux, uy = 1.0, 0.0
        if length > 0:
            ux, uy = (c * dx - sn * dy) / length, (sn * dx + c * dy) / length
        along, across = sigma_along * z_pos[0, i], sigma_across * z_pos[1, i]
        state[X, i] += along * ux - across * uy
        state[Y, i] += along * uy + across * ux


@numba.njit(inline="always", cache=True, nogil=True)
def _move(state, i, c, sn, dx, dy):  # pragma: no cover - compiled
    sc = state[SCALE, i]
    state[COS, i] = c
    state[SIN, i] = sn
    state[X, i] += (c * dx - sn * dy) * sc
    state[Y, i] += (sn * dx + c * dy) * sc


def reference_draws(
    stream: Stream, n: int, jump_prob: float, jump_sigma: float, scale_walk: bool
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The draws of one :func:`_predict` call, in its order, from ``stream`` (tests only; advances it).

    Returns
    -------
    noise
        ``(4, n)`` standard normals of ``x, y, theta, scale`` (``scale`` zero without a scale walk).
    jump_idx, jump_rad
        The particles that jump and their jumps (radians).
    """
    state = stream.state
    jump_idx, jump_rad = [], []
    if jump_prob > 0:
        i = -1
        while True:
            gap = math.floor(math.log1p(-draw_random(state)) / math.log1p(-jump_prob))
            if gap >= n - 1 - i:
                break
            i += 1 + int(gap)
            jump_idx.append(i)
            jump_rad.append(jump_sigma * draw_standard_normal(state))
    noise = np.zeros((4, n))
    for i in range(n):
        for row in range(4 if scale_walk else 3):
            noise[row, i] = draw_standard_normal(state)
    return noise, np.array(jump_idx, dtype=np.int64), np.array(jump_rad)


def reference_predict(
    state: np.ndarray,
    noise: np.ndarray,
    dx: float,
    dy: float,
    sigma_xy: float,
    sigma_theta: float,
    sigma_scale: float,
    jump_idx: np.ndarray,
    jump_rad: np.ndarray,
    sigma_across: float | None = None,
) -> np.ndarray:
    """The numpy oracle of the compiled update (tests only): the new state, ``state`` untouched.
    ``sigma_across``: anisotropic, ``sigma_xy`` along each particle's turned step and this across it."""
    out = state.copy()
    np.add.at(out[THETA], jump_idx, jump_rad)
    out[THETA] += sigma_theta * noise[2]
    out[SCALE] += sigma_scale * noise[3]
    out[COS], out[SIN] = np.cos(out[THETA]), np.sin(out[THETA])
    step_x = out[COS] * dx - out[SIN] * dy
    step_y = out[SIN] * dx + out[COS] * dy
    if sigma_across is None:
        out[X] += sigma_xy * noise[0]
        out[Y] += sigma_xy * noise[1]
    else:
        ux, uy = step_x / np.hypot(dx, dy), step_y / np.hypot(dx, dy)
        out[X] += sigma_xy * noise[0] * ux - sigma_across * noise[1] * uy
        out[Y] += sigma_xy * noise[0] * uy + sigma_across * noise[1] * ux
    out[X] += step_x * out[SCALE]
    out[Y] += step_y * out[SCALE]
    return out
