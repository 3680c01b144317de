"""GNSS-driven correction of a velocity that turned: a mixture proposal for heading, scale and position.

The heading offset takes a small random walk at each update, so when a velocity model's direction
turns by tens of degrees within seconds (a model that has not seen the phone or its carrier; on the
IPIN 2023 trials RoNIN trained on MS-indoor alone turns by 30-60 degrees from one leg to the next),
selection cannot follow: the cloud walks off the fixes, and once it is a dozen metres away every fix
is an outlier to every particle (the robust GNSS likelihood's floor), so good fixes no longer pull it
back. The divergence recovery waits for minutes of disagreement by design (multipath bursts).

This part fits the accepted fixes of the last ``window_s`` seconds on the cloud's inertial path by a
similarity transform (:mod:`curbside.localize.filter.pathfit`). It acts only when

- the fixes are good enough to steer by (median reported accuracy at most ``max_accuracy_m``) and lie
  close to the fitted path (residual at most ``max_residual_ratio`` times that accuracy: fixes that
  wander with multipath do not fit a rigidly turned walk);
- the fit turns the inertial path by ``min_rotation_deg`` or more, and the filter's own estimated
  track by ``min_estimate_rotation_deg`` or more (the cloud really walks off the fixes, rather than
  following them through its position noise);
- its speed scale is plausible (``min_scale`` to ``max_scale``) and both path and fixes span enough
  metres for the fit to mean something.

Then, after resampling, a share ``fraction`` of the particles, picked at random, is re-drawn where the
fit puts the walker now (σ = ``position_sigma_factor`` x the median accuracy), with the cloud's heading
offset plus the fitted turn and the fitted speed scale (each with a small spread). The likelihoods then
keep them or not, as they do the divergence recovery's. Parameters:
:class:`~curbside.localize.filter.correction_config.HeadingCorrectionConfig`; docs/filter.md,
"Heading correction from GNSS".
"""

from __future__ import annotations

import logging
import math

import numpy as np

from curbside.localize.filter.correction_config import HeadingCorrectionConfig
from curbside.localize.filter.gnss import GnssLikelihood
from curbside.localize.filter.particles import SCALE, THETA, Estimate, ParticleSet, X, Y
from curbside.localize.filter.parts import Update
from curbside.localize.filter.pathfit import FixPathWindow, PathFit, fit_similarity, span_m

logger = logging.getLogger(__name__)


class HeadingCorrection:
    """GNSS-driven heading, scale and position re-draws (see the module docstring).

    Parameters
    ----------
    config
        The window, the gates and the re-draw.
    gnss
        The GNSS likelihood (which fixes count).
    rng
        The filter's seeded generator (drawn from only when particles are re-drawn).
    """

    def __init__(
        self, config: HeadingCorrectionConfig, gnss: GnssLikelihood, rng: np.random.Generator
    ) -> None:
        self.config = config
        self.gnss = gnss
        self.rng = rng
        self.window = FixPathWindow()
        self.pending: tuple[PathFit, float] | None = None  # the fit and the fixes' median accuracy
        self.corrections = 0

    def observe(self, update: Update, last: Estimate) -> None:
        """Before the likelihoods: extend the inertial path; keep an accepted fix; fit and gate when due."""
        config = self.config
        if config.fraction <= 0:
            return
        self.window.advance(update, last.theta)
        fix = update.fix
        if fix is None or not self.gnss.accepts(fix):
            return
        if not self.window.add(update.t, fix, complex(last.x, last.y), config.window_s):
            return
        accuracy_m = self.window.median_accuracy_m()
        if accuracy_m > config.max_accuracy_m:  # the usual case in a canyon: decided without arrays
            return
        path, fixes, accuracy, estimates = self.window.arrays()
        if span_m(path) < config.min_path_m:
            return
        if span_m(fixes) < max(config.min_fix_span_m, 3.0 * math.sqrt(2.0) * accuracy_m):
            return
        fit = fit_similarity(path, fixes, accuracy)
        if (
            abs(fit.rotation) < math.radians(config.min_rotation_deg)
            or fit.rms_m > config.max_residual_ratio * accuracy_m
            or not config.min_scale <= fit.scale <= config.max_scale
        ):
            return
        turn = fit_similarity(estimates, fixes, accuracy).rotation
        if abs(turn) < math.radians(config.min_estimate_rotation_deg):
            return
        logger.debug(
            "t=%.1f: fixes turn the inertial path by %.0f deg (the track by %.0f), scale %.2f, residual "
            "%.1f m at accuracy %.1f m: re-draw",
            update.t, math.degrees(fit.rotation), math.degrees(turn), fit.scale, fit.rms_m, accuracy_m,
        )
        self.pending = (fit, accuracy_m)

    def correct(self, particles: ParticleSet) -> int:
        """After resampling: re-draw a share of the particles from a pending fit; how many."""
        if self.pending is None:
            return 0
        (fit, accuracy_m), self.pending = self.pending, None
        config, rng = self.config, self.rng
        n = len(particles)
        k = int(round(config.fraction * n))
        if k == 0:
            return 0
        idx = rng.choice(n, size=k, replace=False)
        state = particles.state
        theta = state[THETA].copy()
        theta[idx] += fit.rotation + math.radians(config.heading_sigma_deg) * rng.standard_normal(k)
        particles.set_heading(theta)
        scale = fit.scale * np.exp(config.scale_sigma * rng.standard_normal(k))
        state[SCALE, idx] = np.clip(scale, config.min_scale, config.max_scale)
        here = fit.place(self.window.path)
        sigma_m = config.position_sigma_factor * accuracy_m
        state[X, idx] = here.real + sigma_m * rng.standard_normal(k)
        state[Y, idx] = here.imag + sigma_m * rng.standard_normal(k)
        self.corrections += 1
        return k
