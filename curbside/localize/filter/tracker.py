"""The streaming tracker: start it, then call :meth:`Tracker.step` once per update (footstep).

A :class:`Tracker` composes the parts of :mod:`curbside.localize.filter` and runs them in one order at
every update::

    predictor.predict          move every particle by the step's inertial displacement
    divergence.observe         (optional) measure the cloud's agreement with this update's fix, and
                               whether the map holds it still while the phone walks (a stall)
    scale.observe              (optional) fit the recent fixes against the cloud's inertial path
    turn.observe               (optional) the same for a velocity that turned, with its gates
    for each likelihood:       map, GNSS, or any part you add
        likelihood.weigh       add log-likelihoods to the particles' log-weights
    normalise_and_estimate     log-sum-exp normalisation; weighted mean, heading, speed scale, n_eff
    collapse.reseed            only when every weight is zero
    segments.mode              (optional) the MAP sidewalk segment
    calibration.calibrate      (optional) its probability, tempered by how long the fixes' errors last
                               (and the position's 68 % radius widened alike)
    resampler.resample         every update (the paper) or below an ESS threshold
    divergence.inject          (optional) re-draw a fraction of the particles around the fix
    scale.correct              (optional) re-draw a fraction of the speed scales around the fitted one
    turn.correct               (optional) re-draw a fraction of the particles where the fit puts them
    smoother.record            (optional) follow the genealogy; smooth the updates ``lag_s`` old

:meth:`Tracker.from_config` builds the default parts from a :class:`FilterConfig`; the constructor takes
parts directly, and the ``likelihoods`` list may be edited (see ``docs/filter.md``). Batch runs
(:mod:`curbside.localize.engine`) drive the same class as a live app does.
"""

from __future__ import annotations

import logging
import math

import numpy as np
import pyproj

from curbside.errors import CurbsideInputError
from curbside.localize.filter.calibration import SegmentCalibration, accuracy_radius_m
from curbside.localize.filter.config import FilterConfig, GnssConfig, MotionConfig
from curbside.localize.filter.correction_config import ScaleCorrectionConfig
from curbside.localize.filter.gnss import GnssLikelihood
from curbside.localize.filter.heading_correction import HeadingCorrection
from curbside.localize.filter.initiate import Initiator
from curbside.localize.filter.map_likelihood import MapLikelihood
from curbside.localize.filter.particles import Estimate, ParticleSet, normalise_and_estimate
from curbside.localize.filter.parts import GnssFix, Likelihood, Predictor, Resampler, Update
from curbside.localize.filter.predict import InertialPredictor
from curbside.localize.filter.recovery import CollapseRecovery, DivergenceRecovery
from curbside.localize.filter.resample import SystematicResampler
from curbside.localize.filter.scale import ScaleCorrection
from curbside.localize.filter.segments import SegmentEstimator
from curbside.localize.filter.smoother import FixedLagSmoother
from curbside.localize.filter.street_heading import StreetHeadingLikelihood
from curbside.localize.raster import MapRaster, load_or_build_raster
from curbside.osmseg.mapio import MapLayers
from curbside.projection import LocalFrame

logger = logging.getLogger(__name__)

# A named tuple from a complete tuple of its fields, without the keyword handling of its constructor
# (half the cost, once per update).
_new_tuple = tuple.__new__


def _valid_fix(fix: GnssFix | None) -> bool:
    return (
        fix is not None
        and math.isfinite(fix.x)
        and math.isfinite(fix.y)
        and math.isfinite(fix.accuracy_m)
        and fix.accuracy_m > 0
    )


