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
  A fix reporting an accuracy ``a`` worse than ``correlation_accuracy_m`` has ``tau`` longer by
  ``a / correlation_accuracy_m``: such a fix is off by multipath, which changes only as the walker's
  geometry to the facades does, so a run of them carries less than their sigma alone would say.
- **Bias state**: alternatively the error shared by successive fixes is modelled, not tempered: a
  first-order Gauss-Markov bias ``b`` (time constant ``tau``, stationary sigma ``k_b`` times the
  accuracy), with a fix measuring ``position + b + w`` (``w`` white, sigma ``k_w`` times the accuracy).
  Given a particle's position the bias is linear-Gaussian, so it is Rao-Blackwellised (Doucet et al.
  2000): each particle carries the Kalman mean of its bias (rows ``bias_x, bias_y``) and all share one
  variance ``P``, which does not depend on the particle. At a fix ``dt`` after the previous one,
  ``rho = exp(-dt / tau)``, ``P- = rho^2 P + (1 - rho^2) s_b^2``, the innovation variance is
  ``S = P- + s_w^2``, a particle's likelihood is the mixture above with the Gaussian's variance ``S``
  centred on ``position + rho * mean``, and its mean moves by ``r K (innovation)`` with gain
  ``K = P- / S`` and ``r`` the particle's inlier responsibility (an outlier fix teaches the bias
  nothing); ``P = (1 - r_mean K) P-``.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from curbside.localize.filter.config import GnssConfig
from curbside.localize.filter.kernelmath import cell_index, exp, logaddexp
from curbside.localize.filter.particles import BIAS_X, BIAS_Y, ParticleSet, X, Y
from curbside.localize.filter.parts import GnssFix, Update
from curbside.localize.raster import MapRaster, RasterLookup


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
    raster
        The map raster: its nearest-segment grid and segment axes give each particle's street
        direction for ``config.across_factor``.
    """

    def __init__(
        self, config: GnssConfig, n: int, rng: np.random.Generator, raster: MapRaster | None = None
    ) -> None:
        self.config = config
        self.rng = rng
        self._streets = None  # the nearest-segment grid and segment axes, for the anisotropic model
        if config.across_factor != 1.0 and raster is not None and raster.segment_axes is not None:
            lk = RasterLookup(raster)
            self._streets = (lk.padded_segments, lk.index_grid,
                             np.ascontiguousarray(raster.segment_axes, dtype=np.float64))
        self.log_inlier_prob = math.log1p(-config.outlier_prob)
        self.log_outlier_density = -math.inf  # no outlier component: the plain Gaussian
        if config.outlier_prob > 0:
            self.log_outlier_density = math.log(config.outlier_prob) - math.log(
                math.pi * config.outlier_radius_m**2
            )
        self.last_fix_t = -math.inf
        self.bias_variance = 0.0  # per axis, shared by every particle's bias mean

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

    def correlation_time_s(self, accuracy_m: float) -> float:
        """The GNSS error's time constant (s) for a fix reporting ``accuracy_m``."""
        c = self.config
        if c.correlation_accuracy_m <= 0:
            return c.correlation_time_s
        return c.correlation_time_s * max(1.0, accuracy_m / c.correlation_accuracy_m)

    def exponent(self, dt_s: float, accuracy_m: float = 0.0) -> float:
        """Tempering exponent of a fix reporting ``accuracy_m``, ``dt_s`` seconds after the previous one
        (1 for the first)."""
        tau = self.correlation_time_s(accuracy_m)
        if tau <= 0 or not math.isfinite(dt_s):
            return 1.0
        rho = math.exp(-max(dt_s, 0.0) / tau)
        return (1.0 - rho) / (1.0 + rho)

    def _bias_prior(self, fix: GnssFix, dt_s: float) -> tuple[float, float]:
        """``(rho, P-)``: bias decay since the last fix and the predicted bias variance (per axis)."""
        stationary = (self.config.bias_sigma_factor * fix.accuracy_m) ** 2
        rho = math.exp(-max(dt_s, 0.0) / self.config.bias_time_s) if math.isfinite(dt_s) else 0.0
        return rho, rho * rho * self.bias_variance + (1.0 - rho * rho) * stationary

    def weigh(self, particles: ParticleSet, update: Update) -> None:
        """Add the log-likelihood of ``update.fix`` (nothing for no or an unusable fix)."""
        fix = update.fix
        if not self.accepts(fix):
            return
        dt_s = update.t - self.last_fix_t
        self.last_fix_t = update.t
        exponent = self.exponent(dt_s, fix.accuracy_m)
        if self.config.student_dof > 0:
            nu, variance = self.config.student_dof, self.sigma_m(fix) ** 2
            log_norm = math.lgamma(nu / 2 + 1) - math.lgamma(nu / 2) - math.log(nu * math.pi * variance)
            _add_student_log_likelihood(particles.state, particles.log_weight, fix.x, fix.y,
                                        1 / (nu * variance), -(nu + 2) / 2, log_norm, exponent)
            return
        if self._streets is not None:
            a, b, c = self.coefficients(fix)
            f = self.config.across_factor
            _add_anisotropic_log_likelihood(particles.state, particles.log_weight, fix.x, fix.y, a,
                                            a / (f * f), b, b - math.log(f), c, exponent,
                                            *self._streets)
            return
        if self.config.bias_sigma_factor <= 0:
            a, b, c = self.coefficients(fix)
            _add_gnss_log_likelihood(particles.state, particles.log_weight, fix.x, fix.y, a, b, c, exponent)
            return
        rho, prior = self._bias_prior(fix, dt_s)
        innovation = prior + self.sigma_m(fix) ** 2
        a, b = -0.5 / innovation, self.log_inlier_prob - math.log(2.0 * math.pi * innovation)
        gain = prior / innovation
        mean_inlier = _add_gnss_bias_log_likelihood(particles.state, particles.log_weight, fix.x, fix.y, a, b,
                                                    self.log_outlier_density, rho, gain)
        self.bias_variance = (1.0 - mean_inlier * gain) * prior


