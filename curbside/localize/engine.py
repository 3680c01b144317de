"""The tracking engine: a session's streams in, filter updates out, the same for a file as for a live feed.

:class:`SessionEngine` takes a session's rows as they come (``push``: IMU, velocity, footsteps, GNSS,
in chunks of any size), turns them into updates of a :class:`~curbside.localize.filter.Tracker`, and
returns each estimate as soon as every input it depends on is final (``advance``); ``finish`` flushes
the tail. ``localize run`` pushes whole files and finishes; the live service pushes a few rows per
request. Because an update is only made once its inputs are final, both give the same track. With a
fixed-lag smoother (``filter.smoother.lag_s``) each row's ``smooth_x, smooth_y`` are filled in
``lag_s`` later, and the last ones by ``finish``.

When the filter updates:

- at every footstep (the paper), and
- when no footstep has come for ``max_update_interval_s``, on that time grid (a detector that misses
  steps, or a walker standing at a crossing, never leaves a stretch untracked). With
  ``engine.standing_speed_mps``, such an update whose inertial speed is under that bound is a walker
  standing still: the velocity model's drift while the phone is handled moves no particle.

With ``unseen_velocity.mode = on`` the filter moves with the preset for a velocity model new to the
phone or the place (:class:`~curbside.localize.runconfig.UnseenVelocityConfig`) from the start; with
``auto``, from the update at which the model is caught reading motion while the walker stands: the
median inertial speed of the first ``still_updates`` time-grid updates slower than the preset's
standing bound, ``settle_s`` or more after the last footstep, is at least ``still_speed_mps``. Each
update is decided from inputs before it, so a file and a live feed switch at the same update
(:attr:`SessionEngine.unseen_since_t`).

With ``familiar_velocity.mode = auto`` (opt-in) a second tracker, moving with the calm motion model of
:class:`~curbside.localize.runconfig.FamiliarVelocityConfig`, takes the same updates from the start
(:attr:`SessionEngine.shadow`); the track follows it while the velocity's speed reads smooth from one
half-second window to the next (:class:`~curbside.localize.velocity_checks.SpeedJitterCheck`, fed with
the velocity up to each update), and once the test's verdict is final the other tracker is dropped. A
model caught reading motion at a standstill is not familiar: the unseen-velocity switch drops the calm
tracker. Each row says which motion model its estimate came from (:attr:`Row.motion`).

With a fix lag (``fix_lag``, opt-in; a batch run under ``auto`` estimates it from the recording), each
fix is moved forward by the inertial motion that lag holds back before it reaches the filter
(:class:`~curbside.localize.fix_lag.LagCompensator`).

The first update is the start: the known start pose (``meta.json``) at its time, with the heading
offset that turns the first ``heading_align_distance_m`` of inertial motion onto the start heading; or,
without one, the first update time whose fix is usable. At each update the inertial displacement since
the previous update and the fix chosen by the association rule go to :meth:`Tracker.step`.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from curbside.errors import CurbsideInputError
from curbside.localize.filter.particles import SCALE, THETA, X, Y
from curbside.localize.filter.tracker import Tracker
from curbside.localize.fix_lag import LagCompensator
from curbside.localize.particle_recorder import CloudRecorder
from curbside.localize.raster import MapRaster
from curbside.localize.runconfig import RunConfig
from curbside.localize.streams import DisplacementIntegrator, FixStore, StepTimes
from curbside.localize.velocity_checks import SpeedJitterCheck, StillSpeedCheck
from curbside.projection import LocalFrame

logger = logging.getLogger(__name__)


@dataclass
class Row:
    """One update of the track: the estimate and how the update came about.

    Attributes
    ----------
    kind
        ``start``, ``step`` (a footstep) or ``time`` (no footstep for ``max_update_interval_s``).
    fix_used
        Whether a GNSS fix weighed the particles at this update.
    motion
        The motion model of the filter whose estimate this is: ``default`` (the method's own),
        ``familiar`` (the familiar-velocity calm model) or ``unseen`` (the unseen-velocity model); empty
        in ``gnss`` mode.
    smooth_x, smooth_y
        The fixed-lag smoother's position (NaN without one, or until it is made).
    accuracy_m
        Radius around ``x, y`` that holds the walker 68 % of the time (the fix's reported accuracy in
        ``gnss`` mode), metres.
    """

    t: float
    x: float
    y: float
    kind: str
    fix_used: bool = False
    theta: float = math.nan
    scale: float = math.nan
    n_eff: float = math.nan
    recovered: bool = False
    injected: int = 0
    segment_id: str | None = None
    segment_prob: float = math.nan
    mode_x: float = math.nan
    mode_y: float = math.nan
    smooth_x: float = math.nan
    smooth_y: float = math.nan
    motion: str = ""
    accuracy_m: float = math.nan


@dataclass
class StartPose:
    """A known start: WGS84 position, heading clockwise from north (degrees), and its time if known."""

    lat: float
    lon: float
    heading_deg: float
    t: float | None = None


@dataclass
class _State:
    started: bool = False
    prev_t: float = -math.inf
    prev_d: np.ndarray = field(default_factory=lambda: np.zeros(2))
    finished: bool = False
    clock: float = -math.inf
    smoothed_rows: int = 0
    last_step_t: float = -math.inf


class SessionEngine:
    """Streams of one session -> updates of one tracker (see the module docstring).

    Parameters
    ----------
    config
        Method, seed, filter and engine parameters.
    frame
        The local metric frame (the map's).
    raster
        The map raster, ``None`` for no map likelihood.
    start
        Known start pose (used when ``config.use_start_pose``), or ``None``.
    t_begin
        Updates start at or after this time (the start pose's time, when the walk began).
    cadence
        Footsteps come from a fixed cadence (no step file and no IMU).
    save_particles
        Pack the particles' ``x, y, theta, scale`` and weights at each update, around its estimate, into
        :attr:`snapshots` (a :class:`~curbside.localize.particle_recorder.CloudRecorder`).
    spill_dir
        Where :attr:`snapshots` keeps the clouds on disk as the walk goes (default: the system's
        temporary folder; see :class:`~curbside.localize.particle_recorder.CloudRecorder`).
    step_means_velocity
        The velocity rows are per-step means (PDR), not samples (see
        :class:`~curbside.localize.streams.DisplacementIntegrator`).
    fix_lag_s
        The fixes' lag to compensate (s; see :mod:`curbside.localize.fix_lag`); ``None``: ``fix_lag.lag_s``
        unless ``fix_lag.mode`` is ``off`` (a batch run passes its estimate).
    """

    def __init__(
        self,
        config: RunConfig,
        frame: LocalFrame,
        raster: MapRaster | None = None,
        *,
        start: StartPose | None = None,
        t_begin: float | None = None,
        cadence: bool = False,
        save_particles: bool = False,
        step_means_velocity: bool = False,
        fix_lag_s: float | None = None,
        spill_dir: str | Path | None = None,
    ) -> None:
        self.config = config
        self.frame = frame
        real_steps = not (cadence or step_means_velocity)
        unseen = config.unseen_velocity.mode
        #: Time from which the unseen-velocity preset applies (``-inf``: from the start; ``None``: not).
        self.unseen_since_t: float | None = -math.inf if unseen == "on" else None
        familiar = "off" if unseen == "on" else config.familiar_velocity.mode
        if unseen == "on":
            config = config.with_unseen_velocity()
        e = config.engine
        #: The filter whose estimates make the track (``None`` in ``gnss`` mode) ...
        self.tracker: Tracker | None = None
        #: ... and, while the familiar-velocity test runs, the other one (both step at every update).
        self.shadow: Tracker | None = None
        #: Whether :attr:`tracker` moves with the familiar-velocity (calm) motion model.
        self.familiar_output = familiar == "on"
        #: The familiar-velocity test (``auto``; kept after its verdict for the record).
        self.familiar_check: SpeedJitterCheck | None = None
        if config.mode != "gnss":
            self.tracker = self._new_tracker(config.with_familiar_velocity() if familiar == "on" else config,
                                             raster)
            if familiar == "auto" and not step_means_velocity:
                self.shadow = self._new_tracker(config.with_familiar_velocity(), raster)
        self._still_check = None
        if unseen == "auto" and real_steps and self.tracker is not None:
            self._still_check = StillSpeedCheck(config.unseen_velocity)
        self.start = start if config.use_start_pose else None
        self.t_begin = -math.inf if t_begin is None else float(t_begin)
        self.displacement = DisplacementIntegrator(e.velocity_max_gap_s, step_means_velocity)
        #: Below this inertial speed, a time-grid update is standing (needs real footsteps).
        self.standing_speed = e.standing_speed_mps if real_steps else 0.0
        self.steps = StepTimes(e.cadence_s if cadence else None)
        self.fixes = FixStore(e.fix_association, e.interp_max_gap_s, e.max_fix_age_s)
        if fix_lag_s is None:
            fix_lag_s = 0.0 if config.fix_lag.mode == "off" else config.fix_lag.lag_s
        #: Moves each fix forward by the inertial motion its lag holds back (``None``: no lag).
        self.lag = LagCompensator(fix_lag_s) if fix_lag_s > 0 and self.tracker is not None else None
        self.rows: list[Row] = []
        self.snapshots: CloudRecorder | None = None
        if save_particles:
            self.snapshots = CloudRecorder(frame.crs.to_wkt(), spill_dir=spill_dir)
        self._s = _State()

    def _new_tracker(self, config: RunConfig, raster: MapRaster | None) -> Tracker:
        return Tracker.from_config(
            raster, config.filter, config.seed, self.frame, use_gnss=config.mode in ("paper", "fused")
        )

    # -- input ------------------------------------------------------------------------------------

    def push_velocity(self, t: np.ndarray, velocity_en: np.ndarray) -> None:
        """World-frame velocity rows (m/s east, north)."""
        self.displacement.push(t, velocity_en)
        self._tick(t)

    def push_steps(self, t: np.ndarray, complete_until: float) -> None:
        """Footstep times, and the time up to which every step has been reported."""
        self.steps.push(t, complete_until)
        self._tick(t)

    def push_gnss(self, gnss: pd.DataFrame) -> None:
        """Fixes ``t, lat, lon, accuracy_m`` (invalid ones are ignored)."""
        if gnss is None or len(gnss) == 0:
            return
        x, y = self.frame.to_xy(gnss["lon"].to_numpy(float), gnss["lat"].to_numpy(float))
        self.fixes.push(
            gnss["t"].to_numpy(float), np.atleast_1d(x), np.atleast_1d(y), gnss["accuracy_m"].to_numpy(float)
        )
        self._tick(gnss["t"].to_numpy(float))

    def _tick(self, t: np.ndarray) -> None:
        t = np.asarray(t, float)
        if len(t):
            self._s.clock = max(self._s.clock, float(t[-1]))
            if self.steps.cadence_s is not None:
                first = self.t_begin if math.isfinite(self.t_begin) else float(t[0])
                self.steps.extend_cadence(first, self._s.clock)

    # -- output -----------------------------------------------------------------------------------

    def advance(self) -> list[Row]:
        """Make every update whose inputs are final; return the new rows."""
        n0 = len(self.rows)
        while self._advance_once():
            pass
        return self.rows[n0:]

    def finish(self) -> list[Row]:
        """All inputs are in: make the remaining updates; return the new rows."""
        self._s.finished = True
        self.steps.complete_until = math.inf
        rows = self.advance()
        if self.tracker is not None and self.tracker.smoother is not None:
            self._fill_smoothed(self.tracker.take_smoothed(final=True))
        return rows

    @property
    def unseen_velocity_from_s(self) -> float | None:
        """Time of the first update with the unseen-velocity motion model (``None``: none had it)."""
        if self.unseen_since_t is None or not self.rows:
            return None
        return max(self.unseen_since_t, self.rows[0].t)

    @property
    def motion(self) -> str:
        """The motion model of :attr:`tracker` now (see :attr:`Row.motion`)."""
        if self.familiar_output:
            return "familiar"
        return "default" if self.unseen_since_t is None else "unseen"

    @property
    def familiar_velocity(self) -> dict[str, object] | None:
        """The familiar-velocity test's record (``None`` when it did not run): the median relative speed
        change and the number of samples it saw, and its verdict (``familiar``, ``not familiar``, or
        ``undecided`` when the walk ended first or the unseen-velocity test spoke first)."""
        check = self.familiar_check
        if check is None:
            return None
        verdict = {True: "familiar", False: "not familiar", None: "undecided"}[check.final]
        median = check.median_jitter
        return {
            "median_speed_change": None if math.isnan(median) else round(median, 4),
            "samples": len(check.samples),
            "verdict": verdict,
        }

    def no_estimate_problem(self) -> str:
        """Why a finished run made no update: nothing to start from, or a recording that ends first."""
        fixes = self.fixes.fixes.rows()
        usable = fixes[fixes[:, 3] < self.config.filter.gnss.max_accuracy_m, 0]
        if self.start is None and not len(usable):
            return NO_START
        if self.tracker is None or not math.isfinite(self.displacement.first_t):
            return NO_START
        anchor = f"the first usable fix (t = {usable[0]:.1f} s)" if self.start is None else "the start pose"
        return (f"no estimate: the recording is too short: its inertial data covers only t = "
                f"{self.displacement.first_t:.1f}-{self.displacement.complete_until:.1f} s, too little to "
                f"start from {anchor} and make an update")

    @property
    def data_end(self) -> float:
        """The last time updates can be made for (velocity known; the GNSS span in ``gnss`` mode)."""
        if self.tracker is None:
            return self._s.clock
        return self.displacement.complete_until

    def _ready(self, t: float) -> bool:
        s = self._s
        if t > self.data_end and (s.finished or self.tracker is None):
            return False
        if s.finished:
            return True
        velocity_ok = self.tracker is None or self.displacement.complete_until >= t
        return velocity_ok and s.clock >= t + self.config.engine.fix_lookahead_s

    def _next_time(self) -> tuple[float, str] | None:
        """The next update time and kind after the previous update, once it can be decided."""
        prev = self._s.prev_t
        fill = prev + self.config.engine.max_update_interval_s
        step = self.steps.next_after(prev)
        if step <= fill:
            return step, "step"
        if self.steps.complete_until >= fill:
            return fill, "time"
        return None

    def _advance_once(self) -> bool:
        if not self._s.started:
            return self._try_start()
        nxt = self._next_time()
        if nxt is None or not self._ready(nxt[0]):
            return False
        self._update(*nxt)
        return True

    # -- the start ----------------------------------------------------------------------------------

    def _first_time(self) -> float | None:
        """The first candidate update time (``t_begin`` or the data's start)."""
        if math.isfinite(self.t_begin):
            return self.t_begin
        firsts = [self.displacement.first_t, self.steps.next_after(-math.inf)]
        fixes = self.fixes.fixes.rows()
        if len(fixes):
            firsts.append(float(fixes[0, 0]))
        firsts = [f for f in firsts if math.isfinite(f)]
        return min(firsts) if firsts else None

    def _next_candidate(self) -> float | None:
        """Before the start: the next time at which the filter could start."""
        if self._s.prev_t == -math.inf:
            return self._first_time()
        nxt = self._next_time()
        return None if nxt is None else nxt[0]

    def _try_start(self) -> bool:
        s = self._s
        if self.start is not None and self.tracker is not None:
            return self._start_at_pose()
        t = self._next_candidate()
        if t is None or not self._ready(t):
            return False
        s.prev_t = t
        fix = self.fixes.at(t, hold_forever=self.tracker is None)
        if fix is None or fix.accuracy_m >= self.config.filter.gnss.max_accuracy_m:
            return True  # no usable fix here: try the next candidate
        if self.tracker is None:
            self._record(Row(t, fix.x, fix.y, "start", True, accuracy_m=fix.accuracy_m))
        else:
            if self.shadow is not None:
                self.shadow.start_at_fix(t, fix)
            self._record_estimate(self.tracker.start_at_fix(t, fix), "start", True)
            s.prev_d = self.displacement.at(t)
            self._begin_familiar_test(t, s.prev_d)
        s.started = True
        return True

    def _start_at_pose(self) -> bool:
        """Start at the known pose once the heading alignment can be decided."""
        s, start = self._s, self.start
        t0 = self._first_time()
        if t0 is None:
            return False
        offset = self._heading_offset(t0, start.heading_deg)
        if offset is None:
            return False
        x, y = self.frame.to_xy(start.lon, start.lat)
        estimate = self.tracker.start_at_pose(t0, float(x), float(y), offset)
        if self.shadow is not None:
            self.shadow.start_at_pose(t0, float(x), float(y), offset)
        self._record_estimate(estimate, "start", False)
        s.prev_t, s.prev_d, s.started = t0, self.displacement.at(t0), True
        self._begin_familiar_test(t0, s.prev_d)
        return True

    def _begin_familiar_test(self, t0: float, d0: np.ndarray) -> None:
        if self.shadow is not None:
            self.familiar_check = SpeedJitterCheck(self.config.familiar_velocity, t0, d0)

    def _heading_offset(self, t0: float, heading_deg: float) -> float | None:
        """Offset turning the first motion after ``t0`` onto ``heading_deg``; ``None`` until decidable."""
        knots = self.displacement.knots.rows()
        d0 = self.displacement.at(t0)
        later = knots[knots[:, 0] >= t0]
        far = (
            np.hypot(later[:, 1] - d0[0], later[:, 2] - d0[1]) >= self.config.engine.heading_align_distance_m
        )
        if far.any():
            first = later[int(np.argmax(far)), 1:] - d0
        elif self._s.finished:
            if len(later) == 0 or np.hypot(*(later[-1, 1:] - d0)) < 0.5:
                logger.warning(
                    "no inertial motion to align with the start heading: heading offset starts at 0"
                )
                return 0.0
            first = later[-1, 1:] - d0
        else:
            return None
        offset = math.pi / 2 - math.radians(heading_deg) - math.atan2(first[1], first[0])
        return math.atan2(math.sin(offset), math.cos(offset))

    # -- one update ---------------------------------------------------------------------------------

    def _update(self, t: float, kind: str) -> None:
        s = self._s
        hold = self.tracker is None
        fix = self.fixes.at(t, hold_forever=hold)
        if self.tracker is None:
            if fix is not None:
                self._record(Row(t, fix.x, fix.y, kind, True, accuracy_m=fix.accuracy_m))
        else:
            d = self.displacement.at(t)
            if self.lag is not None:
                ahead = self.lag.offset(t, d)
                if fix is not None:
                    fix = fix._replace(x=fix.x + ahead[0], y=fix.y + ahead[1])
            moved = d - s.prev_d
            speed = math.hypot(*moved) / max(t - s.prev_t, 1e-9)
            if kind == "time" and speed < self.standing_speed:
                moved = np.zeros(2)  # no footstep and hardly any inertial speed: standing
            use = fix if self.config.mode in ("paper", "fused") else None
            estimate = self.tracker.step(t, displacement_en=moved, gnss_fix=use)
            if self.shadow is not None:
                other = self.shadow.step(t, displacement_en=moved, gnss_fix=use)
                if self._follow_familiar(t):
                    estimate = other
            self._record_estimate(estimate, kind, self.tracker.usable(use))
            s.prev_d = d
            if kind == "step":
                s.last_step_t = t
            elif self._still_check is not None and self._still_check.caught(speed, t - s.last_step_t):
                self._switch_to_unseen_velocity(t, self._still_check.median_mps)
        s.prev_t = t
        self.displacement.forget_before(t)
        self.steps.forget_before(t)
        self.fixes.forget_before(t - self.config.engine.max_fix_age_s)

    def _follow_familiar(self, t: float) -> bool:
        """Feed the familiar-velocity test with the velocity up to ``t``; make :attr:`tracker` the filter it
        says (``True`` when that swapped the two), and drop the other once the verdict is final."""
        check = self.familiar_check
        check.observe(self.displacement.at, t)
        swap = check.smooth != self.familiar_output
        if swap:
            self.tracker, self.shadow = self.shadow, self.tracker
            self.familiar_output = not self.familiar_output
            logger.info(
                "t=%.1f s: the velocity's speed changes by %.1f %% from one %.1f s window to the next "
                "(median of %d): the track follows the %s motion model (familiar_velocity.mode = auto)",
                t, 100 * check.median_jitter, check.config.window_s, len(check.samples),
                "calm" if self.familiar_output else "default",
            )
        if check.final is not None:
            self.shadow = None  # the verdict: keep the filter that makes the track
        return swap

    def _switch_to_unseen_velocity(self, t: float, still_speed_mps: float) -> None:
        if self.shadow is not None:  # a model caught reading motion at a standstill is not familiar
            if self.familiar_output:
                self.tracker = self.shadow
            self.shadow = None
        self.familiar_output = False
        unseen = self.config.with_unseen_velocity()
        self.tracker.adopt_motion(unseen.filter.motion, unseen.filter.scale_correction)
        self.standing_speed = unseen.engine.standing_speed_mps
        self.unseen_since_t = t
        logger.info(
            "t=%.1f s: the velocity model reads %.2f m/s while no footstep comes: from here on, the motion "
            "model for a velocity model new to the phone or the place (unseen_velocity.mode = auto)",
            t,
            still_speed_mps,
        )

    def _record_estimate(self, e, kind: str, fix_used: bool) -> None:
        prob = e.segment_prob if self.tracker.segments is not None else math.nan
        self._record(
            Row(
                e.t,
                e.x,
                e.y,
                kind,
                fix_used,
                e.theta,
                e.scale,
                e.n_eff,
                e.recovered,
                e.injected,
                e.segment_id,
                prob,
                e.mode_x,
                e.mode_y,
                motion=self.motion,
                accuracy_m=e.accuracy_m,
            )
        )
        if self.snapshots is not None:
            state, weights = self.tracker.particles.state, self.tracker.particles.weights
            self.snapshots.add(e.t, e.x, e.y, state[X], state[Y], state[THETA], state[SCALE], weights)
        if self.tracker.smoother is not None:
            self._fill_smoothed(self.tracker.take_smoothed())
        if self.shadow is not None and self.shadow.smoother is not None:
            self.shadow.take_smoothed()  # kept in step, so that a swap hands over the next update's

    def _fill_smoothed(self, smoothed: np.ndarray) -> None:
        """Give the rows, in order, the fixed-lag smoother's positions (one per tracker update)."""
        k = self._s.smoothed_rows
        for _, x, y in smoothed:
            self.rows[k].smooth_x, self.rows[k].smooth_y = float(x), float(y)
            k += 1
        self._s.smoothed_rows = k

    def _record(self, row: Row) -> None:
        self.rows.append(row)


NO_START = "no estimate: no start pose and no usable GNSS fix to start from"


def require_rows(engine: SessionEngine | None, name: str) -> None:
    """Raise the one-line input error of a run that produced no estimate (``engine`` ``None``: none was
    made, for want of a fix to set the frame)."""
    if engine is None:
        raise CurbsideInputError(name, NO_START)
    if not engine.rows:
        raise CurbsideInputError(name, engine.no_estimate_problem())