class Tracker:
    """Streaming particle filter assembled from parts (see the module docstring).

    Parameters
    ----------
    particles
        The particle set (its size is N).
    predictor, likelihoods, resampler, initiator, collapse
        The parts run at every update, in the order of the module docstring.
    divergence
        Optional GNSS-driven divergence recovery.
    segments
        Optional sidewalk-segment estimator.
    frame
        Local metric frame; set by the first :meth:`start_at` when ``None``.
    gnss
        The GNSS likelihood among ``likelihoods``, if any: it decides which fixes count.
    scale
        Optional GNSS-driven speed-scale correction.
    smoother
        Optional fixed-lag smoother (its output: :meth:`take_smoothed`).
    turn
        Optional GNSS-driven correction of a velocity that turned (heading, scale and position).
    calibration
        Optional calibration of the MAP segment's probability and of the position's 68 % radius from the
        accepted fixes' innovations.

    Attributes
    ----------
    recoveries
        Number of collapses re-seeded so far.
    last_estimate
        The latest :class:`Estimate` (``None`` before the start).
    """

    def __init__(
        self,
        particles: ParticleSet,
        predictor: Predictor,
        likelihoods: list[Likelihood],
        resampler: Resampler,
        initiator: Initiator,
        collapse: CollapseRecovery,
        divergence: DivergenceRecovery | None = None,
        segments: SegmentEstimator | None = None,
        frame: LocalFrame | None = None,
        gnss: GnssLikelihood | None = None,
        scale: ScaleCorrection | None = None,
        smoother: FixedLagSmoother | None = None,
        turn: HeadingCorrection | None = None,
        calibration: SegmentCalibration | None = None,
    ) -> None:
        self.particles = particles
        self.predictor = predictor
        self.likelihoods = likelihoods
        self.resampler = resampler
        self.initiator = initiator
        self.collapse = collapse
        self.divergence = divergence
        self.segments = segments
        self.frame = frame
        self.gnss = gnss
        self.scale = scale
        self.smoother = smoother
        self.turn = turn
        self.calibration = calibration
        #: Fixes reporting a positive accuracy under this are taken to report this (``GnssConfig``).
        self.min_accuracy_m = (gnss.config if gnss is not None else GnssConfig()).min_accuracy_m
        self._smoothed: list[np.ndarray] = []
        self.recoveries = 0
        self.last_estimate: Estimate | None = None
        self.last_fix: GnssFix | None = None

    @classmethod
    def from_config(
        cls,
        map_layers: MapLayers | MapRaster | None = None,
        config: FilterConfig | None = None,
        seed: int | None = 0,
        frame: LocalFrame | None = None,
        use_gnss: bool = True,
    ) -> Tracker:
        """The default parts for ``config``, one seeded generator shared by all of them.

        Parameters
        ----------
        map_layers
            The map (rasterised once, cached on disk), a built :class:`MapRaster`, or ``None`` for no map
            likelihood.
        config
            Every parameter (default: curbside's fused filter).
        seed
            Same seed and inputs, same estimates.
        frame
            Local metric frame (default: the map's CRS; without a map, set by :meth:`start_at`).
        use_gnss
            Weigh by GNSS fixes (``False``: the inertial-only filter; a fix may still start it).
        """
        config = config or FilterConfig()
        n = int(config.n_particles)
        rng = np.random.default_rng(seed)
        raster = map_layers
        if isinstance(map_layers, MapLayers):
            raster = load_or_build_raster(
                map_layers, config.map.raster_resolution_m, config.map.segment_reach_m
            )
        map_lik = None if raster is None else MapLikelihood(raster, config.map)
        if map_lik is not None:  # the likelihood's raster for every part, so each padded grid is made once
            raster = map_lik.raster
        if frame is None and raster is not None:
            frame = LocalFrame(pyproj.CRS.from_wkt(raster.crs))
        gnss = GnssLikelihood(config.gnss, n, rng, raster) if use_gnss else None
        on_streets = raster is not None and raster.segment_axes is not None
        heading = None
        if config.street_heading.strength_per_m > 0 and on_streets:
            heading = StreetHeadingLikelihood(raster, config.street_heading)
        likelihoods: list[Likelihood] = [lik for lik in (map_lik, heading, gnss) if lik is not None]
        divergence = None
        if gnss is not None and config.recovery.max_fraction > 0:
            divergence = DivergenceRecovery(config.recovery, gnss, rng, map_lik)
        # Built whenever GNSS weighs, idle at fraction 0, so adopt_motion can turn it on mid-walk.
        scale = None if gnss is None else ScaleCorrection(config.scale_correction, gnss, rng)
        segments = None
        if config.segment_estimate and raster is not None and raster.segment_index is not None:
            segments = SegmentEstimator(raster, n)
        smoother = FixedLagSmoother(config.smoother, n) if config.smoother.lag_s > 0 else None
        turn = None
        if gnss is not None and config.heading_correction.fraction > 0:
            turn = HeadingCorrection(config.heading_correction, gnss, rng)
        calibration = None
        if gnss is not None and not config.calibration.identity:
            calibration = SegmentCalibration(config.calibration, n)
        return cls(
            ParticleSet(n),
            InertialPredictor(config.motion, n, rng),
            likelihoods,
            SystematicResampler(config.resample, rng),
            Initiator(config.start, rng, map_lik, config.motion.scale_init_sigma),
            CollapseRecovery(config.recovery, rng, map_lik, config.start.fix_sigma_factor),
            divergence,
            segments,
            frame,
            gnss,
            scale,
            smoother,
            turn,
            calibration,
        )

    # -- starting -----------------------------------------------------------------------------------

    @property
    def started(self) -> bool:
        """Whether the particles have been placed."""
        return self.last_estimate is not None

    @property
    def map_raster(self) -> MapRaster | None:
        """The map raster of the map likelihood (``None`` without a map)."""
        map_lik = self.initiator.map_likelihood
        return None if map_lik is None else map_lik.raster

    @property
    def wall_tolerance_m(self) -> float | None:
        """How soft the map's walls are on this map (m; ``None`` without a map)."""
        map_lik = self.initiator.map_likelihood
        return None if map_lik is None else map_lik.wall_tolerance_m

    @property
    def walkable_first(self) -> bool | None:
        """Whether the map's sidewalks and crosswalks win over its buildings (``None`` without a map)."""
        map_lik = self.initiator.map_likelihood
        return None if map_lik is None else map_lik.walkable_first

    def to_xy(self, *, lat: float, lon: float) -> tuple[float, float]:
        """Metres in this tracker's frame of a WGS84 position (sets the frame when there is none).

        Raises
        ------
        CurbsideInputError
            ``lat`` / ``lon`` not finite or out of range (lat in [-90, 90], lon in [-180, 180]).
        """
        if not (math.isfinite(lat) and math.isfinite(lon) and -90 <= lat <= 90 and -180 <= lon <= 180):
            raise CurbsideInputError("position", f"lat={lat!r}, lon={lon!r} is not a WGS84 position")
        if self.frame is None:
            self.frame = LocalFrame.around(lon, lat)
        x, y = self.frame.to_xy(lon, lat)
        return float(x), float(y)

    def fix(self, *, lat: float, lon: float, accuracy_m: float) -> GnssFix:
        """A :class:`GnssFix` from WGS84 degrees, in this tracker's frame (see :meth:`to_xy`)."""
        return GnssFix(*self.to_xy(lat=lat, lon=lon), float(accuracy_m))

    def start_at(self, t: float, *, lat: float, lon: float, heading_offset_rad: float = 0.0) -> Estimate:
        """Start from a known pose given in WGS84 (see :meth:`start_at_pose`)."""
        return self.start_at_pose(t, *self.to_xy(lat=lat, lon=lon), heading_offset_rad)

    def start_at_pose(self, t: float, x: float, y: float, heading_offset_rad: float = 0.0) -> Estimate:
        """Start around a known pose; a pose in a building moves to the nearest free cell, with a warning.

        Raises
        ------
        CurbsideInputError
            A non-finite pose, a pose outside the map's extent, or in a building with no free space near.
        """
        if not all(math.isfinite(v) for v in (t, x, y, heading_offset_rad)):
            raise CurbsideInputError(
                "start pose", f"not finite: t={t}, x={x}, y={y}, heading={heading_offset_rad}"
            )
        raster = self.map_raster
        if raster is not None and not bool(raster.contains(x, y)):
            raise CurbsideInputError("start pose", f"({x:.1f}, {y:.1f}) lies outside the map's extent")
        self.initiator.at_pose(self.particles, x, y, heading_offset_rad)
        return self._conclude(t, 0.0)

    def start_at_fix(self, t: float, fix: GnssFix) -> Estimate:
        """Start around a GNSS fix (heading offset over the configured spread)."""
        if not _valid_fix(fix):
            raise ValueError(f"cannot start from an invalid fix {fix}")
        fix = self._floored(fix)
        self.initiator.at_fix(self.particles, fix)
        self.last_fix = fix
        return self._conclude(t, 0.0)

    # -- one update ---------------------------------------------------------------------------------

    def usable(self, fix: GnssFix | None) -> bool:
        """Whether ``fix`` would weigh the particles (valid, and accurate enough for the GNSS part)."""
        return self.gnss.accepts(fix) if self.gnss is not None else False

    def adopt_motion(self, motion: MotionConfig, scale_correction: ScaleCorrectionConfig) -> None:
        """From the next update on, move with ``motion``'s noise and correct the speed scale by
        ``scale_correction`` (the switch to a velocity model's unseen-place motion model, mid-walk)."""
        self.predictor.config = motion
        if self.scale is not None:
            self.scale.config = scale_correction

    def step(
        self,
        t: float,
        velocity_en: tuple[float, float] | np.ndarray | None = None,
        dt: float | None = None,
        displacement_en: tuple[float, float] | np.ndarray | None = None,
        gnss_fix: GnssFix | None = None,
    ) -> Estimate | None:
        """Advance the filter by one update.

        Parameters
        ----------
        t
            Time of the update, seconds.
        velocity_en, dt
            Mean inertial velocity (east, north; m/s) over the step and the step's duration (s) ...
        displacement_en
            ... or the step's displacement (east, north; metres) directly.
        gnss_fix
            A fix valid at ``t`` (invalid or inaccurate fixes are ignored).

        Returns
        -------
        Estimate or None
            ``None`` while the tracker has not started (no start pose and no valid fix yet); a valid fix
            before the start starts the tracker there.
        """
        if displacement_en is not None:
            dx, dy = float(displacement_en[0]), float(displacement_en[1])
        elif velocity_en is not None and dt is not None:
            dx, dy = float(velocity_en[0]) * dt, float(velocity_en[1]) * dt
        else:
            raise ValueError("step() needs velocity_en and dt, or displacement_en")
        if not (math.isfinite(dx) and math.isfinite(dy) and math.isfinite(t)):
            raise ValueError(f"non-finite inertial displacement ({dx}, {dy}) or time at t={t}")
        if gnss_fix is not None and 0.0 < gnss_fix.accuracy_m < self.min_accuracy_m:
            gnss_fix = self._floored(gnss_fix)
        last = self.last_estimate
        if last is None:
            return self.start_at_fix(t, gnss_fix) if _valid_fix(gnss_fix) else None
        # Once per footstep: attributes are read once into locals (this is most of the update at small N).
        particles, divergence = self.particles, self.divergence
        update = _new_tuple(Update, (t, t - last.t, dx, dy, gnss_fix))
        self.predictor.predict(particles, dx, dy)
        inject = 0.0 if divergence is None else divergence.observe(particles, update, last)
        if self.scale is not None:
            self.scale.observe(update, last)
        if self.turn is not None:
            self.turn.observe(update, last)
        for likelihood in self.likelihoods:
            likelihood.weigh(particles, update)
        if gnss_fix is not None and self.usable(gnss_fix):
            self.last_fix = gnss_fix
            if self.calibration is not None:
                self.calibration.observe(t, gnss_fix.x - last.x, gnss_fix.y - last.y)
        return self._conclude(t, inject)

    def _floored(self, fix: GnssFix) -> GnssFix:
        """``fix`` with its accuracy raised to :attr:`min_accuracy_m` when it reports less (not 0:
        invalid stays invalid)."""
        if 0.0 < fix.accuracy_m < self.min_accuracy_m:
            return fix._replace(accuracy_m=self.min_accuracy_m)
        return fix

    def take_smoothed(self, final: bool = False) -> np.ndarray:
        """The fixed-lag smoother's positions made since the last call, oldest first.

        Parameters
        ----------
        final
            The data have ended: also smooth the updates younger than the lag.

        Returns
        -------
        numpy.ndarray
            ``(m, 3)`` rows ``t, x, y``, one per update in the order the updates were made; empty
            without a smoother.
        """
        if self.smoother is not None and final:
            self._smoothed.append(self.smoother.flush(self.particles))
        out = np.concatenate(self._smoothed) if self._smoothed else np.empty((0, 3))
        self._smoothed.clear()
        return out

    def _conclude(self, t: float, inject_fraction: float) -> Estimate:
        """Normalise, recover from a collapse, estimate, resample, inject."""
        p, segments = self.particles, self.segments
        m = normalise_and_estimate(p)
        collapsed = not m.ok
        if collapsed:
            self.recoveries += 1
            logger.debug("particle cloud collapsed at t=%.2f s: re-seeded (%d so far)", t, self.recoveries)
            last = self.last_estimate
            self.collapse.reseed(p, None if last is None else (last.x, last.y), self.last_fix)
            m = normalise_and_estimate(p)
        segment_id, prob, mode_x, mode_y = None, 0.0, m.x, m.y
        if segments is not None:
            mode = segments.mode(p)
            if mode.segment >= 0:
                segment_id, prob = segments.segment_id(mode.segment), mode.prob
                if self.calibration is not None:
                    prob = self.calibration.calibrate(prob)
                mode_x, mode_y = mode.x, mode.y
        temperature = 1.0 if self.calibration is None else self.calibration.temperature
        resampled = self.resampler.resample(p, m.n_eff)
        injected = 0
        if inject_fraction > 0:
            injected = self.divergence.inject(p, self.last_fix, inject_fraction)
        if self.scale is not None:
            self.scale.correct(p)
        if self.turn is not None:
            self.turn.correct(p)
        if self.smoother is not None:
            self._smoothed.append(self.smoother.record(t, p, resampled))
        self.last_estimate = estimate = _new_tuple(
            Estimate,
            (t, m.x, m.y, m.theta, m.scale, m.n_eff, collapsed, self.frame, segment_id, prob, mode_x, mode_y,
             injected, accuracy_radius_m(m.spread_m, temperature)),
        )
        return estimate
