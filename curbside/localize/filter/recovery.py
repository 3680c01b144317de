"""Recovery policies: re-seed a collapsed cloud; re-draw part of a cloud that no longer agrees with GNSS;
re-draw a cloud far from every fix.

**Collapse** (:class:`CollapseRecovery`): every weight is zero (all particles walked into buildings, or
``w = 0`` left none on a crossing). Half the particles go around the cloud's centre (where the last
estimate has moved to), half around the latest usable fix (all of them when one of the two is
missing); heading offsets and speed scales are kept (those beliefs are still informative); weights
then come from the map alone, and are made uniform if even that kills every particle. Never NaN.

**Divergence** (:class:`DivergenceRecovery`, Augmented MCL driven by GNSS; Thrun, Burgard & Fox,
*Probabilistic Robotics* 2005, section 8.3.5): the robust GNSS likelihood bounds what one fix can do,
so a cloud that drifted tens of metres away sees every fix as an outlier and GNSS can no longer pull it
back. Each fix measures the cloud's agreement with it, ``w_avg = sum_i w_i exp(-d_i^2 / (2 s^2))``
(``d_i``: the particle's expected fix to the fix, ``s = kernel_scale *`` the likelihood's sigma,
``w_i``: the prior weights), a short- and a long-term average follow it, and when the short one falls
well below the long one the fraction ``min(max_fraction, max(0, 1 - w_fast / (trigger_ratio *
w_slow)))`` of the particles is re-drawn around the fix after resampling. Injected particles take the
speed scale and bias of random current particles, and their heading offset with a jitter
(``inject_heading_sigma_deg``): a cloud usually diverges because its heading offset went wrong.

**Stall** (the same part, a second trigger): the map can hold a cloud still while the phone walks on.
A cloud that lags along the street turns at the corner too early, into a wall, and the only particles
left are those that the walls stop; with fixes reporting 10 m accuracy, the agreement kernel reads a
cloud 50 m away as agreeing for minutes. Walkers do not walk into walls, so when the estimate has
moved less than ``stall_ratio`` of the inertial displacement over the last ``stall_window_s`` (turned
and scaled by the estimate's heading offset and speed scale, and at least ``stall_min_speed_mps``
per second) *and* the map stopped at least ``stall_blocked_share`` of the particles at an average
update of that window, ``stall_fraction`` of the particles is re-drawn around each usable fix, as for
a divergence, until the cloud moves again. The second condition tells walls from fixes: a run of
fixes that lag the walker also holds a cloud back, and re-drawing around them would follow them.

**Lost** (:class:`Relocation`, a third trigger of the same part; the "kidnapped robot" of Thrun et al.
2005, section 8.3.5): a cloud hundreds of metres from the fixes (a start at a phone's stale last-known
place) gets nothing from them, since the robust likelihood bounds what a fix can do, and no kernel
average has ever agreed with them, so the divergence trigger does not fire. When, for
``relocate_after_s``, every usable fix reporting at most ``relocate_max_accuracy_m`` lay farther than
``relocate_distance_m`` from the estimate (farther than any fix error of the simulated canyons or the
IPIN phones) and the latest such fix agrees with most of them (a share ``relocate_agreeing_share`` of
those of that time lie within ``relocate_agreement_m`` of it), every particle is re-drawn around that
fix: spread by the likelihood's sigma, its heading offset jittered (``relocate_heading_sigma_deg``),
its GNSS bias zeroed and its speed scale kept, weights uniform; the map and the fix weigh them at the
same update. A fix within the distance stops the count.
"""

from __future__ import annotations

import collections
import logging
import math

import numba
import numpy as np

from curbside.localize.filter.correction_config import RecoveryConfig
from curbside.localize.filter.gnss import GnssLikelihood
from curbside.localize.filter.kernelmath import exp
from curbside.localize.filter.map_likelihood import MapLikelihood
from curbside.localize.filter.particles import (
    BIAS_X,
    BIAS_Y,
    COS,
    SCALE,
    SIN,
    THETA,
    Estimate,
    ParticleSet,
    X,
    Y,
)
from curbside.localize.filter.parts import GnssFix, Update

