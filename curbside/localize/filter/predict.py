"""The motion model: each particle moves by the inertial displacement, turned and scaled by its own state.

At an update with inertial displacement ``(dx, dy)`` (metres east/north over the step):

1. a few particles take an abrupt heading-offset jump (probability ``heading_jump_prob`` each, sigma
   ``heading_jump_sigma_deg``): the phone changed hands or went into a pocket, and the inertial heading
   moved by tens of degrees at once. The jumps are a mixture proposal; the likelihoods decide which
   jumped particles survive;
2. every particle's heading offset ``theta`` takes a random-walk increment and its speed scale too;
3. every particle moves by ``(dx, dy)`` rotated by ``theta`` and multiplied by ``scale``, plus isotropic
   position noise of sigma ``max(step_noise_floor_m, step_noise_fraction * |(dx, dy)|)``: the error of
   an inertial step grows with its length, and the floor keeps a standing cloud alive.

The random numbers are drawn with the filter's seeded numpy generator into preallocated buffers; the
arithmetic is one compiled loop (:func:`_predict`). :func:`reference_predict` is the numpy oracle the
tests compare it with.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from curbside.localize.filter.config import MotionConfig
from curbside.localize.filter.particles import COS, SCALE, SIN, THETA, ParticleSet, X, Y


class InertialPredictor:
    """Moves particles by inertial displacements (see the module docstring).

    Parameters
    ----------
    config
        Noise parameters.
    n
        Number of particles.
    rng
        The filter's seeded generator.
    """

    def __init__(self, config: MotionConfig, n: int, rng: np.random.Generator) -> None:
        self.config = config
        self.rng = rng
        self.theta_sigma = math.radians(config.heading_noise_deg)
        self.scale_sigma = config.scale_noise_per_step
        self.jump_sigma = math.radians(config.heading_jump_sigma_deg)
        self.noise = np.zeros((4, n))  # standard normals: x, y, theta, scale
        # Without a scale random walk its row stays zero and is not drawn (fewer normals per update).
        self._drawn = self.noise if self.scale_sigma > 0 else self.noise[:3]
        self._no_jumps = (np.zeros(0, np.int64), np.zeros(0))

    def position_sigma(self, dx: float, dy: float) -> float:
        """Position noise sigma (m) of a step with displacement ``(dx, dy)``."""
        return max(self.config.step_noise_floor_m, self.config.step_noise_fraction * math.hypot(dx, dy))

    def draw(self, n: int) -> tuple[np.ndarray, np.ndarray]:
        """Draw this update's standard normals into :attr:`noise`; return the jumps ``(index, radians)``."""
        self.rng.standard_normal(out=self._drawn)
        if self.config.heading_jump_prob <= 0:
            return self._no_jumps
        k = int(self.rng.binomial(n, self.config.heading_jump_prob))
        if k == 0:
            return self._no_jumps
        return self.rng.integers(0, n, k), self.jump_sigma * self.rng.standard_normal(k)

    def predict(self, particles: ParticleSet, dx: float, dy: float) -> None:
        """Move ``particles`` in place by the step displacement ``(dx, dy)`` metres (east, north)."""
        jump_idx, jump_rad = self.draw(len(particles))
        _predict(
            particles.state,
            self.noise,
            dx,
            dy,
            self.position_sigma(dx, dy),
            self.theta_sigma,
            self.scale_sigma,
            jump_idx,
            jump_rad,
        )


@numba.njit(cache=True, nogil=True)
def _predict(
    state, noise, dx, dy, sigma_xy, sigma_theta, sigma_scale, jump_idx, jump_rad
):  # pragma: no cover
    for j in range(jump_idx.shape[0]):
        state[THETA, jump_idx[j]] += jump_rad[j]
    for i in range(state.shape[1]):
        th = state[THETA, i] + sigma_theta * noise[2, i]
        sc = state[SCALE, i] + sigma_scale * noise[3, i]
        c = math.cos(th)
        s = math.sin(th)
        state[THETA, i] = th
        state[SCALE, i] = sc
        state[COS, i] = c
        state[SIN, i] = s
        state[X, i] += (c * dx - s * dy) * sc + sigma_xy * noise[0, i]
        state[Y, i] += (s * dx + c * dy) * sc + sigma_xy * noise[1, i]


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
) -> np.ndarray:
    """The numpy oracle of the compiled update (tests only): the new state, ``state`` untouched."""
    out = state.copy()
    np.add.at(out[THETA], jump_idx, jump_rad)
    out[THETA] += sigma_theta * noise[2]
    out[SCALE] += sigma_scale * noise[3]
    out[COS], out[SIN] = np.cos(out[THETA]), np.sin(out[THETA])
    out[X] += (out[COS] * dx - out[SIN] * dy) * out[SCALE] + sigma_xy * noise[0]
    out[Y] += (out[SIN] * dx + out[COS] * dy) * out[SCALE] + sigma_xy * noise[1]
    return out
