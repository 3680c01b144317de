"""What the velocity stream says about the velocity model: does it know this walker, or not?

Two tests, each fed by the engine (:mod:`curbside.localize.engine`) with inputs that are final at the
update it makes, so that a file and a live feed decide at the same update:

- :class:`StillSpeedCheck` (``unseen_velocity.mode = auto``): a model new to the phone or the place reads
  the phone being handled as motion while its walker stands; one that knows them reads almost nothing.
- :class:`SpeedJitterCheck` (``familiar_velocity.mode = auto``): while the walker walks, a model that
  knows the phone, the gait and the place gives a smooth speed from one half-second window to the next;
  one new to them jitters.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from curbside.localize.runconfig import FamiliarVelocityConfig, UnseenVelocityConfig


class StillSpeedCheck:
    """Collects the inertial speed of time-grid updates (no footstep) under the standing bound, and
    decides once whether the velocity model reads motion at a standstill."""

    def __init__(self, config: UnseenVelocityConfig) -> None:
        self.config = config
        self.speeds: list[float] = []

    def caught(self, speed_mps: float, since_step_s: float) -> bool:
        """Add one time-grid update's speed (``since_step_s`` after the last footstep); ``True`` exactly
        once, when the model is caught."""
        c = self.config
        counts = speed_mps < c.standing_speed_mps and since_step_s >= c.settle_s
        if not counts or len(self.speeds) >= c.still_updates:
            return False
        self.speeds.append(speed_mps)
        return len(self.speeds) == c.still_updates and self.median_mps >= c.still_speed_mps

    @property
    def median_mps(self) -> float:
        """Median speed of the standstill updates collected so far."""
        return float(np.median(self.speeds))


class SpeedJitterCheck:
    """Whether the inertial speed reads smooth while the walker walks.

    The cumulative displacement is sampled every ``window_s`` seconds from ``t0``; each window's speed is
    its displacement over ``window_s``. Two consecutive windows both at least ``min_speed_mps`` give
    one sample, their relative change ``|v2 - v1| / mean(v1, v2)``. The speed reads smooth while the
    median of all samples so far is under ``jitter_max``, from ``min_samples`` samples on; at
    ``final_samples`` that becomes the verdict (:attr:`final`).

    Parameters
    ----------
    config
        The thresholds (:class:`~curbside.localize.runconfig.FamiliarVelocityConfig`).
    t0
        Start of the first window (the first update).
    d0
        The cumulative inertial displacement at ``t0`` (metres east, north).
    """

    def __init__(self, config: FamiliarVelocityConfig, t0: float, d0: np.ndarray) -> None:
        self.config = config
        self.samples: list[float] = []
        #: ``True`` / ``False`` once the decision is final; ``None`` before.
        self.final: bool | None = None
        self._edge_t = float(t0)
        self._edge_d = np.asarray(d0, float)
        self._prev_speed = math.nan

    def observe(self, displacement_at: Callable[[float], np.ndarray], t: float) -> None:
        """Take in every window that ends at or before ``t`` (``displacement_at``: ``D(t)``, final there)."""
        c = self.config
        while self.final is None and self._edge_t + c.window_s <= t:
            self._edge_t += c.window_s
            d = displacement_at(self._edge_t)
            speed = math.hypot(*(d - self._edge_d)) / c.window_s
            self._edge_d = d
            if speed >= c.min_speed_mps and self._prev_speed >= c.min_speed_mps:  # False while NaN
                self.samples.append(abs(speed - self._prev_speed) / (0.5 * (speed + self._prev_speed)))
                if c.final_samples and len(self.samples) >= c.final_samples:
                    self.final = self._smooth()
            self._prev_speed = speed

    @property
    def smooth(self) -> bool:
        """Whether the speed reads smooth now (the final verdict once there is one)."""
        return self.final if self.final is not None else self._smooth()

    @property
    def median_jitter(self) -> float:
        """Median relative speed change of the samples so far (NaN before any)."""
        return float(np.median(self.samples)) if self.samples else math.nan

    def _smooth(self) -> bool:
        return len(self.samples) >= self.config.min_samples and self.median_jitter < self.config.jitter_max