logger = logging.getLogger(__name__)


class CollapseRecovery:
    """Re-seeds a collapsed cloud (see the module docstring).

    Parameters
    ----------
    config
        ``collapse_sigma_m``.
    rng
        The filter's seeded generator.
    map_likelihood
        The map (weights after re-seeding); ``None`` without a map.
    fix_sigma_factor
        Spread around the latest fix = this times its accuracy.
    """

    def __init__(
        self,
        config: RecoveryConfig,
        rng: np.random.Generator,
        map_likelihood: MapLikelihood | None,
        fix_sigma_factor: float,
    ) -> None:
        self.config = config
        self.rng = rng
        self.map_likelihood = map_likelihood
        self.fix_sigma_factor = fix_sigma_factor

    def reseed(
        self, particles: ParticleSet, fallback_xy: tuple[float, float] | None, fix: GnssFix | None
    ) -> None:
        """Re-seed around the cloud's centre (else ``fallback_xy``) and ``fix``; weights from the map."""
        n, s = len(particles), particles.state
        centres = []
        cx, cy = float(np.mean(s[X])), float(np.mean(s[Y]))
        if math.isfinite(cx) and math.isfinite(cy):
            centres.append((cx, cy, self.config.collapse_sigma_m))
        elif fallback_xy is not None:
            centres.append((*fallback_xy, self.config.collapse_sigma_m))
        if fix is not None:
            centres.append((fix.x, fix.y, self.fix_sigma_factor * fix.accuracy_m))
        if not centres:
            centres.append((0.0, 0.0, self.config.collapse_sigma_m))
        which = np.arange(n) % len(centres)
        cxs, cys, sig = (np.array(v)[which] for v in zip(*centres, strict=True))
        s[X] = cxs + sig * self.rng.standard_normal(n)
        s[Y] = cys + sig * self.rng.standard_normal(n)
        theta = s[THETA]
        theta[~np.isfinite(theta)] = 0.0
        particles.set_heading(theta.copy())
        s[SCALE][~np.isfinite(s[SCALE])] = 1.0
        particles.reset_weights()
        if self.map_likelihood is not None:
            particles.log_weight += self.map_likelihood.log_likelihood(s[X], s[Y])
        if not np.isfinite(particles.log_weight.max()):
            particles.reset_weights()


