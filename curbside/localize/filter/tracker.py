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

from curbside.errors import CurbsideInputError, CurbsideValueError
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
from curbside.localize.filter.step_input import (
    check_fix,
    finite,
    real,
    step_displacement,
    time_s,
    valid_fix,
)
from curbside.localize.filter.street_heading import StreetHeadingLikelihood
from curbside.localize.raster import MapRaster, load_or_build_raster
from curbside.osmseg.mapio import MapLayers
from curbside.projection import LocalFrame

logger = logging.getLogger(__name__)

#: A usable fix agrees with the estimate it made when it lies within this many times
#: ``hypot(fix.accuracy_m, r)`` of it, ``r`` the cloud's 68 % radius (``estimate.accuracy_m`` without
#: its outage floor, ``CalibrationConfig.radius_floor_m_per_s``): two 68 % radii, about 4.5 sigma per axis.
FIX_AGREEMENT_RADII = 3.0

# A named tuple from a complete tuple of its fields, without the keyword handling of its constructor
# (half the cost, once per update).
_new_tuple = tuple.__new__


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
    last_fix
        The latest fix that weighed the particles or started them (``None``: none yet).
    last_fix_t
        Time of the latest fix that started the particles, or weighed them and agreed with the estimate
        it made (within :data:`FIX_AGREEMENT_RADII` times the hypotenuse of the fix's accuracy and the
        cloud's 68 % radius);
        ``None``: none yet. See :meth:`seconds_since_fix`.
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
        gnss_config = gnss.config if gnss is not None else GnssConfig()
        #: Fixes reporting a positive accuracy under this are taken to report this (``GnssConfig``).
        self.min_accuracy_m = gnss_config.min_accuracy_m
        #: :meth:`step` starts the tracker only at a fix reporting a better accuracy than this.
        self.max_accuracy_m = gnss_config.max_accuracy_m
        self._smoothed: list[np.ndarray] = []
        self.recoveries = 0
        self.last_estimate: Estimate | None = None
        self.last_fix: GnssFix | None = None
        self.last_fix_t: float | None = None
        self._warned_outside = False
        self._gaps_in_a_row = 0
        # The 68 % radius's floor counts from the later of the last agreeing fix and the last start; the
        # agreement test reads the cloud's radius, without the floor (which would let a drifted cloud
        # agree with the first fix back and drop the floor while it is still far off).
        self._started_t = math.nan
        self._cloud_radius_m = math.nan

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
            likelihood. Each tracker made from map layers holds its own copy of the raster (about
            136 MB for the bundled San Francisco map); trackers of one map (one per walker) share one
            when given another tracker's :attr:`map_raster` (``Tracker.from_config(first.map_raster,
            ...)``: no copy; the raster is only read).
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
        CurbsideValueError
            ``lat`` / ``lon`` not numbers, not finite or out of range (lat in [-90, 90], lon in
            [-180, 180]).
        """
        lat, lon = real(lat, "lat"), real(lon, "lon")
        if not (math.isfinite(lat) and math.isfinite(lon) and -90 <= lat <= 90 and -180 <= lon <= 180):
            raise CurbsideValueError("position", f"lat={lat!r}, lon={lon!r} is not a WGS84 position")
        if self.frame is None:
            self.frame = LocalFrame.around(lon, lat)
        x, y = self.frame.to_xy(lon, lat)
        return float(x), float(y)

    def fix(self, *, lat: float, lon: float, accuracy_m: float | None) -> GnssFix:
        """A :class:`GnssFix` from WGS84 degrees, in this tracker's frame (see :meth:`to_xy`).

        ``accuracy_m`` ``None`` (a phone location without an accuracy), NaN, infinite or not positive
        makes an invalid fix, as the service reads a ``null`` accuracy: it weighs nothing, starts nothing,
        and :meth:`start_at_fix` refuses it.

        Raises
        ------
        CurbsideValueError
            A position :meth:`to_xy` refuses, or an ``accuracy_m`` that is not a number.
        """
        accuracy = math.nan if accuracy_m is None else real(accuracy_m, "accuracy_m")
        return GnssFix(*self.to_xy(lat=lat, lon=lon), accuracy)

    def start_at(self, t: float, *, lat: float, lon: float, heading_offset_rad: float = 0.0) -> Estimate:
        """Start from a known pose given in WGS84 (see :meth:`start_at_pose`).

        Raises
        ------
        CurbsideValueError
            What :meth:`to_xy` and :meth:`start_at_pose` refuse.
        """
        return self.start_at_pose(t, *self.to_xy(lat=lat, lon=lon), heading_offset_rad)

    def start_at_pose(self, t: float, x: float, y: float, heading_offset_rad: float = 0.0) -> Estimate:
        """Start (or start again) around a known pose; a pose in a building moves to the nearest free
        cell, with a warning.

        Raises
        ------
        CurbsideValueError
            A ``t`` that is not seconds (:meth:`step`) or is before the previous update's, a non-finite
            pose, a pose outside the map's extent, or in a building with no free space near.
        """
        t = self._start_time(t)
        x, y = finite(x, "x"), finite(y, "y")
        heading_offset_rad = finite(heading_offset_rad, "heading_offset_rad")
        raster = self.map_raster
        if raster is not None and not bool(raster.contains(x, y)):
            raise CurbsideValueError("start pose", f"({x:.1f}, {y:.1f}) lies outside the map's extent")
        try:
            self.initiator.at_pose(self.particles, x, y, heading_offset_rad)
        except CurbsideInputError as exc:
            raise CurbsideValueError(exc.source, exc.problem) from None
        self._started_t = t
        return self._conclude(t, 0.0)

    def start_at_fix(self, t: float, fix: GnssFix) -> Estimate:
        """Start (or start again) around a valid GNSS fix, the heading offset over the configured spread.

        It starts where it is told, as the engine does at its first usable fix: a fix outside the map's
        extent or less accurate than ``filter.gnss.max_accuracy_m`` is taken (:meth:`step` waits for a
        better one). After the app was stopped, or after a long time without fixes
        (:meth:`seconds_since_fix`), starting again at the next good fix is the way back.

        Raises
        ------
        CurbsideValueError
            A ``t`` that is not seconds or is before the previous update's; ``fix`` not a
            :class:`GnssFix`, or invalid (position not finite, accuracy not positive and finite).
        """
        t = self._start_time(t)
        check_fix(fix, "fix")
        if not valid_fix(fix):
            raise CurbsideValueError("fix", f"cannot start from an invalid fix {fix}")
        fix = self._floored(fix)
        self.initiator.at_fix(self.particles, fix)
        self.last_fix, self.last_fix_t = fix, t
        self._started_t = t
        return self._conclude(t, 0.0)

    def _start_time(self, t: object) -> float:
        """``t`` checked as :meth:`step` does, except that a restart may repeat the last update's time."""
        t = time_s(t)
        last = self.last_estimate
        if last is not None and t < last.t:
            raise CurbsideValueError("t", f"{t!r} is before the previous update's {last.t!r}")
        return t

    # -- one update ---------------------------------------------------------------------------------

    def usable(self, fix: GnssFix | None) -> bool:
        """Whether ``fix`` would weigh the particles (valid, and accurate enough for the GNSS part)."""
        return self.gnss.accepts(fix) if self.gnss is not None else False

    def seconds_since_fix(self, t: float | None = None) -> float:
        """Seconds from the last fix that started the particles or agreed with the estimate
        (:attr:`last_fix_t`) to ``t`` (default: the latest update's time); ``inf`` when there was none.

        It grows while no usable fix comes (a GNSS outage) and while the fixes that come disagree with
        the estimate (a cloud that started at a phone's stale first fix, kilometres off). Either way
        the estimate is dead reckoning: its ``accuracy_m`` and ``segment_prob`` describe the cloud, not
        the walker (docs/filter.md, "From Python, one update at a time", has the app's rule).
        """
        if t is None:
            t = math.nan if self.last_estimate is None else self.last_estimate.t
        return math.inf if self.last_fix_t is None else t - self.last_fix_t

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
            Time of the update, seconds (``|t|`` under 1e10: not milliseconds), after the previous
            update's. Updates more than ``filter.motion.gap_s`` apart say the walker's motion in between
            is unknown: the cloud widens (call at least once a second, with a zero displacement while
            standing, as the engine does).
        velocity_en, dt
            Mean inertial velocity (east, north; m/s) over the step and the step's duration (s; within
            0.1 s + 10 % of ``t`` minus the previous update's ``t``) ...
        displacement_en
            ... or the step's displacement (east, north; metres) directly. Either may move the walker at
            most :data:`MAX_SPEED_MPS` times the time since the previous update, plus
            :data:`STEP_SLACK_M`.
        gnss_fix
            A fix valid at ``t`` (invalid or inaccurate fixes are ignored).

        Returns
        -------
        Estimate or None
            ``None`` while the tracker has not started: no start pose and no fix yet that :meth:`usable`
            would accept (without a GNSS part: valid and more accurate than :attr:`max_accuracy_m`)
            inside the map's extent. The first such fix starts the tracker there.

        Raises
        ------
        CurbsideValueError
            Naming the argument and its value: a ``t`` that is not seconds or not after the previous
            update's; no motion, or a motion that is not an (east, north) pair of finite numbers; a
            ``dt`` not positive or disagreeing with the update times; a motion faster than the bound
            above; a ``gnss_fix`` that is not a :class:`GnssFix`.
        """
        t = time_s(t)
        last = self.last_estimate
        dt_s = math.nan if last is None else t - last.t
        if dt_s <= 0:
            raise CurbsideValueError(
                "t", f"{t!r} is not after the previous update's {last.t!r} (time must increase)"
            )
        dx, dy = step_displacement(velocity_en, dt, displacement_en, dt_s)
        self._note_gap(dt_s)
        if gnss_fix is not None:
            check_fix(gnss_fix, "gnss_fix")
            if 0.0 < gnss_fix.accuracy_m < self.min_accuracy_m:
                gnss_fix = self._floored(gnss_fix)
        if last is None:
            return self.start_at_fix(t, gnss_fix) if self._can_start_at(gnss_fix) else None
        # Once per footstep: attributes are read once into locals (this is most of the update at small N).
        particles, divergence = self.particles, self.divergence
        update = _new_tuple(Update, (t, dt_s, dx, dy, gnss_fix))
        self.predictor.predict(particles, dx, dy, dt_s)
        inject = 0.0 if divergence is None else divergence.observe(particles, update, last)
        if self.scale is not None:
            self.scale.observe(update, last)
        if self.turn is not None:
            self.turn.observe(update, last)
        for likelihood in self.likelihoods:
            likelihood.weigh(particles, update)
        used = gnss_fix is not None and self.usable(gnss_fix)
        if used:
            self.last_fix = gnss_fix
            if self.calibration is not None:
                self.calibration.observe(t, gnss_fix.x - last.x, gnss_fix.y - last.y)
        estimate = self._conclude(t, inject)
        if used and math.hypot(gnss_fix.x - estimate.x, gnss_fix.y - estimate.y) <= FIX_AGREEMENT_RADII * (
            math.hypot(gnss_fix.accuracy_m, self._cloud_radius_m)
        ):
            self.last_fix_t = t
        return estimate

    def _can_start_at(self, fix: GnssFix | None) -> bool:
        """Whether :meth:`step` may start at ``fix``: usable (valid and accurate enough) and inside the
        map's extent (a phone's first fix may be its last known place, kilometres away)."""
        if not valid_fix(fix) or not fix.accuracy_m < self.max_accuracy_m:
            return False
        raster = self.map_raster
        if raster is None or bool(raster.contains(fix.x, fix.y)):
            return True
        if not self._warned_outside:
            logger.warning(
                "a fix at (%.0f, %.0f) lies outside the map's extent: not starting there; waiting for a "
                "fix inside the map (or start_at / start_at_fix)", fix.x, fix.y
            )
            self._warned_outside = True
        return False

    def _note_gap(self, dt_s: float) -> None:
        """Warn once when three updates in a row come a gap apart: a clock in milliseconds, most likely
        (each such update is read as time without motion and widens the cloud)."""
        gap_s = getattr(getattr(self.predictor, "config", None), "gap_s", math.inf)  # custom: no gap rule
        self._gaps_in_a_row = self._gaps_in_a_row + 1 if dt_s > gap_s else 0
        if self._gaps_in_a_row == 3:
            logger.warning(
                "three updates in a row came %.4g s or more apart (the last %.4g s): is t in milliseconds? "
                "step() takes seconds; an update more than filter.motion.gap_s (%g s) after the previous "
                "one is read as a gap and widens the cloud", gap_s, dt_s, gap_s,
            )

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
        accuracy_m = self._accuracy_m(t, m.spread_m)
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
             injected, accuracy_m),
        )
        return estimate

    def _accuracy_m(self, t: float, spread_m: float) -> float:
        """The 68 % radius to report at ``t`` for a cloud of rms spread ``spread_m`` (keeps the cloud's
        own radius, without the floor, for the agreement test)."""
        if self.calibration is None:
            self._cloud_radius_m = accuracy_radius_m(spread_m)
            return self._cloud_radius_m
        since = self._started_t if self.last_fix_t is None else max(self.last_fix_t, self._started_t)
        self._cloud_radius_m, accuracy_m = self.calibration.radius_m(spread_m, t - since)
        return accuracy_m
