"""How far to trust the MAP segment: its probability tempered by how long the fixes' errors last.

The posterior mass of the MAP sidewalk segment (:mod:`.segments`) is what an app would announce a side
at, but the filter counts every fix as news. Where a fix's error lasts (the receiver's smoothing, a
reflection that stays while the walker passes a tower), ten fixes that agree are closer to one, and the
mass comes out more certain than the sidewalk is right. Weighing the fixes less would cost the track
(docs/tuning.md); this part leaves the track alone and calibrates the reported number only, by
temperature scaling: ``logit(p') = logit(p) / T``.

``T`` grows with the persistence of the fixes' error, read from the walk itself without ground truth:
the innovation ``e`` (an accepted fix minus the filter's previous estimate) and its variogram at a lag,

    rho = 1 - mean |e(t) - e(t - lag)|^2 / (2 mean |e|^2),

about the share of a fix's error still there ``lag`` seconds later (0 for white fixes, near 1 for an
error that lasts). Until enough pairs are in, ``rho`` is shrunk towards a prior. Then
``T = temperature + temperature_per_persistence * clip(rho, 0, 1)``. A probability read from N particles
cannot resolve less than half a particle, so ``p`` is first held within ``[0.5 / N, 1 - 0.5 / N]``.

The same temperature widens the position's uncertainty: a likelihood raised to ``1 / T`` widens a
Gaussian posterior by ``sqrt(T)``. :func:`accuracy_radius_m` turns the cloud's spread into the radius
that holds the walker 68 % of the time, as a phone reports a fix's accuracy. Where no fix has agreed
with the estimate for a while (a GNSS outage), the map's walls cut the cloud at corners while the
inertial error grows, so :meth:`SegmentCalibration.radius_m` holds the radius at least
``radius_floor_m_per_s`` times the seconds since the last agreeing fix (or the start).
docs/filter.md, "How far to trust segment_prob" and "The position's 68 % radius", says how the values
were chosen and what they do.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from curbside.configio import check, non_negative, positive, unit_interval

#: The 68 % radius of a circular 2-D Gaussian over its root mean square radius: ``sqrt(-ln 0.32)``.
RADIUS_68_PER_RMS = math.sqrt(-math.log(0.32))


def accuracy_radius_m(spread_m: float, temperature: float = 1.0) -> float:
    """The radius that holds the walker 68 % of the time, from the cloud's root mean square distance from
    its mean (``spread_m``) widened by ``sqrt(temperature)``."""
    return RADIUS_68_PER_RMS * spread_m * math.sqrt(temperature)


#: Degrees of freedom of the radial tail :func:`radius_at_share_m` assumes (a circular bivariate
#: Student-t; ``math.inf``: a Gaussian). Chosen on the benchmark's tune split only (curbside fused at its
#: defaults, filter seed 0, the benchmark's and the lasting fixes pooled, 236,868 footsteps): the value
#: whose scaled radii held the walker closest to 50 / 80 / 90 / 95 % of the time (least squares over
#: 1.5-12 in steps of 0.1; 3.3 on the benchmark's fixes alone, 2.0 on the lasting ones).
TAIL_DOF = 2.5


def radius_at_share_m(
    accuracy_m: float | np.ndarray, share: float, tail_dof: float = TAIL_DOF
) -> float | np.ndarray:
    """The radius that holds the walker a ``share`` of the time, scaled from the 68 % one (``accuracy_m``).

    The filter's errors have heavier tails than a Gaussian's (docs/filter.md, "Other shares"), so they
    are taken as a circular bivariate Student-t with ``tail_dof`` degrees of freedom, whose radius is
    beyond ``r`` with probability ``(1 + r^2 / (nu s^2))^(-nu / 2)``. The radius at ``share`` is then
    ``accuracy_m * sqrt(((1 - share)^(-2 / nu) - 1) / (0.32^(-2 / nu) - 1))``: at the default 2.5, 0.71
    times for 50 %, 1.89 times for 90 % and 2.59 times for 95 %. ``tail_dof = math.inf`` scales as for
    a Gaussian, ``sqrt(ln(1 - share) / ln 0.32)`` (1.62 times for 95 %).
    """
    if not 0 < share < 1:
        raise ValueError(f"share must lie in (0, 1), got {share}")
    if not tail_dof > 0:
        raise ValueError(f"tail_dof must be positive (math.inf for a Gaussian), got {tail_dof}")
    if math.isinf(tail_dof):
        return accuracy_m * math.sqrt(math.log(1.0 - share) / math.log(0.32))
    # (1 - p)^(-2 / nu) - 1 as expm1, so that a large nu keeps its precision
    return accuracy_m * math.sqrt(
        math.expm1(-2.0 / tail_dof * math.log(1.0 - share)) / math.expm1(-2.0 / tail_dof * math.log(0.32))
    )


@dataclass(frozen=True)
class CalibrationConfig:
    """How the MAP segment's probability is calibrated (the ``filter.calibration`` section).

    Attributes
    ----------
    temperature
        The temperature for fixes whose error does not last (1 and a zero slope: the posterior mass as
        it is; the paper's preset).
    temperature_per_persistence
        How much the temperature grows from fixes whose error is gone a lag later (persistence 0) to
        fixes whose error is all still there (1).
    persistence_lag_s, pair_tolerance_s
        The lag of the innovation's variogram, and how much shorter a pair's separation may be.
    prior_persistence, prior_pairs
        The persistence assumed before any pair, and how many pairs it counts as.
    radius_floor_m_per_s
        How fast the floor under the 68 % radius (``accuracy_m``) grows with the seconds since the last
        fix that agreed with the estimate, or since the start (m/s; 0: no floor). It bounds the radius
        from below through a GNSS outage, where the cloud narrows at the map's walls while its error
        grows (the default was measured on the tune split with fixes dropped: docs/filter.md, "The
        position's 68 % radius"). Off, like the rest of the calibration, when temperature is 1 and its
        slope 0.
    """

    temperature: float = 1.5
    temperature_per_persistence: float = 2.0
    persistence_lag_s: float = 10.0
    pair_tolerance_s: float = 1.0
    prior_persistence: float = 0.3
    prior_pairs: float = 20.0
    radius_floor_m_per_s: float = 0.215

    def __post_init__(self) -> None:
        positive(self, "temperature", "pair_tolerance_s")
        non_negative(self, "temperature_per_persistence", "prior_pairs", "radius_floor_m_per_s")
        check(self.pair_tolerance_s <= self.persistence_lag_s < math.inf,
              "persistence_lag_s must be finite and at least pair_tolerance_s, got "
              f"{self.persistence_lag_s} and {self.pair_tolerance_s}")
        unit_interval(self, "prior_persistence")
        check(math.isfinite(self.radius_floor_m_per_s),
              f"radius_floor_m_per_s must be finite, got {self.radius_floor_m_per_s}")

    @property
    def identity(self) -> bool:
        """Whether the probability is reported as the posterior mass (temperature 1, no slope)."""
        return self.temperature == 1 and self.temperature_per_persistence == 0


class SegmentCalibration:
    """The calibrated probability of the MAP segment (see the module docstring).

    Parameters
    ----------
    config
        Temperature, its slope in the persistence, the lag and the prior.
    n
        Number of particles (the resolution of the probability).

    Attributes
    ----------
    pairs
        Innovation pairs ``lag`` apart seen so far.
    persistence
        The share of a fix's error left ``persistence_lag_s`` later, shrunk towards the prior.
    temperature
        The temperature the next probability is divided by (in logit).
    """

    def __init__(self, config: CalibrationConfig, n: int) -> None:
        self.config = config
        self._floor = 0.5 / n
        self._ceiling = 1.0 - self._floor
        self._recent: deque[tuple[float, float, float]] = deque()
        self._sum_sq = 0.0
        self._fixes = 0
        self._sum_sq_change = 0.0
        self.pairs = 0
        self.persistence = config.prior_persistence
        self.temperature = self._temperature_at(self.persistence)

    def observe(self, t: float, innovation_x_m: float, innovation_y_m: float) -> None:
        """Take the innovation of an accepted fix at time ``t`` (fix minus the previous estimate, m)."""
        c, recent = self.config, self._recent
        while recent and recent[0][0] < t - c.persistence_lag_s:
            recent.popleft()
        # The earliest innovation at most `lag` old, if it is nearly `lag` old (the variogram's pair).
        if recent and t - recent[0][0] > c.persistence_lag_s - c.pair_tolerance_s:
            _, x0, y0 = recent[0]
            self._sum_sq_change += (innovation_x_m - x0) ** 2 + (innovation_y_m - y0) ** 2
            self.pairs += 1
        recent.append((t, innovation_x_m, innovation_y_m))
        self._sum_sq += innovation_x_m**2 + innovation_y_m**2
        self._fixes += 1
        # Updated here, once per fix, rather than read at every update.
        if self.pairs and self._sum_sq > 0:
            rho = 1.0 - (self._sum_sq_change / self.pairs) / (2.0 * self._sum_sq / self._fixes)
            w = self.pairs / (self.pairs + c.prior_pairs)
            self.persistence = w * rho + (1.0 - w) * c.prior_persistence
            self.temperature = self._temperature_at(self.persistence)

    def _temperature_at(self, persistence: float) -> float:
        c = self.config
        return c.temperature + c.temperature_per_persistence * min(max(persistence, 0.0), 1.0)

    def radius_m(self, spread_m: float, seconds_since_fix: float) -> tuple[float, float]:
        """The cloud's 68 % radius (:func:`accuracy_radius_m` at this temperature) and the one to report:
        that radius, or ``radius_floor_m_per_s * seconds_since_fix`` where that is larger.

        ``seconds_since_fix`` counts from the last fix that agreed with the estimate, or from the start.
        """
        cloud_m = accuracy_radius_m(spread_m, self.temperature)
        floor_m = self.config.radius_floor_m_per_s * seconds_since_fix
        return cloud_m, floor_m if floor_m > cloud_m else cloud_m

    def calibrate(self, prob: float) -> float:
        """The tempered probability of a MAP segment of posterior mass ``prob`` (0 stays 0: no segment)."""
        if not prob > 0:
            return 0.0
        floor, ceiling = self._floor, self._ceiling
        p = floor if prob < floor else ceiling if prob > ceiling else prob  # clip, without two builtin calls
        return 1.0 / (1.0 + math.exp(-math.log(p / (1.0 - p)) / self.temperature))

    def record(self) -> dict[str, float]:
        """``fix_persistence``, ``temperature`` and ``fix_pairs`` so far (for ``run.json``)."""
        return {"fix_persistence": self.persistence, "temperature": self.temperature, "fix_pairs": self.pairs}