# The kernels use kernelmath's exp and logaddexp, which vectorise under error_model="numpy".
@numba.njit(cache=True, nogil=True, error_model="numpy")
def _add_gnss_log_likelihood(state, log_weight, fix_x, fix_y, a, b, c, exponent):  # pragma: no cover
    for i in range(state.shape[1]):
        ex = state[X, i] - fix_x
        ey = state[Y, i] - fix_y
        log_weight[i] += exponent * logaddexp((ex * ex + ey * ey) * a + b, c)


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _add_anisotropic_log_likelihood(
    state, log_weight, fix_x, fix_y, a, a_across, b, b_aniso, c, exponent, padded_segments, grid, axes,
):  # pragma: no cover - compiled
    # Along/across the particle's nearest sidewalk segment; isotropic where no segment is near.
    for i in range(state.shape[1]):
        ex = state[X, i] - fix_x
        ey = state[Y, i] - fix_y
        k = padded_segments[cell_index(state[X, i], state[Y, i], grid)]
        if k < 0:
            inlier = (ex * ex + ey * ey) * a + b
        else:
            along = ex * axes[k, 0] + ey * axes[k, 1]
            across = ey * axes[k, 0] - ex * axes[k, 1]
            inlier = along * along * a + across * across * a_across + b_aniso
        log_weight[i] += exponent * logaddexp(inlier, c)


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _add_student_log_likelihood(state, log_weight, fix_x, fix_y, inv_scale, power, log_norm, exponent):  # noqa: E501 # pragma: no cover
    # bivariate Student-t: log p = log_norm + power * log1p(d^2 * inv_scale)
    for i in range(state.shape[1]):
        ex = state[X, i] - fix_x
        ey = state[Y, i] - fix_y
        log_weight[i] += exponent * (log_norm + power * math.log1p((ex * ex + ey * ey) * inv_scale))


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _add_gnss_bias_log_likelihood(state, log_weight, fix_x, fix_y, a, b, c, rho, gain):  # pragma: no cover
    total = 0.0
    n = state.shape[1]
    for i in range(n):
        bx = rho * state[BIAS_X, i]
        by = rho * state[BIAS_Y, i]
        ex = fix_x - state[X, i] - bx  # the innovation
        ey = fix_y - state[Y, i] - by
        inlier = (ex * ex + ey * ey) * a + b
        ll = logaddexp(inlier, c)
        log_weight[i] += ll
        r = exp(inlier - ll)
        total += r
        state[BIAS_X, i] = bx + r * gain * ex
        state[BIAS_Y, i] = by + r * gain * ey
    return total / n


def reference_log_likelihood(
    x: np.ndarray, y: np.ndarray, fix: GnssFix, coefficients: tuple[float, float, float], exponent: float
) -> np.ndarray:
    """The numpy oracle of the compiled likelihood without a bias state (tests only)."""
    a, b, c = coefficients
    return exponent * np.logaddexp(a * ((x - fix.x) ** 2 + (y - fix.y) ** 2) + b, c)


def reference_anisotropic_log_likelihood(
    x: np.ndarray, y: np.ndarray, fix: GnssFix, sigma_m: float, across_factor: float, axis: np.ndarray,
    log_outlier: float, log_inlier_prob: float, exponent: float,
) -> np.ndarray:
    """The numpy oracle of the anisotropic likelihood, points on a street of axis ``axis`` (tests only)."""
    from scipy.stats import multivariate_normal

    u = np.asarray(axis, float)
    rot = np.column_stack([u, [-u[1], u[0]]])  # columns: along, across
    cov = rot @ np.diag([sigma_m**2, (across_factor * sigma_m) ** 2]) @ rot.T
    gauss = multivariate_normal([fix.x, fix.y], cov).logpdf(np.column_stack([x, y])) + log_inlier_prob
    return exponent * np.logaddexp(gauss, log_outlier)


def reference_student_log_likelihood(
    x: np.ndarray, y: np.ndarray, fix: GnssFix, sigma_m: float, dof: float, exponent: float
) -> np.ndarray:
    """The numpy oracle of the Student-t likelihood (tests only): scipy's bivariate t log-density."""
    from scipy.stats import multivariate_t

    points = np.column_stack([x, y])
    return exponent * multivariate_t(loc=[fix.x, fix.y], shape=sigma_m**2 * np.eye(2), df=dof).logpdf(points)


def reference_bias_update(
    state: np.ndarray, fix: GnssFix, a: float, b: float, c: float, rho: float, gain: float
) -> tuple[np.ndarray, np.ndarray, float]:
    """The numpy oracle of the bias-state update: ``(log-likelihood, new state, mean inlier share)``."""
    out = state.copy()
    bx, by = rho * state[BIAS_X], rho * state[BIAS_Y]
    ex, ey = fix.x - state[X] - bx, fix.y - state[Y] - by
    inlier = a * (ex**2 + ey**2) + b
    ll = np.logaddexp(inlier, c)
    r = np.exp(inlier - ll)
    out[BIAS_X], out[BIAS_Y] = bx + r * gain * ex, by + r * gain * ey
    return ll, out, float(r.mean())
