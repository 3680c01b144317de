"""The GNSS likelihood: how much each particle agrees with a fix, given the fix's reported accuracy.

The paper's rule (Ren & Ke 2010): multiply each weight by a bivariate Gaussian centred on the fix,
sigma proportional to the reported accuracy, for fixes reporting an accuracy under a threshold. curbside
adds three things, each with one parameter of :class:`~curbside.localize.filter.config.GnssConfig` and
each off in the paper preset:

- **Outlier mixture**: in urban canyons a fix can be tens of metres off while reporting a few metres
  (multipath, a reflected signal "on the other side of the street"). The likelihood is
  ``(1 - outlier_prob) * Gaussian + outlier_prob / (pi R^2)``: however far the fix, it lowers no
  particle's weight by more than a fixed factor, so one bad fix cannot wipe out the cloud.
- **Tempering**: urban GNSS errors are correlated over seconds. Treating the error as first-order
  Gauss-Markov with time constant ``tau``, fixes ``dt`` apart have correlation ``rho = exp(-dt / tau)``
  and ``N`` of them carry the information of ``N (1 - rho) / (1 + rho)`` independent ones (the effective
  sample size of the mean of an AR(1) series); each fix's log-likelihood is multiplied by that exponent.
- **Bias state**: optionally each particle carries the slowly wandering GNSS error itself (rows
  ``bias_x, bias_y``), a first-order Gauss-Markov process propagated from fix to fix; a fix then
  measures position + bias.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from curbside.localize.filter.config import GnssConfig
from curbside.localize.filter.particles import BIAS_X, BIAS_Y, ParticleSet, X, Y
from curbside.localize.filter.parts import GnssFix, Update


class GnssLikelihood:
    """Robust, tempered log-likelihood of the particles given a GNSS fix (see the module docstring).

    Parameters
    ----------
    config
        The GNSS section of the filter's configuration.
    n
        Number of particles.
    rng
        The filter's seeded generator (drawn from only with a bias state).
    """

    def __init__(self, config: GnssConfig, n: int, rng: np.random.Generator) -> None:
        self.config = config
        self.rng = rng
        self.log_inlier_prob = math.log1p(-config.outlier_prob)
        self.log_outlier_density = -math.inf  # no outlier component: the plain Gaussian
        if config.outlier_prob > 0:
            self.log_outlier_density = math.log(config.outlier_prob) - math.log(
                math.pi * config.outlier_radius_m**2
            )
        self.last_fix_t = -math.inf
        self.bias_noise = np.zeros((2, n))

    def accepts(self, fix: GnssFix | None) -> bool:
        """Whether ``fix`` is valid (finite position, accuracy > 0 and finite) and accurate enough."""
        return (
            fix is not None
            and math.isfinite(fix.x)
            and math.isfinite(fix.y)
            and math.isfinite(fix.accuracy_m)
            and 0.0 < fix.accuracy_m < self.config.max_accuracy_m
        )

    def sigma_m(self, fix: GnssFix) -> float:
        """The likelihood's sigma for ``fix`` (metres per axis)."""
        return self.config.sigma_factor * fix.accuracy_m

    def coefficients(self, fix: GnssFix) -> tuple[float, float, float]:
        """``(a, b, c)``: inlier log-density ``a * squared distance + b``, outlier log-density ``c``."""
        variance = self.sigma_m(fix) ** 2
        return (
            -0.5 / variance,
            self.log_inlier_prob - math.log(2.0 * math.pi * variance),
            self.log_outlier_density,
        )

    def exponent(self, dt_s: float) -> float:
        """Tempering exponent of a fix ``dt_s`` seconds after the previous one (1 for the first)."""
        tau = self.config.correlation_time_s
        if tau <= 0 or not math.isfinite(dt_s):
            return 1.0
        rho = math.exp(-max(dt_s, 0.0) / tau)
        return (1.0 - rho) / (1.0 + rho)

    def _bias_step(self, dt_s: float) -> tuple[bool, float, float]:
        """``(on, rho, innovation sigma)`` of the bias over ``dt_s``; draws the innovations."""
        sigma = self.config.bias_sigma_m
        if sigma <= 0:
            return False, 1.0, 0.0
        self.rng.standard_normal(out=self.bias_noise)
        rho = math.exp(-max(dt_s, 0.0) / self.config.bias_time_s) if math.isfinite(dt_s) else 0.0
        return True, rho, sigma * math.sqrt(1.0 - rho * rho)

    def weigh(self, particles: ParticleSet, update: Update) -> None:
        """Add the tempered log-likelihood of ``update.fix`` (nothing for no or an unusable fix)."""
        fix = update.fix
        if not self.accepts(fix):
            return
        dt_s = update.t - self.last_fix_t
        a, b, c = self.coefficients(fix)
        _add_gnss_log_likelihood(
            particles.state,
            particles.log_weight,
            fix.x,
            fix.y,
            a,
            b,
            c,
            self.exponent(dt_s),
            *self._bias_step(dt_s),
            self.bias_noise,
        )
        self.last_fix_t = update.t


@numba.njit(cache=True, nogil=True)
def _add_gnss_log_likelihood(
    state, log_weight, fix_x, fix_y, a, b, c, exponent, use_bias, rho, innovation, bias_noise
):  # pragma: no cover - compiled
    for i in range(state.shape[1]):
        ex = state[X, i] - fix_x
        ey = state[Y, i] - fix_y
        if use_bias:
            bx = rho * state[BIAS_X, i] + innovation * bias_noise[0, i]
            by = rho * state[BIAS_Y, i] + innovation * bias_noise[1, i]
            state[BIAS_X, i] = bx
            state[BIAS_Y, i] = by
            ex += bx
            ey += by
        inlier = (ex * ex + ey * ey) * a + b
        # logaddexp(inlier, c), as numpy computes it
        if c == -math.inf:
            ll = inlier
        elif inlier >= c:
            ll = inlier + math.log1p(math.exp(c - inlier))
        else:
            ll = c + math.log1p(math.exp(inlier - c))
        log_weight[i] += exponent * ll


def reference_log_likelihood(
    x: np.ndarray, y: np.ndarray, fix: GnssFix, coefficients: tuple[float, float, float], exponent: float
) -> np.ndarray:
    """The numpy oracle of the compiled likelihood without a bias state (tests only)."""
    a, b, c = coefficients
    return exponent * np.logaddexp(a * ((x - fix.x) ** 2 + (y - fix.y) ** 2) + b, c)
