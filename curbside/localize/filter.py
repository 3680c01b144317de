"""The map-aware particle filter of Dubiner, Ren & Manduchi, built from small components that compose.

Read it top to bottom:

1. :class:`FilterConfig`: every parameter, defaults from :mod:`curbside.settings`.
2. :class:`ParticleSet`: the state. Per particle ``x``, ``y`` (metres east/north in the map's local
   UTM CRS), ``theta`` (heading drift, radians, counter-clockwise), ``scale`` (speed scale, beyond the
   paper: the inertial speed may be off by several per cent), ``bias_x``, ``bias_y`` (the slowly
   wandering GNSS error, beyond the paper, optional) and a log-weight.
3. :class:`InertialPredictor`: at a footstep, rotate the step's inertial displacement by each
   particle's ``theta``, scale it by its ``scale``, add it, and add Gaussian noise to ``x``, ``y``,
   ``theta`` and ``scale``; the GNSS bias follows a first-order Gauss-Markov process.
4. :class:`MapLikelihood`: log-weight by the map class under each particle, looked up in a raster
   (0 in buildings, ``jaywalk_weight`` on the street, 1 elsewhere).
5. :class:`GnssLikelihood`: a robust GNSS likelihood: an isotropic Gaussian centred on a fix, sigma
   proportional to the reported accuracy, mixed with a flat outlier density, and tempered for the
   time correlation of successive fixes.
6. :func:`normalise_log_weights`: weights stay in the log domain (products of many likelihoods never
   underflow) and are normalised with the log-sum-exp trick.
7. :class:`SystematicResampler`: seeded, vectorised systematic resampling.
8. The fast path: the same arithmetic in three numba loops (predict + map + GNSS in one pass,
   normalise + estimate, resample). The numpy components above are the reference; the tests check
   that both paths give the same particles from the same draws.
9. :func:`segment_posterior`: the posterior over discrete sidewalk segments (one ``bincount`` of the
   weights by each particle's nearest segment, from the map's segment raster), its mode (the MAP
   segment) and the weighted mean of the particles on it: the Bayes decision for sidewalk assignment,
   which the weighted mean of a cloud split across a street is not.
10. :class:`Tracker`: the streaming API a navigation app calls once per footstep; it composes the
    components, recovers from collapse (and, with :class:`DivergenceRecovery`, Augmented MCL, from a
    cloud that no longer agrees with GNSS) and returns an :class:`Estimate`. Batch runs
    (:mod:`curbside.localize.pipeline`) drive the same class.

Arrays are preallocated for the particle count (the fast path allocates nothing per step), so one
update at N=500 costs tens of microseconds (``benchmarks/bench_filter.py``). Resampling swaps the
particle arrays with spare ones: read ``tracker.particles.x`` after a step, do not keep it.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field
from typing import NamedTuple

import numba
import numpy as np
import pyproj

from curbside import settings
from curbside.errors import CurbsideInputError
from curbside.localize.maplikelihood import (
    BUILDING,
    STREET,
    MapRaster,
    RasterLookup,
    load_or_build_raster,
)
from curbside.osmseg.mapio import MapLayers
from curbside.projection import LocalFrame

logger = logging.getLogger(__name__)

RESAMPLE_POLICIES = ("always", "ess")
BACKENDS = ("numba", "numpy")


@dataclass(frozen=True)
class FilterConfig:
    """Parameters of the particle filter (see ``docs/filter.md`` for the reasoning behind each).

    Attributes
    ----------
    n_particles
        Number of particles N (the paper: 500).
    jaywalk_weight
        Weight of a particle on street surface outside crosswalks, in [0, 1] (the paper: 0.4).
    step_noise_fraction, step_noise_floor_m
        Position noise per footstep, east and north: sigma = max(floor, fraction * step length).
    theta_noise_deg
        Heading-drift random walk per footstep (one sigma).
    scale_init_sigma, scale_noise_per_step
        Speed-scale spread around 1 at the start and its random walk per footstep (both 0: the
        paper's three-state filter).
    init_position_sigma_m, init_theta_sigma_deg
        Spread around a known start pose.
    gnss_init_theta_sigma_deg
        Drift spread when starting from a GNSS fix; ``None`` for the full circle.
    recovery_sigma_m
        Spread of particles re-seeded around the last estimate after a collapse.
    recovery_alpha_fast, recovery_alpha_slow
        Rates (per fix) of the short- and long-term averages of the cloud's GNSS agreement that drive
        the divergence recovery (:class:`DivergenceRecovery`).
    recovery_trigger_ratio
        Particles are injected once the short-term average falls below this fraction of the long-term
        one (1: the book's rule).
    recovery_kernel_scale
        The agreement kernel's sigma is this multiple of the GNSS likelihood's sigma.
    recovery_max_fraction
        At most this fraction of the particles is re-drawn around a fix at one step (0: no recovery).
    gnss_sigma_factor
        GNSS likelihood sigma = factor * reported accuracy.
    gnss_max_accuracy_m
        Fixes with a worse reported accuracy make no update.
    gnss_outlier_prob
        Weight of the flat outlier component of the GNSS likelihood, in [0, 1).
    gnss_outlier_radius_m
        The outlier component is the uniform density over a disc of this radius, ``1 / (pi R^2)``.
    gnss_error_correlation_s
        Time constant (s) of the GNSS error; each fix's log-likelihood is tempered by the fraction of an
        independent fix it carries (0: successive fixes are independent, no tempering).
    gnss_bias_sigma_m, gnss_bias_time_s
        The GNSS bias state: stationary sigma (m, per axis; 0: no bias state) and time constant (s) of
        a first-order Gauss-Markov error that each fix measures on top of the particle's position.
    resample
        ``"always"`` (every footstep, as the paper) or ``"ess"`` (when the effective sample size drops
        below ``ess_fraction * n_particles``).
    ess_fraction
        Threshold of the ``"ess"`` policy.
    raster_resolution_m
        Cell size of the map raster.
    max_start_snap_m
        A start pose in a building moves to the nearest free cell within this distance.
    backend
        ``"numba"`` (fused kernels, the default) or ``"numpy"`` (the reference components).
    segment_estimate
        Compute the posterior over sidewalk segments and the mode estimate at each step (needs a map
        with sidewalk segments; without, the mode estimate is the weighted mean).
    """

    n_particles: int = field(default_factory=lambda: settings.default_particles)
    jaywalk_weight: float = field(default_factory=lambda: settings.default_jaywalk_weight)
    step_noise_fraction: float = field(default_factory=lambda: settings.filter_step_noise_fraction)
    step_noise_floor_m: float = field(default_factory=lambda: settings.filter_step_noise_floor_m)
    theta_noise_deg: float = field(default_factory=lambda: settings.filter_theta_noise_deg)
    scale_init_sigma: float = field(default_factory=lambda: settings.filter_scale_init_sigma)
    scale_noise_per_step: float = field(default_factory=lambda: settings.filter_scale_noise_per_step)
    init_position_sigma_m: float = field(default_factory=lambda: settings.filter_init_position_sigma_m)
    init_theta_sigma_deg: float = field(default_factory=lambda: settings.filter_init_theta_sigma_deg)
    gnss_init_theta_sigma_deg: float | None = field(
        default_factory=lambda: settings.filter_gnss_init_theta_sigma_deg
    )
    recovery_sigma_m: float = field(default_factory=lambda: settings.filter_recovery_sigma_m)
    recovery_alpha_fast: float = field(default_factory=lambda: settings.filter_recovery_alpha_fast)
    recovery_alpha_slow: float = field(default_factory=lambda: settings.filter_recovery_alpha_slow)
    recovery_trigger_ratio: float = field(default_factory=lambda: settings.filter_recovery_trigger_ratio)
    recovery_kernel_scale: float = field(default_factory=lambda: settings.filter_recovery_kernel_scale)
    recovery_max_fraction: float = field(default_factory=lambda: settings.filter_recovery_max_fraction)
    gnss_sigma_factor: float = field(default_factory=lambda: settings.gnss_sigma_factor)
    gnss_max_accuracy_m: float = field(default_factory=lambda: settings.gnss_max_accuracy_m)
    gnss_outlier_prob: float = field(default_factory=lambda: settings.gnss_outlier_prob)
    gnss_outlier_radius_m: float = field(default_factory=lambda: settings.gnss_outlier_radius_m)
    gnss_error_correlation_s: float = field(default_factory=lambda: settings.gnss_error_correlation_s)
    gnss_bias_sigma_m: float = field(default_factory=lambda: settings.gnss_bias_sigma_m)
    gnss_bias_time_s: float = field(default_factory=lambda: settings.gnss_bias_time_s)
    resample: str = field(default_factory=lambda: settings.filter_resample)
    ess_fraction: float = field(default_factory=lambda: settings.filter_ess_fraction)
    raster_resolution_m: float = field(default_factory=lambda: settings.raster_resolution_m)
    max_start_snap_m: float = field(default_factory=lambda: settings.filter_max_start_snap_m)
    backend: str = "numba"
    segment_estimate: bool = True

    def __post_init__(self) -> None:
        if int(self.n_particles) < 1:
            raise ValueError(f"n_particles must be at least 1, got {self.n_particles}")
        if not 0.0 <= self.jaywalk_weight <= 1.0:
            raise ValueError(f"jaywalk_weight must lie in [0, 1], got {self.jaywalk_weight}")
        if self.resample not in RESAMPLE_POLICIES:
            raise ValueError(f"resample must be one of {RESAMPLE_POLICIES}, got {self.resample!r}")
        if self.backend not in BACKENDS:
            raise ValueError(f"backend must be one of {BACKENDS}, got {self.backend!r}")
        if not self.gnss_sigma_factor > 0:
            raise ValueError(f"gnss_sigma_factor must be positive, got {self.gnss_sigma_factor}")
        if not 0.0 <= self.gnss_outlier_prob < 1.0:
            raise ValueError(f"gnss_outlier_prob must lie in [0, 1), got {self.gnss_outlier_prob}")
        if not self.gnss_outlier_radius_m > 0:
            raise ValueError(f"gnss_outlier_radius_m must be positive, got {self.gnss_outlier_radius_m}")
        if not self.gnss_error_correlation_s >= 0:
            raise ValueError(
                f"gnss_error_correlation_s must be non-negative, got {self.gnss_error_correlation_s}"
            )
        if not 0.0 <= self.recovery_max_fraction <= 1.0:
            raise ValueError(f"recovery_max_fraction must lie in [0, 1], got {self.recovery_max_fraction}")
        if not (0.0 < self.recovery_alpha_slow < self.recovery_alpha_fast <= 1.0
                and 0.0 < self.recovery_trigger_ratio <= 1.0 and self.recovery_kernel_scale > 0):
            raise ValueError(
                "need 0 < recovery_alpha_slow < recovery_alpha_fast <= 1, 0 < recovery_trigger_ratio <= 1, "
                f"recovery_kernel_scale > 0; got {self.recovery_alpha_slow}, {self.recovery_alpha_fast}, "
                f"{self.recovery_trigger_ratio}, {self.recovery_kernel_scale}"
            )
        if not (self.gnss_bias_sigma_m >= 0 and self.gnss_bias_time_s > 0):
            raise ValueError(
                f"gnss_bias_sigma_m must be >= 0 and gnss_bias_time_s > 0, got {self.gnss_bias_sigma_m}, "
                f"{self.gnss_bias_time_s}"
            )


class ParticleSet:
    """The particles: preallocated ``(N,)`` float64 arrays.

    Attributes
    ----------
    x, y
        Metres east and north in the local CRS.
    theta
        Heading drift, radians: the inertial velocity is rotated counter-clockwise by it.
    scale
        Speed scale: the inertial displacement is multiplied by it.
    bias_x, bias_y
        GNSS bias, metres east/north: a fix measures ``(x + bias_x, y + bias_y)`` plus white noise.
    log_weight
        Unnormalised log-weights (``-inf`` = weight 0).
    """

    def __init__(self, n: int) -> None:
        self.x = np.zeros(n)
        self.y = np.zeros(n)
        self.theta = np.zeros(n)
        self.scale = np.ones(n)
        self.bias_x = np.zeros(n)
        self.bias_y = np.zeros(n)
        self.log_weight = np.full(n, -math.log(n))

    def __len__(self) -> int:
        return len(self.x)


class InertialPredictor:
    """Motion model: displacement rotated by each particle's drift, plus Gaussian noise.

    At each footstep ``theta`` and ``scale`` first take their random-walk increments, then every
    particle moves by the step's displacement ``(dx, dy)`` rotated by its own ``theta`` and multiplied
    by its own ``scale``, plus isotropic position noise with sigma ``max(step_noise_floor_m,
    step_noise_fraction * |(dx, dy)|)``: the error of an inertial step grows with its length, and the
    floor keeps standing-still clouds alive. With a GNSS bias state, the bias decays by ``rho = exp(-dt /
    tau)`` over the step's duration ``dt`` and takes an innovation of sigma ``sigma_b sqrt(1 - rho^2)``,
    which keeps its stationary sigma at ``sigma_b``.

    Parameters
    ----------
    config
        Noise parameters.
    rng
        The filter's seeded generator.
    """

    def __init__(self, config: FilterConfig, rng: np.random.Generator) -> None:
        n = config.n_particles
        self.rng = rng
        self.noise_fraction = config.step_noise_fraction
        self.noise_floor_m = config.step_noise_floor_m
        self.theta_sigma = math.radians(config.theta_noise_deg)
        self.scale_sigma = config.scale_noise_per_step
        self.noise = np.zeros((4, n))  # standard normals: x, y, theta, scale
        # Without a scale random walk its row stays zero and is not drawn (fewer normals per step).
        self._drawn = self.noise if self.scale_sigma > 0 else self.noise[:3]
        self.bias_sigma_m = config.gnss_bias_sigma_m
        self.bias_time_s = config.gnss_bias_time_s
        self.bias_noise = np.zeros((2, n))  # drawn after the others, only with a bias state
        self.cos_theta = np.empty(n)
        self.sin_theta = np.empty(n)
        self._tmp = np.empty(n)

    def draw_noise(self, dx: float, dy: float) -> float:
        """Draw this step's standard normals into :attr:`noise`; return the position sigma (m)."""
        self.rng.standard_normal(out=self._drawn)
        if self.bias_sigma_m > 0:
            self.rng.standard_normal(out=self.bias_noise)
        return max(self.noise_floor_m, self.noise_fraction * math.hypot(dx, dy))

    def bias_decay(self, dt_s: float) -> tuple[float, float]:
        """``(rho, innovation sigma)`` of the GNSS bias over ``dt_s`` seconds (``(1, 0)`` without one)."""
        if self.bias_sigma_m <= 0:
            return 1.0, 0.0
        rho = math.exp(-max(dt_s, 0.0) / self.bias_time_s)
        return rho, self.bias_sigma_m * math.sqrt(1.0 - rho * rho)

    def predict(self, particles: ParticleSet, dx: float, dy: float, dt_s: float = 0.0) -> None:
        """Move ``particles`` in place by the step displacement ``(dx, dy)`` metres (east, north).

        ``dt_s`` is the step's duration (it only ages the GNSS bias). Leaves ``cos_theta`` /
        ``sin_theta`` of the new drift angles for the estimate.
        """
        sigma_xy = self.draw_noise(dx, dy)
        if self.bias_sigma_m > 0:
            rho, innovation = self.bias_decay(dt_s)
            for bias, noise_row in zip((particles.bias_x, particles.bias_y), self.bias_noise, strict=True):
                bias *= rho
                bias += innovation * noise_row
        noise, c, s, tmp = self.noise, self.cos_theta, self.sin_theta, self._tmp
        noise[:2] *= sigma_xy
        noise[2] *= self.theta_sigma
        noise[3] *= self.scale_sigma
        particles.theta += noise[2]
        particles.scale += noise[3]
        np.cos(particles.theta, out=c)
        np.sin(particles.theta, out=s)
        # x += scale (dx cos - dy sin) + noise;  y += scale (dx sin + dy cos) + noise
        np.multiply(c, dx, out=tmp)
        tmp -= s * dy
        tmp *= particles.scale
        particles.x += tmp
        particles.x += noise[0]
        np.multiply(s, dx, out=tmp)
        tmp += c * dy
        tmp *= particles.scale
        particles.y += tmp
        particles.y += noise[1]


class MapLikelihood:
    """Log-likelihood of each particle's position given the map: a lookup in the class raster.

    Weights: 0 in a building, ``jaywalk_weight`` on street surface, 1 on crosswalks, sidewalks, free
    space and anywhere outside the raster.

    Parameters
    ----------
    raster
        The map rasterised by :func:`curbside.localize.maplikelihood.load_or_build_raster`.
    jaywalk_weight
        Weight on street surface, in [0, 1].
    """

    def __init__(self, raster: MapRaster, jaywalk_weight: float) -> None:
        weights = np.ones(BUILDING + 1)  # FREE, SIDEWALK, CROSSWALK: 1
        weights[STREET] = jaywalk_weight
        weights[BUILDING] = 0.0
        with np.errstate(divide="ignore"):
            self.log_table = np.log(weights)
        self.raster = raster
        self.lookup = RasterLookup(raster)

    def log_likelihood(self, x: np.ndarray, y: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        """Log-weight (``-inf`` in buildings) of each point ``(x, y)``."""
        codes = self.lookup.codes_at(x, y)
        return np.take(self.log_table, codes, out=out)


@dataclass(frozen=True)
class GnssFix:
    """One GNSS fix in the tracker's local frame.

    Attributes
    ----------
    x, y
        Metres east/north in the local CRS.
    accuracy_m
        Reported horizontal accuracy radius; not positive or not finite = invalid.
    """

    x: float
    y: float
    accuracy_m: float


class GnssLikelihood:
    """Robust, tempered log-likelihood of particle positions given a GNSS fix.

    Three ideas, each with one parameter:

    - **Gaussian inlier**: an isotropic bivariate Gaussian centred on the fix with sigma = ``sigma_factor``
      times the reported accuracy radius.
    - **Outlier mixture**: in urban canyons a fix can be tens of metres off while reporting a few
      metres (multipath, a reflected signal "on the other side of the street"). The likelihood is
      ``(1 - outlier_prob) * Gaussian + outlier_prob / (pi R^2)``, a uniform density over a disc of
      radius ``outlier_radius_m`` that bounds the likelihood below: however far the fix, it can lower
      no particle's weight by more than a fixed factor, so one bad fix cannot wipe out the cloud.
    - **Tempering**: urban GNSS errors are correlated over tens of seconds, so successive fixes are
      far from independent. Treating the error as first-order Gauss-Markov with time constant
      ``correlation_time_s``, fixes ``dt`` apart have correlation ``rho = exp(-dt / tau)`` and N of
      them carry the information of ``N (1 - rho) / (1 + rho)`` independent ones (the effective sample
      size of the mean of an AR(1) series). Each fix's log-likelihood is multiplied by that exponent,
      so a fix repeated (or interpolated) twice in one second counts no more than once.

    Parameters
    ----------
    sigma_factor
        Multiplies the reported accuracy radius.
    max_accuracy_m
        Fixes reporting a worse (larger) accuracy make no update.
    outlier_prob
        Weight of the outlier component, in [0, 1) (0: the plain Gaussian).
    outlier_radius_m
        Radius of the outlier disc, metres.
    correlation_time_s
        Time constant of the GNSS error, seconds (0: independent fixes, exponent 1).
    """

    def __init__(
        self,
        sigma_factor: float,
        max_accuracy_m: float,
        outlier_prob: float = 0.0,
        outlier_radius_m: float = 50.0,
        correlation_time_s: float = 0.0,
    ) -> None:
        self.sigma_factor = sigma_factor
        self.max_accuracy_m = max_accuracy_m
        self.outlier_prob = outlier_prob
        self.outlier_radius_m = outlier_radius_m
        self.correlation_time_s = correlation_time_s
        self.log_inlier_prob = math.log1p(-outlier_prob)
        self.log_outlier_density = -math.inf  # no outlier component: the plain Gaussian
        if outlier_prob > 0:
            self.log_outlier_density = math.log(outlier_prob) - math.log(math.pi * outlier_radius_m**2)

    def accepts(self, fix: GnssFix | None) -> bool:
        """Whether ``fix`` is valid (finite position, accuracy > 0 and finite) and accurate enough."""
        return (
            fix is not None
            and math.isfinite(fix.x)
            and math.isfinite(fix.y)
            and math.isfinite(fix.accuracy_m)
            and 0.0 < fix.accuracy_m < self.max_accuracy_m
        )

    def coefficients(self, fix: GnssFix) -> tuple[float, float, float]:
        """``(a, b, c)``: inlier log-density ``a * squared distance + b``, outlier log-density ``c``.

        Both include their mixture weights, so the log-likelihood is ``logaddexp(a d^2 + b, c)``.
        """
        variance = (self.sigma_factor * fix.accuracy_m) ** 2
        log_norm = self.log_inlier_prob - math.log(2.0 * math.pi * variance)
        return -0.5 / variance, log_norm, self.log_outlier_density

    def exponent(self, dt_s: float) -> float:
        """Tempering exponent of a fix ``dt_s`` seconds after the previous one applied (inf: the first).

        ``(1 - rho) / (1 + rho)`` with ``rho = exp(-dt_s / tau)``; 1 without correlation or for the first
        fix.
        """
        if self.correlation_time_s <= 0 or not math.isfinite(dt_s):
            return 1.0
        rho = math.exp(-max(dt_s, 0.0) / self.correlation_time_s)
        return (1.0 - rho) / (1.0 + rho)

    def log_likelihood(
        self, x: np.ndarray, y: np.ndarray, fix: GnssFix, out: np.ndarray, tmp: np.ndarray,
        exponent: float = 1.0,
    ) -> np.ndarray:
        """Tempered log-likelihood of each particle position given the fix (written into ``out``)."""
        scale, log_norm, log_outlier = self.coefficients(fix)
        np.subtract(x, fix.x, out=out)
        np.square(out, out=out)
        np.subtract(y, fix.y, out=tmp)
        np.square(tmp, out=tmp)
        out += tmp
        out *= scale
        out += log_norm
        np.logaddexp(out, log_outlier, out=out)
        out *= exponent
        return out


def normalise_log_weights(log_weight: np.ndarray, out: np.ndarray) -> bool:
    """Normalised linear weights from log-weights (log-sum-exp); ``False`` when they collapsed.

    Parameters
    ----------
    log_weight
        Unnormalised log-weights; modified in place to the normalised log-weights.
    out
        Receives the linear weights (summing to 1).

    Returns
    -------
    bool
        ``False`` when every weight is zero or any is NaN (nothing is written then).
    """
    peak = log_weight.max()
    if not math.isfinite(peak):
        return False
    log_weight -= peak
    np.exp(log_weight, out=out)
    total = out.sum()
    out /= total
    log_weight -= math.log(total)
    return True


def effective_sample_size(weights: np.ndarray) -> float:
    """Kish's effective sample size ``1 / sum(w^2)`` of normalised weights."""
    return 1.0 / float(np.dot(weights, weights))


def systematic_indices(weights: np.ndarray, u0: float, out: np.ndarray | None = None) -> np.ndarray:
    """Systematic resampling: indices drawn at the positions ``(u0 + k) / N``, ``k = 0..N-1``.

    The same rule as :func:`filterpy.monte_carlo.systematic_resample` (which draws ``u0`` from the
    global numpy RNG), vectorised with a binary search.

    Parameters
    ----------
    weights
        Normalised weights, shape ``(N,)``.
    u0
        The one uniform draw in [0, 1).
    out
        Optional ``intp`` buffer for the indices.

    Returns
    -------
    numpy.ndarray
        ``(N,)`` indices into ``weights``.
    """
    n = len(weights)
    positions = (np.arange(n) + u0) / n
    cumulative = np.cumsum(weights)
    idx = np.searchsorted(cumulative, positions, side="right")
    # Rounding can leave the cumulative sum a hair below 1.
    return np.minimum(idx, n - 1, out=out)


class SystematicResampler:
    """Seeded systematic resampling of a :class:`ParticleSet`, with preallocated buffers.

    Parameters
    ----------
    n
        Number of particles.
    rng
        The filter's seeded generator (one uniform per resampling).
    """

    def __init__(self, n: int, rng: np.random.Generator) -> None:
        self.rng = rng
        self._ramp = np.arange(n, dtype=float)
        self._positions = np.empty(n)
        self._cumulative = np.empty(n)
        self._idx = np.empty(n, dtype=np.intp)
        self._spare = np.empty(n)
        self._log_uniform = -math.log(n)
        self._last = n - 1

    def resample(self, particles: ParticleSet, weights: np.ndarray) -> np.ndarray:
        """Replace ``particles`` by a systematic resample under ``weights``; reset weights to uniform.

        Returns the indices drawn (a reused buffer).
        """
        np.add(self._ramp, self.rng.random(), out=self._positions)
        self._positions /= len(weights)
        np.cumsum(weights, out=self._cumulative)
        idx = self._idx
        idx[...] = np.searchsorted(self._cumulative, self._positions, side="right")
        np.minimum(idx, self._last, out=idx)
        for name in ("x", "y", "theta", "scale", "bias_x", "bias_y"):
            current = getattr(particles, name)
            np.take(current, idx, out=self._spare)
            setattr(particles, name, self._spare)
            self._spare = current
        particles.log_weight.fill(self._log_uniform)
        return idx


class DivergenceRecovery:
    """Augmented MCL driven by GNSS: re-draw particles around the fix when the cloud stops agreeing.

    The robust GNSS likelihood bounds what one fix can do to the cloud, so a cloud that has drifted
    tens of metres away (a wrong turn, particles trapped behind a building) sees every fix as an
    outlier and GNSS can no longer pull it back. Following Thrun, Burgard & Fox, *Probabilistic
    Robotics* (2005), section 8.3.5, each fix measures the cloud's mean agreement with it,
    ``w_avg = sum_i w_i exp(-d_i^2 / (2 sigma^2))`` (``d_i``: the particle's expected fix to the fix,
    ``sigma = sigma_factor * accuracy``, ``w_i``: the prior weights), and a short- and a long-term
    average follow it, ``w += alpha (w_avg - w)``. When the short one falls well below the long one,
    the cloud has stopped agreeing with a GNSS that used to agree, and the fraction
    ``min(max_fraction, max(0, 1 - w_fast / (trigger_ratio * w_slow)))`` of the particles is replaced
    by draws around the fix. The agreement is the pure Gaussian kernel without its normaliser: a
    diverged cloud registers as ~0 (neither the outlier floor nor tempering hides it), and a change of
    reported accuracy alone does not read as divergence. It is computed in the log domain.

    Injected particles keep the drift angle, speed scale and GNSS bias of random current particles
    (the drift estimate survives); they land at ``fix - bias`` plus the fix's spread, with the average
    weight ``1 / N``. The map likelihood at the next footstep removes those that land in buildings.

    Parameters
    ----------
    config
        ``recovery_*`` rates, trigger and cap; ``n_particles``.
    sigma_factor
        GNSS sigma = factor * reported accuracy (the likelihood's).
    rng
        The filter's seeded generator (drawn from only when particles are injected).
    """

    def __init__(self, config: FilterConfig, sigma_factor: float, rng: np.random.Generator) -> None:
        self.alpha_fast = config.recovery_alpha_fast
        self.alpha_slow = config.recovery_alpha_slow
        self.trigger_ratio = config.recovery_trigger_ratio
        self.max_fraction = config.recovery_max_fraction
        self.sigma_factor = sigma_factor
        self.kernel_sigma_factor = sigma_factor * config.recovery_kernel_scale
        self.rng = rng
        self.fast = config.backend == "numba"
        self.w_fast = math.nan  # both start at the first fix's agreement
        self.w_slow = math.nan
        n = config.n_particles
        self.prior_log_weight = np.full(n, -math.log(n))
        self._tmp = np.empty(n)
        self._tmp2 = np.empty(n)

    @property
    def enabled(self) -> bool:
        """Whether any particle can ever be injected."""
        return self.max_fraction > 0

    def log_agreement(self, particles: ParticleSet, fix: GnssFix) -> float:
        """``log w_avg``: log of the prior-weighted mean Gaussian kernel of the expected fixes.

        Uses :attr:`prior_log_weight` (normalised log-weights before this fix's update).
        """
        p, d2, tmp = particles, self._tmp, self._tmp2
        scale = -0.5 / (self.kernel_sigma_factor * fix.accuracy_m) ** 2
        if self.fast:
            prior = self.prior_log_weight
            return _log_agreement(p.x, p.y, p.bias_x, p.bias_y, prior, fix.x, fix.y, scale, d2)
        np.add(p.x, p.bias_x, out=d2)
        d2 -= fix.x
        np.square(d2, out=d2)
        np.add(p.y, p.bias_y, out=tmp)
        tmp -= fix.y
        np.square(tmp, out=tmp)
        d2 += tmp
        d2 *= scale
        d2 += self.prior_log_weight
        peak = d2.max()
        if not math.isfinite(peak):
            return -math.inf
        d2 -= peak
        np.exp(d2, out=d2)
        return peak + math.log(float(d2.sum()))

    def observe(self, particles: ParticleSet, fix: GnssFix) -> float:
        """Update both averages with this fix; return the fraction of particles to inject."""
        w_avg = math.exp(self.log_agreement(particles, fix))
        if math.isnan(self.w_slow):
            self.w_fast = self.w_slow = w_avg
        else:
            self.w_fast += self.alpha_fast * (w_avg - self.w_fast)
            self.w_slow += self.alpha_slow * (w_avg - self.w_slow)
        threshold = self.trigger_ratio * self.w_slow
        if not threshold > 0:  # no fix ever agreed (or it underflowed): nothing to compare with
            return 0.0
        return min(self.max_fraction, max(0.0, 1.0 - self.w_fast / threshold))

    def inject(self, particles: ParticleSet, fix: GnssFix, fraction: float) -> int:
        """Replace ``round(fraction * N)`` random particles by draws around ``fix``; return how many."""
        n = len(particles)
        k = int(round(fraction * n))
        if k == 0:
            return 0
        p, rng = particles, self.rng
        idx = rng.choice(n, size=k, replace=False)
        donors = rng.integers(0, n, size=k)
        sigma = self.sigma_factor * fix.accuracy_m
        for name in ("theta", "scale", "bias_x", "bias_y"):
            values = getattr(p, name)
            values[idx] = values[donors]
        p.x[idx] = fix.x - p.bias_x[idx] + sigma * rng.standard_normal(k)
        p.y[idx] = fix.y - p.bias_y[idx] + sigma * rng.standard_normal(k)
        p.log_weight[idx] = -math.log(n)
        return k


class SegmentMode(NamedTuple):
    """The posterior mode over sidewalk segments at one step.

    Attributes
    ----------
    segment
        Index of the MAP segment (-1: no particle with positive weight near a sidewalk).
    prob
        Its posterior probability: the summed normalised weight of the particles whose nearest
        segment it is (0 without one).
    x, y
        Weighted mean of those particles (NaN without a MAP segment).
    """

    segment: int
    prob: float
    x: float
    y: float


def segment_posterior(
    segment_of: np.ndarray, weights: np.ndarray, x: np.ndarray, y: np.ndarray
) -> tuple[np.ndarray, SegmentMode]:
    """Posterior probability of every sidewalk segment and its mode, from weighted particles.

    Each particle votes its normalised weight to its nearest segment; particles near no segment (-1)
    vote for none. For 0-1 loss on the segment, the Bayes decision is the segment of largest posterior
    probability (ties: the lowest index).

    Parameters
    ----------
    segment_of
        ``(N,)`` nearest-segment index of each particle, -1 for none.
    weights
        ``(N,)`` normalised weights.
    x, y
        ``(N,)`` particle positions.

    Returns
    -------
    tuple
        ``(segment_weights, mode)``: the summed weight per segment index (up to the largest index
        present) and a :class:`SegmentMode`.
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
    # bincount sums in particle order, as the compiled path does, so both paths agree to the bit.
    mx = np.bincount(seg, weights=w * x[valid])[best]
    my = np.bincount(seg, weights=w * y[valid])[best]
    return segment_weights, SegmentMode(best, prob, float(mx / prob), float(my / prob))

# -- The fast path: the components above as compiled loops over the particles ------------------------
# Same draws, same formulas, same order of the random numbers; only the loops are compiled. No
# fastmath: the weights rely on -inf.


@numba.njit(cache=True, nogil=True)
def _predict_and_weigh(
    x, y, theta, scale, log_weight, cos_theta, sin_theta, noise, dx, dy, sigma_xy, sigma_theta,
    sigma_scale, use_map, padded, inv_res, x_offset, y_offset, col_max, row_max, stride, log_table,
    use_fix, fix_x, fix_y, fix_scale, fix_log_norm, fix_log_outlier, fix_exponent,
    use_bias, bias_x, bias_y, bias_noise, bias_rho, bias_innovation,
):  # pragma: no cover - compiled
    for i in range(x.shape[0]):
        th = theta[i] + sigma_theta * noise[2, i]
        theta[i] = th
        sc = scale[i] + sigma_scale * noise[3, i]
        scale[i] = sc
        c = math.cos(th)
        s = math.sin(th)
        cos_theta[i] = c
        sin_theta[i] = s
        xi = x[i] + (c * dx - s * dy) * sc + sigma_xy * noise[0, i]
        yi = y[i] + (s * dx + c * dy) * sc + sigma_xy * noise[1, i]
        x[i] = xi
        y[i] = yi
        lw = log_weight[i]
        if use_map:
            fx = min(max(xi * inv_res - x_offset, 0.0), col_max)
            fy = min(max(yi * inv_res - y_offset, 0.0), row_max)
            lw += log_table[padded[int(fy) * stride + int(fx)]]
        if use_bias:
            bx = bias_rho * bias_x[i] + bias_innovation * bias_noise[0, i]
            by = bias_rho * bias_y[i] + bias_innovation * bias_noise[1, i]
            bias_x[i] = bx
            bias_y[i] = by
            xi += bx  # where this particle expects the fix
            yi += by
        if use_fix:
            ex = xi - fix_x
            ey = yi - fix_y
            inlier = (ex * ex + ey * ey) * fix_scale + fix_log_norm
            # logaddexp(inlier, fix_log_outlier), as numpy computes it
            if fix_log_outlier == -math.inf:
                ll = inlier
            elif inlier >= fix_log_outlier:
                ll = inlier + math.log1p(math.exp(fix_log_outlier - inlier))
            else:
                ll = fix_log_outlier + math.log1p(math.exp(inlier - fix_log_outlier))
            lw += fix_exponent * ll
        log_weight[i] = lw


@numba.njit(cache=True, nogil=True)
def _normalise_and_estimate(log_weight, weights, x, y, scale, cos_theta, sin_theta):  # pragma: no cover
    n = log_weight.shape[0]
    peak = -math.inf
    for i in range(n):
        lw = log_weight[i]
        if lw != lw:
            return False, 0.0, 0.0, 0.0, 0.0, 0.0
        peak = max(peak, lw)
    if peak == -math.inf:
        return False, 0.0, 0.0, 0.0, 0.0, 0.0
    total = 0.0
    for i in range(n):
        w = math.exp(log_weight[i] - peak)
        weights[i] = w
        total += w
    log_total = math.log(total)
    ex = ey = esc = ec = es = sq = 0.0
    for i in range(n):
        w = weights[i] / total
        weights[i] = w
        log_weight[i] = log_weight[i] - peak - log_total
        ex += w * x[i]
        ey += w * y[i]
        esc += w * scale[i]
        ec += w * cos_theta[i]
        es += w * sin_theta[i]
        sq += w * w
    return True, ex, ey, math.atan2(es, ec), esc, 1.0 / sq


@numba.njit(cache=True, nogil=True)
def _systematic_resample(
    weights, u0, x, y, theta, scale, bias_x, bias_y, x_out, y_out, theta_out, scale_out, bias_x_out,
    bias_y_out,
):  # pragma: no cover - compiled
    # One merge pass: position k goes to the first particle whose cumulative weight exceeds it.
    n = weights.shape[0]
    j = 0
    cumulative = weights[0]
    for k in range(n):
        position = (k + u0) / n
        while position >= cumulative and j < n - 1:
            j += 1
            cumulative += weights[j]
        x_out[k] = x[j]
        y_out[k] = y[j]
        theta_out[k] = theta[j]
        scale_out[k] = scale[j]
        bias_x_out[k] = bias_x[j]
        bias_y_out[k] = bias_y[j]


@numba.njit(cache=True, nogil=True)
def _segment_mode(
    weights, x, y, padded_segments, inv_res, x_offset, y_offset, col_max, row_max, stride, segment_of,
    segment_sums,
):  # pragma: no cover - compiled
    # segment_sums (3, S): weight, weight * x, weight * y per segment; all zeros on entry and on exit
    # (only the touched entries are reset, in the second loop).
    n = x.shape[0]
    for i in range(n):
        fx = min(max(x[i] * inv_res - x_offset, 0.0), col_max)
        fy = min(max(y[i] * inv_res - y_offset, 0.0), row_max)
        k = padded_segments[int(fy) * stride + int(fx)]
        segment_of[i] = k
        if k >= 0:
            w = weights[i]
            segment_sums[0, k] += w
            segment_sums[1, k] += w * x[i]
            segment_sums[2, k] += w * y[i]
    best = -1
    prob = mx = my = 0.0
    for i in range(n):
        k = segment_of[i]
        if k < 0:
            continue
        w = segment_sums[0, k]
        # Each segment is compared once, at its first particle (its sums are then reset to 0).
        if w > prob or (w == prob and w > 0.0 and k < best):
            best = k
            prob = w
            mx = segment_sums[1, k]
            my = segment_sums[2, k]
        segment_sums[0, k] = 0.0
        segment_sums[1, k] = 0.0
        segment_sums[2, k] = 0.0
    if best < 0:
        return -1, 0.0, math.nan, math.nan
    return best, prob, mx / prob, my / prob


@numba.njit(cache=True, nogil=True)
def _log_agreement(x, y, bias_x, bias_y, prior_log_weight, fix_x, fix_y, scale, work):  # pragma: no cover
    """:meth:`DivergenceRecovery.log_agreement` as two compiled passes (max, then sum of exp)."""
    peak = -math.inf
    for i in range(x.shape[0]):
        dx = x[i] + bias_x[i] - fix_x
        dy = y[i] + bias_y[i] - fix_y
        v = scale * (dx * dx + dy * dy) + prior_log_weight[i]
        work[i] = v
        peak = max(peak, v)
    if not math.isfinite(peak):
        return -math.inf
    total = 0.0
    for i in range(x.shape[0]):
        total += math.exp(work[i] - peak)
    return peak + math.log(total)


class Estimate(NamedTuple):
    """The filter's output at one footstep (a named tuple: cheap to make once per footstep).

    Attributes
    ----------
    t
        Time, seconds on the session clock.
    x, y
        Weighted mean position, metres in the local CRS.
    theta
        Weighted circular mean of the heading drift, radians.
    scale
        Weighted mean speed scale.
    n_eff
        Effective sample size before resampling.
    recovered
        Whether the particle cloud collapsed at this step and was re-seeded.
    frame
        The local frame, for :attr:`lat` / :attr:`lon`.
    segment_id
        ``segment_id`` of the MAP sidewalk segment (the segment of largest posterior probability);
        ``None`` without a segment raster or with no weight near a sidewalk.
    segment_prob
        Its posterior probability (NaN without a segment raster, 0 with no weight near a sidewalk).
    mode_x, mode_y
        The mode estimate: weighted mean of the particles on the MAP segment (the weighted mean ``x, y``
        when there is none), metres in the local CRS.
    """

    t: float
    x: float
    y: float
    theta: float
    scale: float
    n_eff: float
    recovered: bool
    frame: LocalFrame | None = None
    segment_id: str | None = None
    segment_prob: float = math.nan
    mode_x: float = math.nan
    mode_y: float = math.nan

    @property
    def lat(self) -> float:
        """Latitude, WGS84 degrees."""
        return float(self.frame.to_lonlat(self.x, self.y)[1])

    @property
    def lon(self) -> float:
        """Longitude, WGS84 degrees."""
        return float(self.frame.to_lonlat(self.x, self.y)[0])

    @property
    def mode_lonlat(self) -> tuple[float, float]:
        """``(lon, lat)`` of the mode estimate, WGS84 degrees."""
        lon, lat = self.frame.to_lonlat(self.mode_x, self.mode_y)
        return float(lon), float(lat)


class Tracker:
    """Streaming particle filter: start it, then call :meth:`step` once per footstep.

    Parameters
    ----------
    map_layers
        The map (rasterised once, cached on disk), an already built :class:`MapRaster`, or ``None``
        to run without a map likelihood.
    config
        Filter parameters (defaults from :mod:`curbside.settings`).
    seed
        Seed of the filter's random generator: same seed and inputs, same estimates.
    frame
        Local metric frame. Default: the map's CRS; without a map, set by :meth:`start_at_lonlat` or
        given here.

    Attributes
    ----------
    recoveries
        Number of collapses (every weight zero) re-seeded so far.
    injections
        Number of particles injected around GNSS fixes so far (:class:`DivergenceRecovery`);
        ``last_injected``: how many at the latest step.

    Examples
    --------
    >>> tracker = Tracker(read_map("map.geojson"), FilterConfig(n_particles=500), seed=1)
    >>> tracker.start_at_lonlat(t0, lat, lon, heading_offset_rad=0.0)
    >>> est = tracker.step(t1, velocity_en=(1.1, 0.2), dt=0.55, gnss_fix=tracker.fix(lat, lon, 6.0))
    """

    def __init__(
        self,
        map_layers: MapLayers | MapRaster | None = None,
        config: FilterConfig | None = None,
        seed: int | None = 0,
        frame: LocalFrame | None = None,
    ) -> None:
        self.config = config or FilterConfig()
        n = int(self.config.n_particles)
        self.rng = np.random.default_rng(seed)
        if isinstance(map_layers, MapLayers):
            raster = load_or_build_raster(map_layers, self.config.raster_resolution_m)
        else:
            raster = map_layers
        self.map_likelihood = None if raster is None else MapLikelihood(raster, self.config.jaywalk_weight)
        if frame is None and raster is not None:
            frame = LocalFrame(pyproj.CRS.from_wkt(raster.crs))
        self.frame = frame
        self.predictor = InertialPredictor(self.config, self.rng)
        self.gnss_likelihood = GnssLikelihood(
            self.config.gnss_sigma_factor, self.config.gnss_max_accuracy_m, self.config.gnss_outlier_prob,
            self.config.gnss_outlier_radius_m, self.config.gnss_error_correlation_s,
        )
        self.resampler = SystematicResampler(n, self.rng)
        self.particles = ParticleSet(n)
        self.started = False
        self.last_estimate: Estimate | None = None
        self.last_fix: GnssFix | None = None
        self.last_fix_t = -math.inf
        self.recoveries = 0
        self.recovery = DivergenceRecovery(self.config, self.config.gnss_sigma_factor, self.rng)
        self._recovery_on = self.recovery.enabled
        self.injections = 0
        self.last_injected = 0
        self._inject_fraction = 0.0
        self._weights = np.empty(n)
        self._loglik = np.empty(n)
        self._tmp = np.empty(n)
        self._ess_threshold = self.config.ess_fraction * n
        self._log_uniform = -math.log(n)
        self._fast = self.config.backend == "numba"
        self._spare = tuple(np.empty(n) for _ in range(6))
        self._expected_x = np.empty(n)  # particle position + GNSS bias: where it expects the fix
        self._expected_y = np.empty(n)
        lookup = self.map_likelihood.lookup if self.map_likelihood is not None else None
        self._map_args = (
            (True, lookup.padded, lookup.inv_res, lookup.x_offset, lookup.y_offset, lookup.col_max,
             lookup.row_max, lookup.stride, self.map_likelihood.log_table)
            if lookup is not None
            else (False, np.zeros(1, np.uint8), 1.0, 0.0, 0.0, 0.0, 0.0, 1, np.zeros(BUILDING + 1))
        )
        self.segment_ids: np.ndarray | None = None
        if self.config.segment_estimate and lookup is not None and lookup.padded_segments is not None:
            self.segment_ids = raster.segment_ids
            self._segment_of = np.empty(n, lookup.padded_segments.dtype)
            self._segment_args = (
                lookup.padded_segments, lookup.inv_res, lookup.x_offset, lookup.y_offset, lookup.col_max,
                lookup.row_max, lookup.stride, self._segment_of, np.zeros((3, len(raster.segment_ids))),
            )

    # -- starting -----------------------------------------------------------------------------------

    def fix(self, lat: float, lon: float, accuracy_m: float) -> GnssFix:
        """A :class:`GnssFix` from WGS84 degrees, in this tracker's frame."""
        if self.frame is None:
            self.frame = LocalFrame.around(lon, lat)
        x, y = self.frame.to_xy(lon, lat)
        return GnssFix(float(x), float(y), float(accuracy_m))

    def start_at_lonlat(self, t: float, lat: float, lon: float, heading_offset_rad: float = 0.0) -> Estimate:
        """Start from a known pose given in WGS84 (see :meth:`start_at_pose`)."""
        if self.frame is None:
            self.frame = LocalFrame.around(lon, lat)
        x, y = self.frame.to_xy(lon, lat)
        return self.start_at_pose(t, float(x), float(y), heading_offset_rad)

    def start_at_pose(self, t: float, x: float, y: float, heading_offset_rad: float = 0.0) -> Estimate:
        """Start from a known pose: particles around ``(x, y)`` with drift around ``heading_offset_rad``.

        A pose inside a building is moved to the nearest free raster cell, with a warning.

        Raises
        ------
        CurbsideInputError
            The pose lies in a building with no free cell within ``config.max_start_snap_m``.
        """
        if self.map_likelihood is not None:
            raster = self.map_likelihood.raster
            if raster.codes_at(np.array([x]), np.array([y]))[0] == BUILDING:
                snapped = raster.nearest_code_other_than(x, y, BUILDING, self.config.max_start_snap_m)
                if snapped is None:
                    raise CurbsideInputError(
                        "start pose",
                        f"inside a building with no free space within {self.config.max_start_snap_m:g} m",
                    )
                logger.warning(
                    "start pose lies inside a building: starting from the nearest free cell, %.1f m away",
                    math.hypot(snapped[0] - x, snapped[1] - y),
                )
                x, y = snapped
        self._seed(x, y, self.config.init_position_sigma_m, heading_offset_rad,
                   math.radians(self.config.init_theta_sigma_deg))
        return self._update(t)

    def start_at_fix(self, t: float, fix: GnssFix) -> Estimate:
        """Start from a GNSS fix: particles spread by the fix's sigma, drift over the configured spread."""
        if not self.gnss_likelihood.accepts(fix):
            raise ValueError(f"cannot start from an invalid or inaccurate fix {fix}")
        sigma = self.gnss_likelihood.sigma_factor * fix.accuracy_m
        theta_sigma = self.config.gnss_init_theta_sigma_deg
        self._seed(fix.x, fix.y, sigma, 0.0, None if theta_sigma is None else math.radians(theta_sigma))
        p = self.particles
        p.x -= p.bias_x  # the fix is position + bias
        p.y -= p.bias_y
        self.last_fix, self.last_fix_t = fix, t
        return self._update(t)

    def _seed(self, x: float, y: float, sigma_m: float, theta: float, theta_sigma: float | None) -> None:
        p, n = self.particles, len(self.particles)
        p.x[:] = x + sigma_m * self.rng.standard_normal(n)
        p.y[:] = y + sigma_m * self.rng.standard_normal(n)
        if theta_sigma is None:
            p.theta[:] = self.rng.uniform(-math.pi, math.pi, n)
        else:
            p.theta[:] = theta + theta_sigma * self.rng.standard_normal(n)
        if self.config.scale_init_sigma > 0:
            p.scale[:] = 1.0 + self.config.scale_init_sigma * self.rng.standard_normal(n)
        else:
            p.scale.fill(1.0)
        if self.config.gnss_bias_sigma_m > 0:
            p.bias_x[:] = self.config.gnss_bias_sigma_m * self.rng.standard_normal(n)
            p.bias_y[:] = self.config.gnss_bias_sigma_m * self.rng.standard_normal(n)
        else:
            p.bias_x.fill(0.0)
            p.bias_y.fill(0.0)
        np.cos(p.theta, out=self.predictor.cos_theta)
        np.sin(p.theta, out=self.predictor.sin_theta)
        p.log_weight.fill(-math.log(n))
        if self.map_likelihood is not None:
            p.log_weight += self.map_likelihood.log_likelihood(p.x, p.y, out=self._loglik)
        self.started = True

    # -- one footstep -------------------------------------------------------------------------------

    def step(
        self,
        t: float,
        velocity_en: tuple[float, float] | np.ndarray | None = None,
        dt: float | None = None,
        displacement_en: tuple[float, float] | np.ndarray | None = None,
        gnss_fix: GnssFix | None = None,
    ) -> Estimate | None:
        """Advance the filter by one footstep.

        Parameters
        ----------
        t
            Time of the footstep, seconds.
        velocity_en, dt
            Mean inertial velocity (east, north; m/s) over the step and the step's duration (s) ...
        displacement_en
            ... or the step's displacement (east, north; metres) directly.
        gnss_fix
            A fix valid at ``t`` (invalid or inaccurate fixes are ignored).

        Returns
        -------
        Estimate or None
            ``None`` while the tracker has not started (no start pose and no usable fix yet); a usable
            fix before the start starts the tracker there.
        """
        if displacement_en is not None:
            dx, dy = float(displacement_en[0]), float(displacement_en[1])
        elif velocity_en is not None and dt is not None:
            dx, dy = float(velocity_en[0]) * dt, float(velocity_en[1]) * dt
        else:
            raise ValueError("step() needs velocity_en and dt, or displacement_en")
        if not (math.isfinite(dx) and math.isfinite(dy)):
            raise ValueError(f"non-finite inertial displacement ({dx}, {dy}) at t={t}")
        use_fix = self.gnss_likelihood.accepts(gnss_fix)
        if not self.started:
            return self.start_at_fix(t, gnss_fix) if use_fix else None
        p = self.particles
        exponent = self.gnss_likelihood.exponent(t - self.last_fix_t) if use_fix else 0.0
        dt_s = t - self.last_estimate.t if self.last_estimate is not None else 0.0
        track_agreement = use_fix and self._recovery_on
        if track_agreement and self.config.resample != "always":  # else uniform, as it starts
            np.copyto(self.recovery.prior_log_weight, p.log_weight)
        if self._fast:
            self._predict_and_weigh_fast(dx, dy, dt_s, gnss_fix if use_fix else None, exponent)
        else:
            self.predictor.predict(p, dx, dy, dt_s)
            if self.map_likelihood is not None:
                p.log_weight += self.map_likelihood.log_likelihood(p.x, p.y, out=self._loglik)
            if use_fix:
                np.add(p.x, p.bias_x, out=self._expected_x)
                np.add(p.y, p.bias_y, out=self._expected_y)
                p.log_weight += self.gnss_likelihood.log_likelihood(
                    self._expected_x, self._expected_y, gnss_fix, self._loglik, self._tmp, exponent
                )
        if use_fix:
            self.last_fix, self.last_fix_t = gnss_fix, t
        if track_agreement:
            self._inject_fraction = self.recovery.observe(p, gnss_fix)
        return self._update(t)

    def _predict_and_weigh_fast(
        self, dx: float, dy: float, dt_s: float, fix: GnssFix | None, exponent: float
    ) -> None:
        pred, p = self.predictor, self.particles
        sigma_xy = pred.draw_noise(dx, dy)
        bias_args = (pred.bias_sigma_m > 0, p.bias_x, p.bias_y, pred.bias_noise, *pred.bias_decay(dt_s))
        if fix is None:
            fix_args = (False, 0.0, 0.0, 0.0, 0.0, -math.inf, 0.0)
        else:
            fix_args = (True, fix.x, fix.y, *self.gnss_likelihood.coefficients(fix), exponent)
        _predict_and_weigh(
            p.x, p.y, p.theta, p.scale, p.log_weight, pred.cos_theta, pred.sin_theta, pred.noise, dx, dy,
            sigma_xy, pred.theta_sigma, pred.scale_sigma, *self._map_args, *fix_args, *bias_args,
        )

    def _normalise_and_estimate(self) -> tuple[bool, float, float, float, float, float]:
        """``(ok, x, y, theta, scale, n_eff)`` after normalising the weights in place."""
        p, w = self.particles, self._weights
        c, s = self.predictor.cos_theta, self.predictor.sin_theta
        if self._fast:
            return _normalise_and_estimate(p.log_weight, w, p.x, p.y, p.scale, c, s)
        if not normalise_log_weights(p.log_weight, w):
            return False, 0.0, 0.0, 0.0, 0.0, 0.0
        theta = math.atan2(float(np.dot(w, s)), float(np.dot(w, c)))
        x, y, scale = float(np.dot(w, p.x)), float(np.dot(w, p.y)), float(np.dot(w, p.scale))
        return True, x, y, theta, scale, effective_sample_size(w)

    def segment_mode(self) -> SegmentMode | None:
        """The posterior mode over sidewalk segments under the current normalised weights.

        ``None`` without a segment raster (no map, a map without sidewalks, or
        ``config.segment_estimate`` off).
        """
        if self.segment_ids is None:
            return None
        p = self.particles
        if self._fast:
            return SegmentMode(*_segment_mode(self._weights, p.x, p.y, *self._segment_args))
        segment_of = self.map_likelihood.lookup.segments_at(p.x, p.y, out=self._segment_of)
        return segment_posterior(segment_of, self._weights, p.x, p.y)[1]

    def _update(self, t: float) -> Estimate:
        """Normalise, recover from a collapse, estimate (mean and segment mode), resample."""
        ok, x, y, theta, scale, n_eff = self._normalise_and_estimate()
        if not ok:
            self._recover(t)  # leaves finite weights, so the second pass succeeds
            _, x, y, theta, scale, n_eff = self._normalise_and_estimate()
        mode = self.segment_mode()
        if mode is None:
            segment_id, prob, mode_x, mode_y = None, math.nan, x, y
        elif mode.segment < 0:
            segment_id, prob, mode_x, mode_y = None, 0.0, x, y
        else:
            segment_id, prob, mode_x, mode_y = str(self.segment_ids[mode.segment]), mode.prob, mode.x, mode.y
        estimate = Estimate(
            t, x, y, theta, scale, n_eff, not ok, self.frame, segment_id, prob, mode_x, mode_y
        )
        if self.config.resample == "always" or n_eff < self._ess_threshold:
            self._resample()
        self.last_injected = self._inject() if self._inject_fraction > 0 else 0
        self.last_estimate = estimate
        return estimate

    def _resample(self) -> None:
        p = self.particles
        if not self._fast:
            self.resampler.resample(p, self._weights)
            return
        out = self._spare
        _systematic_resample(
            self._weights, self.rng.random(), p.x, p.y, p.theta, p.scale, p.bias_x, p.bias_y, *out
        )
        self._spare = (p.x, p.y, p.theta, p.scale, p.bias_x, p.bias_y)
        p.x, p.y, p.theta, p.scale, p.bias_x, p.bias_y = out
        p.log_weight.fill(self._log_uniform)

    def _inject(self) -> int:
        """After resampling, inject the fraction of particles :meth:`step` asked for around the latest fix."""
        k = self.recovery.inject(self.particles, self.last_fix, self._inject_fraction)
        self._inject_fraction = 0.0
        self.injections += k
        if k:
            logger.debug("cloud disagrees with GNSS (w_fast/w_slow = %.3g): %d particles injected",
                         self.recovery.w_fast / self.recovery.w_slow, k)
        return k

    def _recover(self, t: float) -> None:
        """Re-seed a collapsed cloud around the last estimate and the latest good fix; never NaN.

        Half the particles go around the cloud's predicted centre (where the last estimate has moved
        to), half around the latest usable fix (all of them when one of the two is missing). Drift
        angles and speed scales are kept: those beliefs are still informative. Weights then come from the map
        alone; if even that kills every particle, they are made uniform.
        """
        self.recoveries += 1
        p, n = self.particles, len(self.particles)
        centres = []
        cx, cy = float(np.mean(p.x)), float(np.mean(p.y))
        if math.isfinite(cx) and math.isfinite(cy):
            centres.append((cx, cy, self.config.recovery_sigma_m))
        elif self.last_estimate is not None:
            centres.append((self.last_estimate.x, self.last_estimate.y, self.config.recovery_sigma_m))
        fix = self.last_fix
        if fix is not None:
            centres.append((fix.x, fix.y, self.gnss_likelihood.sigma_factor * fix.accuracy_m))
        if not centres:
            centres.append((0.0, 0.0, self.config.recovery_sigma_m))
        which = np.arange(n) % len(centres)
        cxs, cys, sig = (np.array(v)[which] for v in zip(*centres, strict=True))
        p.x[:] = cxs + sig * self.rng.standard_normal(n)
        p.y[:] = cys + sig * self.rng.standard_normal(n)
        p.theta[~np.isfinite(p.theta)] = 0.0
        p.scale[~np.isfinite(p.scale)] = 1.0
        np.cos(p.theta, out=self.predictor.cos_theta)
        np.sin(p.theta, out=self.predictor.sin_theta)
        p.log_weight.fill(-math.log(n))
        if self.map_likelihood is not None:
            p.log_weight += self.map_likelihood.log_likelihood(p.x, p.y, out=self._loglik)
        if not np.isfinite(p.log_weight.max()):
            p.log_weight.fill(-math.log(n))
        logger.debug("particle cloud collapsed at t=%.2f s: re-seeded (%d so far)", t, self.recoveries)
