"""Where the particles start: around a known pose, or around a GNSS fix.

A known start pose (the paper's setting: the walker's start location and heading were known) seeds the
particles around it with a small spread; a pose inside a building is first moved to the nearest free
raster cell (a start tapped a metre into a footprint is a map or a tap error, not a walk through a
wall). Without a pose, the first usable fix seeds them with the fix's spread and the heading offset over
the full circle (a velocity whose yaw reference is arbitrary, e.g. from a game rotation vector).
"""

from __future__ import annotations

import logging
import math

import numpy as np

from curbside.errors import CurbsideInputError
from curbside.localize.filter.config import StartConfig
from curbside.localize.filter.map_likelihood import MapLikelihood
from curbside.localize.filter.particles import BIAS_X, BIAS_Y, SCALE, ParticleSet, X, Y
from curbside.localize.filter.parts import GnssFix
from curbside.localize.raster import BUILDING

logger = logging.getLogger(__name__)


class Initiator:
    """Seeds a particle set (see the module docstring).

    Parameters
    ----------
    config
        Start spreads and the snapping distance.
    rng
        The filter's seeded generator.
    map_likelihood
        The map, for snapping and for the first weights; ``None`` without a map.
    scale_sigma
        Initial speed-scale spread around 1 (the motion model's).
    """

    def __init__(
        self,
        config: StartConfig,
        rng: np.random.Generator,
        map_likelihood: MapLikelihood | None,
        scale_sigma: float = 0.0,
    ) -> None:
        self.config = config
        self.rng = rng
        self.map_likelihood = map_likelihood
        self.scale_sigma = scale_sigma

    def snap(self, x: float, y: float) -> tuple[float, float]:
        """``(x, y)`` moved out of a building to the nearest free cell (unchanged elsewhere).

        Raises
        ------
        CurbsideInputError
            Inside a building with no free cell within ``config.max_snap_m``.
        """
        if self.map_likelihood is None:
            return x, y
        raster = self.map_likelihood.raster
        if raster.codes_at(np.array([x]), np.array([y]))[0] < BUILDING:
            return x, y
        snapped = raster.nearest_free(x, y, self.config.max_snap_m)
        if snapped is None:
            raise CurbsideInputError(
                "start pose", f"inside a building with no free space within {self.config.max_snap_m:g} m"
            )
        logger.warning(
            "start pose lies inside a building: starting from the nearest free cell, %.1f m away",
            math.hypot(snapped[0] - x, snapped[1] - y),
        )
        return snapped

    def at_pose(self, particles: ParticleSet, x: float, y: float, heading_offset_rad: float) -> None:
        """Seed around a known pose (snapped out of buildings)."""
        x, y = self.snap(x, y)
        self.seed(
            particles,
            x,
            y,
            self.config.position_sigma_m,
            heading_offset_rad,
            math.radians(self.config.heading_sigma_deg),
        )

    def at_fix(self, particles: ParticleSet, fix: GnssFix) -> None:
        """Seed around a GNSS fix."""
        sigma = self.config.fix_sigma_factor * fix.accuracy_m
        spread = self.config.fix_heading_sigma_deg
        self.seed(particles, fix.x, fix.y, sigma, 0.0, None if spread is None else math.radians(spread))

    def seed(
        self,
        particles: ParticleSet,
        x: float,
        y: float,
        sigma_m: float,
        heading_rad: float,
        heading_sigma_rad: float | None,
    ) -> None:
        """Particles around ``(x, y)`` with heading offsets around ``heading_rad`` (``None``: any)."""
        n, rng, s = len(particles), self.rng, particles.state
        s[X] = x + sigma_m * rng.standard_normal(n)
        s[Y] = y + sigma_m * rng.standard_normal(n)
        if heading_sigma_rad is None:
            particles.set_heading(rng.uniform(-math.pi, math.pi, n))
        else:
            particles.set_heading(heading_rad + heading_sigma_rad * rng.standard_normal(n))
        s[SCALE] = 1.0 + self.scale_sigma * rng.standard_normal(n) if self.scale_sigma > 0 else 1.0
        s[BIAS_X] = s[BIAS_Y] = 0.0  # the bias means: nothing known yet
        particles.reset_weights()
        if self.map_likelihood is not None:
            particles.log_weight += self.map_likelihood.log_likelihood(s[X], s[Y])