class DivergenceRecovery:
    """Augmented MCL driven by GNSS (see the module docstring).

    Parameters
    ----------
    config
        Rates, trigger, kernel scale and cap.
    gnss
        The GNSS likelihood (which fixes count, and their sigma).
    rng
        The filter's seeded generator (drawn from only when particles are injected).
    map_likelihood
        The map, whose walls the stall test watches (``None``: no map, no stall).
    """

    def __init__(
        self,
        config: RecoveryConfig,
        gnss: GnssLikelihood,
        rng: np.random.Generator,
        map_likelihood: MapLikelihood | None = None,
    ) -> None:
        self.config = config
        self.gnss = gnss
        self.rng = rng
        self.map_likelihood = map_likelihood
        self.w_fast = math.nan  # both start at the first fix's agreement
        self.w_slow = math.nan
        self.injections = 0
        self.relocation = Relocation(config, gnss, rng)
        self.inertial = 0j  # the turned and scaled inertial displacement so far (east + i north)
        # (t, estimate, inertial, blocked share) over the stall window, oldest first; positions complex
        self.recent: collections.deque[tuple[float, complex, complex, float]] = collections.deque()

    def log_agreement(self, particles: ParticleSet, fix: GnssFix) -> float:
        """``log w_avg`` under the current (prior, normalised) log-weights."""
        scale = -0.5 / (self.config.kernel_scale * self.gnss.sigma_m(fix)) ** 2
        return _log_agreement(particles.state, particles.log_weight, fix.x, fix.y, scale)

    def observe(self, particles: ParticleSet, update: Update, last: Estimate | None = None) -> float:
        """Before the likelihoods: the fraction of the particles to re-draw around ``update.fix``.

        ``last`` (the estimate before this update) feeds the stall test; without it only the
        agreement averages decide. While stalled the averages are left as they are.
        """
        stalled = last is not None and self.stalled(update, last)
        if last is not None and self.relocation.observe(particles, update, last):
            self.w_fast = self.w_slow = math.nan  # both start again at the next fix's agreement
            return 0.0
        if self.config.max_fraction <= 0 or not self.gnss.accepts(update.fix):
            return 0.0
        if stalled:
            logger.debug("t=%.1f: the cloud is stalled", update.t)
            return min(self.config.max_fraction, self.config.stall_fraction)
        w_avg = math.exp(self.log_agreement(particles, update.fix))
        if math.isnan(self.w_slow):
            self.w_fast = self.w_slow = w_avg
        else:
            self.w_fast += self.config.alpha_fast * (w_avg - self.w_fast)
            self.w_slow += self.config.alpha_slow * (w_avg - self.w_slow)
        threshold = self.config.trigger_ratio * self.w_slow
        if not threshold > 0:  # no fix ever agreed (or it underflowed): nothing to compare with
            return 0.0
        return min(self.config.max_fraction, max(0.0, 1.0 - self.w_fast / threshold))

    @property
    def relocations(self) -> int:
        """How often the whole cloud was re-drawn around a far fix (:class:`Relocation`)."""
        return self.relocation.relocations

    def stalled(self, update: Update, last: Estimate) -> bool:
        """Whether the walls hold the cloud still while the phone walks on (see the module docstring);
        called once per update, in order.

        The estimate moved less than ``stall_ratio`` of the inertial displacement over the stall window
        (turned and scaled by the estimate's heading offset and speed scale; a vector sum, so a walker
        who turns back is no stall), and the map stopped at least ``stall_blocked_share`` of the
        particles at an average update of the window (fixes that pull a cloud back stop none).
        """
        config = self.config
        if config.stall_ratio <= 0 or self.map_likelihood is None:
            return False
        turn = last.scale * complex(math.cos(last.theta), math.sin(last.theta))
        self.inertial += turn * complex(update.dx, update.dy)
        recent = self.recent
        recent.append((last.t, complex(last.x, last.y), self.inertial, self.map_likelihood.blocked_share))
        while len(recent) > 1 and recent[1][0] <= last.t - config.stall_window_s:
            recent.popleft()
        t0, position0, inertial0, _ = recent[0]
        span_s, walked_m = last.t - t0, abs(self.inertial - inertial0)
        if span_s < 0.9 * config.stall_window_s or walked_m < config.stall_min_speed_mps * span_s:
            return False
        if abs(complex(last.x, last.y) - position0) >= config.stall_ratio * walked_m:
            return False
        return sum(entry[3] for entry in recent) >= config.stall_blocked_share * len(recent)

    def inject(self, particles: ParticleSet, fix: GnssFix, fraction: float) -> int:
        """After resampling: replace ``round(fraction * N)`` random particles by draws around ``fix``."""
        n = len(particles)
        k = int(round(fraction * n))
        if k == 0:
            return 0
        s, rng = particles.state, self.rng
        idx = rng.choice(n, size=k, replace=False)
        donors = rng.integers(0, n, size=k)
        sigma = self.gnss.sigma_m(fix)
        for row in (THETA, COS, SIN, SCALE, BIAS_X, BIAS_Y):
            s[row, idx] = s[row, donors]
        if self.config.inject_heading_sigma_deg > 0:
            s[THETA, idx] += math.radians(self.config.inject_heading_sigma_deg) * rng.standard_normal(k)
            s[COS, idx] = np.cos(s[THETA, idx])
            s[SIN, idx] = np.sin(s[THETA, idx])
        s[X, idx] = fix.x - s[BIAS_X, idx] + sigma * rng.standard_normal(k)
        s[Y, idx] = fix.y - s[BIAS_Y, idx] + sigma * rng.standard_normal(k)
        particles.log_weight[idx] = -math.log(n)
        self.injections += k
        logger.debug("%d particles injected (w_fast/w_slow = %.3g)", k, self.w_fast / self.w_slow)
        return k


