"""GNSS-driven speed-scale correction: a mixture proposal for the speed scale, like Augmented MCL's.

The speed-scale state (row ``scale``) starts around 1 and walks slowly, so a walk whose inertial speed
reads 30 % low (the filter needs a scale near 1.4) is out of reach of selection and diffusion: the
cloud lags along the street. This part compares the fixes with the cloud's own inertial path.

It keeps the cloud's inertial path and the accepted fixes of the last ``window_s`` seconds and fits the
fixes on the path by a similarity transform (:mod:`curbside.localize.filter.pathfit`; the fitted scale
is unbiased by a heading error or a bias the fixes share over the window). The fit is repeated once
without the share ``trim_share`` of the fixes farthest from it (urban-canyon fixes off by tens of
metres), and is used only when the window's path is long compared with the fixes' accuracy (span >
``max(min_path_m, 3 sqrt(2) median accuracy)``).
Its standard error comes from its residuals, counting one independent fix per ``correlation_s``
seconds. When the fitted scale differs from the cloud's mean by more than ``trigger`` (relative) and
by more than ``significance`` standard errors, and the fitted rotation is under ``max_rotation_deg``
(a fit that needs a large turn does not describe this path), a share ``fraction`` of the particles,
picked at random after resampling, re-draws its scale as ``fitted * exp(sigma * N(0, 1))`` clipped to
``[min_scale, max_scale]``; the likelihoods then decide which of them survive. A fit is made at most
every quarter window. Parameters: :class:`~curbside.localize.filter.correction_config.ScaleCorrectionConfig`.
"""

from __future__ import annotations

import logging
import math

import numpy as np

from curbside.localize.filter.correction_config import ScaleCorrectionConfig
from curbside.localize.filter.gnss import GnssLikelihood
from curbside.localize.filter.particles import SCALE, Estimate, ParticleSet
from curbside.localize.filter.parts import Update
from curbside.localize.filter.pathfit import FixPathWindow, fit_similarity, span_m

logger = logging.getLogger(__name__)


def fit_scale(
    path: np.ndarray, fixes: np.ndarray, accuracy: np.ndarray, correlation_s: float
) -> tuple[float, float, float]:
    """Weighted similarity fit of ``fixes`` on ``path`` (complex arrays, metres): ``(scale, rotation, se)``.

    ``rotation`` is in radians; ``se`` is the scale's standard error from the residuals, counting one
    independent fix per ``correlation_s`` seconds' worth of fixes (at 1 Hz; successive fixes share most
    of their error).
    """
    fit = fit_similarity(path, fixes, accuracy)
    w = 1.0 / accuracy**2
    spread = np.sum(w * np.abs(path - fit.path_centre) ** 2)
    r = fit.residuals
    var = np.sum(w * np.abs(r) ** 2) / max(1, len(r) - 3) / 2.0  # per axis
    se = math.sqrt(var / spread * max(1.0, len(r) / max(1.0, len(r) / correlation_s)))
    return fit.scale, fit.rotation, se


def robust_fit(
    path: np.ndarray, fixes: np.ndarray, accuracy: np.ndarray, config: ScaleCorrectionConfig
) -> tuple[float, float, float]:
    """:func:`fit_scale`, then again without the ``trim_share`` of fixes farthest from the fit."""
    scale, rot, se = fit_scale(path, fixes, accuracy, config.correlation_s)
    w = 1.0 / accuracy**2
    z = scale * complex(math.cos(rot), math.sin(rot))
    centre = np.sum(w * (fixes - z * path)) / np.sum(w)
    residual = np.abs(fixes - z * path - centre)
    keep = residual <= np.quantile(residual, 1.0 - config.trim_share)
    if keep.sum() >= 3:
        scale, rot, se = fit_scale(path[keep], fixes[keep], accuracy[keep], config.correlation_s)
    return scale, rot, se


class ScaleCorrection:
    """GNSS-driven speed-scale re-draws (see the module docstring).

    Parameters
    ----------
    config
        The window, the gates and the re-draw.
    gnss
        The GNSS likelihood (which fixes count).
    rng
        The filter's seeded generator (drawn from only when scales are re-drawn).
    """

    def __init__(self, config: ScaleCorrectionConfig, gnss: GnssLikelihood, rng: np.random.Generator) -> None:
        self.config = config
        self.gnss = gnss
        self.rng = rng
        self.window = FixPathWindow()
        self.target = math.nan  # a scale to re-draw around at the next :meth:`correct`
        self.corrections = 0

    def observe(self, update: Update, last: Estimate) -> None:
        """Before the likelihoods: extend the inertial path; keep an accepted fix; fit when due.

        Idle while ``config.fraction`` is 0 (a tracker may turn it on mid-walk).
        """
        if self.config.fraction <= 0:
            return
        self.window.advance(update, last.theta)
        fix, t = update.fix, update.t
        if fix is None or not self.gnss.accepts(fix):
            return
        if not self.window.add(t, fix, complex(last.x, last.y), self.config.window_s):
            return
        path, fixes, accuracy, _ = self.window.arrays()
        span = span_m(path)
        if span < max(self.config.min_path_m, 3.0 * math.sqrt(2.0) * self.window.median_accuracy_m()):
            return
        scale, rot, se = robust_fit(path, fixes, accuracy, self.config)
        if not (math.isfinite(scale) and last.scale > 0):
            return
        logger.debug(
            "t=%.1f: fixes fit scale %.3f +- %.3f (rotation %.1f deg, span %.0f m) against the cloud's %.3f",
            t,
            scale,
            se,
            math.degrees(rot),
            span,
            last.scale,
        )
        off = abs(math.log(scale / last.scale))
        if (
            off > math.log1p(self.config.trigger)
            and off > self.config.significance * se / scale
            and abs(rot) < math.radians(self.config.max_rotation_deg)
        ):
            self.target = min(self.config.max_scale, max(self.config.min_scale, scale))
            logger.debug("t=%.1f: re-draw around %.3f", t, self.target)

    def correct(self, particles: ParticleSet) -> int:
        """After resampling: re-draw the scale of a fraction of the particles around a pending target."""
        if not math.isfinite(self.target):
            return 0
        n = len(particles)
        k = int(round(self.config.fraction * n))
        target, self.target = self.target, math.nan
        if k == 0:
            return 0
        idx = self.rng.choice(n, size=k, replace=False)
        drawn = target * np.exp(self.config.sigma * self.rng.standard_normal(k))
        particles.state[SCALE, idx] = np.clip(drawn, self.config.min_scale, self.config.max_scale)
        self.corrections += 1
        return k