class Relocation:
    """Re-draws the whole cloud around far fixes that agree with each other (see the module docstring).

    Parameters
    ----------
    config
        The ``relocate_*`` fields.
    gnss
        The GNSS likelihood (which fixes count, and the spread of the re-drawn particles).
    rng
        The filter's seeded generator (drawn from only when the cloud is re-drawn).

    Attributes
    ----------
    relocations
        How often the cloud was re-drawn.
    """

    def __init__(self, config: RecoveryConfig, gnss: GnssLikelihood, rng: np.random.Generator) -> None:
        self.config = config
        self.gnss = gnss
        self.rng = rng
        self.relocations = 0
        self.since = math.nan  # time of the first far fix since the last near one (NaN: none)
        self.window: collections.deque[tuple[float, complex]] = collections.deque()  # far (t, fix), old first

    def observe(self, particles: ParticleSet, update: Update, last: Estimate) -> bool:
        """Before the likelihoods, once per update: count ``update.fix`` (far from ``last`` or not), and
        re-draw the cloud around it when the far fixes have lasted long enough and agree with it.
        Returns whether it re-drew."""
        config, fix, t = self.config, update.fix, update.t
        if (
            config.relocate_distance_m <= 0
            or not self.gnss.accepts(fix)
            or fix.accuracy_m > config.relocate_max_accuracy_m
        ):
            return False
        here, window = complex(fix.x, fix.y), self.window
        if abs(here - complex(last.x, last.y)) <= config.relocate_distance_m:
            self.since = math.nan
            window.clear()
            return False
        if math.isnan(self.since):
            self.since = t
        window.append((t, here))
        while window[0][0] < t - config.relocate_after_s:
            window.popleft()
        if t - self.since < config.relocate_after_s or len(window) < config.relocate_min_fixes:
            return False
        apart_m = np.abs(np.array([there for _, there in window]) - here)
        if np.mean(apart_m <= config.relocate_agreement_m) < config.relocate_agreeing_share:
            return False
        logger.info("t=%.1f: every good fix of the last %.0f s lies over %.0f m from the estimate: the "
                    "cloud is re-drawn around them", t, t - self.since, config.relocate_distance_m)
        self.relocate(particles, fix)
        return True

    def relocate(self, particles: ParticleSet, fix: GnssFix) -> None:
        """Re-draw every particle around ``fix`` (see the module docstring)."""
        n, s, rng = len(particles), particles.state, self.rng
        sigma = self.gnss.sigma_m(fix)
        s[X] = fix.x + sigma * rng.standard_normal(n)
        s[Y] = fix.y + sigma * rng.standard_normal(n)
        spread = self.config.relocate_heading_sigma_deg
        if spread is None:
            particles.set_heading(rng.uniform(-math.pi, math.pi, n))
        else:
            particles.set_heading(s[THETA] + math.radians(spread) * rng.standard_normal(n))
        s[BIAS_X] = s[BIAS_Y] = 0.0
        particles.reset_weights()
        self.relocations += 1
        self.since = math.nan
        self.window.clear()


@numba.njit(cache=True, nogil=True, error_model="numpy")  # kernelmath.exp vectorises under it
def _log_agreement(state, log_weight, fix_x, fix_y, scale):  # pragma: no cover - compiled
    n = state.shape[1]
    work = np.empty(n)
    for i in range(n):
        dx = state[X, i] + state[BIAS_X, i] - fix_x
        dy = state[Y, i] + state[BIAS_Y, i] - fix_y
        work[i] = scale * (dx * dx + dy * dy) + log_weight[i]
    peak = -math.inf
    for i in range(n):
        peak = max(peak, work[i])
    if not math.isfinite(peak):
        return -math.inf
    for i in range(n):
        work[i] = exp(work[i] - peak)
    total = 0.0
    for i in range(n):
        total += work[i]
    return peak + math.log(total)
