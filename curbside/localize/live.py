"""One live session: IMU and GNSS rows in as they come, the track out, the same as ``localize run``.

A :class:`LiveSession` owns the three streaming stages of one walker, the same ones the batch command
runs over a whole recording:

- :class:`~curbside.localize.ronin.stream.RoninStream` cuts the IMU into RoNIN windows; the caller runs
  the windows of *all* its sessions through the model in fixed-shape batches
  (:func:`~curbside.localize.ronin.infer.infer_windows`, bit-identical whatever shares a batch) and
  hands each session its velocities back (:meth:`LiveSession.push_velocity`);
- :class:`~curbside.localize.steps.StepDetector` finds the footsteps;
- :class:`~curbside.localize.engine.SessionEngine` makes a filter update once its inputs are final.

Each stage gives the same output however its input is chunked, so a session streamed in small
batches gives the track that :func:`~curbside.localize.pipeline.track_session` gives for the whole
recording with the same configuration and seed (``tests/test_serve.py`` checks it end to end).

**When fixes may arrive.** The engine treats every fix up to its clock (the latest velocity, footstep
or fix time it has been given) as known. A live session therefore hands velocities and footsteps to
the engine only up to ``fix_delay_s`` before the latest row received on either stream: a fix may
arrive up to ``fix_delay_s`` (default 1 s) after the IMU rows of its time. A fix that comes later than
that is dropped with a warning (using it would make the live track differ from the batch one).

**Validation**: :mod:`curbside.localize.live_input` (a batch that fails changes nothing).
"""

from __future__ import annotations

import logging
import math
from typing import TYPE_CHECKING

import numpy as np
import pandas as pd

from curbside.errors import CurbsideInputError
from curbside.localize.engine import Row, SessionEngine, StartPose, require_rows
from curbside.localize.live_input import (
    GNSS_COLUMNS,
    IMU_COLUMNS,
    IMU_QUAT_COLUMNS,
    LiveLimits,
    accel_norms,
    check_gnss,
    check_imu,
    check_time_value,
)
from curbside.localize.raster import MapRaster, load_or_build_raster
from curbside.localize.ronin.stream import InferenceQueue, RoninStream, RoninStreamConfig
from curbside.localize.runconfig import RunConfig
from curbside.localize.session import Session
from curbside.localize.steps import StepDetector
from curbside.localize.track_result import TrackResult, track_table, tracker_record
from curbside.osmseg.mapio import MapLayers
from curbside.projection import LocalFrame

if TYPE_CHECKING:
    from curbside.localize.ronin.model import RoninResNet

logger = logging.getLogger(__name__)

#: The fixes' column index, made once: building one per batch costs more than the batch's numbers.
_GNSS_INDEX = pd.Index(GNSS_COLUMNS, dtype=object)


class LiveSession:
    """One walker's streams to estimates (see the module docstring).

    Parameters
    ----------
    config
        The run configuration (mode, seed, filter, engine), as ``localize run`` takes it.
    map_layers, raster
        The map and its raster (``None`` for no map likelihood); the raster is shared, read-only.
    start
        Known start pose, or ``None``.
    limits
        Input bounds and the fix delay.
    name
        Used in log messages.

    Raises
    ------
    CurbsideInputError
        A velocity or footstep source a live session cannot have (``file``, ``pdr``), or a start pose
        outside the map or at a time that is not seconds
        (:func:`~curbside.localize.live_input.check_time_value`).
    """

    def __init__(
        self,
        config: RunConfig,
        map_layers: MapLayers | None = None,
        raster: MapRaster | None = None,
        *,
        start: StartPose | None = None,
        limits: LiveLimits | None = None,
        name: str = "live",
    ) -> None:
        e = config.engine
        if config.mode != "gnss" and e.velocity_source not in ("auto", "ronin"):
            raise CurbsideInputError(
                "engine.velocity_source", f"{e.velocity_source!r} is not available live; use auto or ronin"
            )
        if e.step_source not in ("auto", "detect", "cadence"):
            raise CurbsideInputError(
                "engine.step_source", f"{e.step_source!r} is not available live; use auto, detect or cadence"
            )
        if start is not None and start.t is not None:
            check_time_value(start.t, "start.t")
        self.config = config
        self.map_layers = map_layers
        self.raster = raster if config.mode != "gnss" else None
        self.start = start
        self.limits = limits or LiveLimits()
        self.name = name
        self.velocity_source = None if config.mode == "gnss" else "ronin"
        self.step_source = "cadence" if e.step_source == "cadence" else "detected"
        self.ronin = RoninStream(source=f"{name} imu") if self.velocity_source else None
        self.steps = StepDetector() if self.step_source == "detected" else None
        self._extent = None if map_layers is None else tuple(map_layers.gdf.total_bounds)
        self.frame = self._initial_frame()
        self.engine: SessionEngine | None = None
        self.imu_columns: tuple[str, ...] | None = None
        self.last_imu_t = -math.inf
        self.last_gnss_t = -math.inf
        self.first_t = math.inf  # the first row's time, either stream
        self._recent_norms = np.zeros(0)  # |a| of the latest IMU rows, for the gravity check
        self._usable_fixes = self._unusable_fixes = 0
        self.finished = False
        #: Why the session cannot go on (its IMU stream proved unusable), or ``None``.
        self.failed: str | None = None
        self._released_until = -math.inf
        self._windows_out = self._velocities_in = 0
        self._tail_taken = False
        self._velocity: list[np.ndarray] = []  # (t, ve, vn) rows inferred, not yet given to the engine
        self._step_times: list[np.ndarray] = []
        self._gnss: list[np.ndarray] = []  # fixes held until the engine exists
        if self.frame is not None:
            self._make_engine()

    # -- set-up -------------------------------------------------------------------------------------

    def _initial_frame(self) -> LocalFrame | None:
        import pyproj

        if self.map_layers is not None:
            frame = LocalFrame(pyproj.CRS(self.map_layers.crs))
            if self.start is not None and self.config.use_start_pose:
                x, y = frame.to_xy(self.start.lon, self.start.lat)
                xmin, ymin, xmax, ymax = self._extent
                if not (xmin <= x <= xmax and ymin <= y <= ymax):
                    raise CurbsideInputError(
                        "start", f"({self.start.lat:.6f}, {self.start.lon:.6f}) lies outside the map's extent"
                    )
            return frame
        if self.start is not None:
            return LocalFrame.around(self.start.lon, self.start.lat)
        return None  # chosen at the first fix

    def _make_engine(self) -> None:
        self.engine = SessionEngine(
            self.config,
            self.frame,
            self.raster,
            start=self.start,
            t_begin=None if self.start is None else self.start.t,
            cadence=self.steps is None,
        )

    # -- input --------------------------------------------------------------------------------------

    def push(
        self,
        imu: np.ndarray | None = None,
        gnss: np.ndarray | None = None,
        imu_columns: tuple[str, ...] = IMU_COLUMNS,
    ) -> list[str]:
        """Validate a batch, then feed it in; nothing changes when it is rejected.

        Parameters
        ----------
        imu
            ``(N, len(imu_columns))`` IMU rows, or ``None``.
        gnss
            ``(M, 4)`` fixes ``t, lat, lon, accuracy_m``, or ``None``.
        imu_columns
            :data:`IMU_COLUMNS` or :data:`IMU_QUAT_COLUMNS`; the same in every batch of a session.

        Returns
        -------
        list of str
            Warnings (fixes dropped for arriving late).

        Raises
        ------
        CurbsideInputError
            Bad rows (see :func:`check_imu`, :func:`check_gnss`), or a stream that turns out unusable
            once its first seconds are in (IMU rate below 20 Hz, no gyroscope, unusable quaternion).
        """
        if self.finished:
            raise RuntimeError("push() after finish()")
        if self.failed:
            raise CurbsideInputError("session", f"unusable: {self.failed}")
        imu = None if imu is None or not len(imu) else np.asarray(imu, float)
        gnss = None if gnss is None or not len(gnss) else np.asarray(gnss, float)
        if imu is not None:
            if self.imu_columns is not None and tuple(imu_columns) != self.imu_columns:
                raise CurbsideInputError(
                    "imu",
                    "the columns changed from one batch to the next (the quaternion in some, not others)",
                )
            check_imu(imu, self.last_imu_t, self.limits, recent_norms=self._recent_norms)
        warnings: list[str] = []
        if gnss is not None:
            check_gnss(gnss, self.last_gnss_t, self.limits)
            gnss, warnings = self._timely_fixes(gnss, imu)
        if imu is not None:
            self._push_imu(imu, tuple(imu_columns))
        if gnss is not None and len(gnss):
            self._push_gnss(gnss)
        for rows in (imu, gnss):
            if rows is not None and len(rows):
                self.first_t = min(self.first_t, float(rows[0, 0]))
        return warnings

    def _timely_fixes(self, gnss: np.ndarray, imu: np.ndarray | None) -> tuple[np.ndarray, list[str]]:
        """The fixes that can still be used; the rest dropped with a warning. Checks the clock.

        A fix far ahead of the IMU is refused only where the fixes' own clock jumps there too (another
        clock, or a glitch that would block the fixes after it): when the IMU stops (a phone app in the
        background) and fixes go on a second apart, they are taken, as ``localize run`` takes them.
        """
        imu_t = imu[-1, 0] if imu is not None else self.last_imu_t
        skew = self.limits.max_clock_skew_s
        jump = np.diff(np.concatenate([[self.last_gnss_t], gnss[:, 0]]))
        ahead = gnss[:, 0] - imu_t
        if math.isfinite(imu_t) and ((ahead > skew) & ~(jump <= skew)).any():
            row = int(np.argmax((ahead > skew) & ~(jump <= skew)))
            raise CurbsideInputError(
                f"gnss[{row}].t",
                f"{float(gnss[row, 0])!r} is {ahead[row]:.0f} s ahead of the IMU (one clock for both "
                "streams)",
            )
        self._check_distance(gnss)
        late = gnss[:, 0] <= self._released_until
        if not late.any():
            return gnss, []
        message = (
            f"{int(late.sum())} fix(es) up to t={gnss[late, 0].max():.3f} dropped: they arrived more than "
            f"{self.limits.fix_delay_s:g} s after the IMU rows of their time"
        )
        logger.info("%s: %s", self.name, message)
        self.last_gnss_t = max(self.last_gnss_t, float(gnss[late, 0].max()))
        return gnss[~late], [message]

    def _check_distance(self, gnss: np.ndarray) -> None:
        frame = self.frame or LocalFrame.around(float(gnss[0, 2]), float(gnss[0, 1]))
        x, y = frame.to_xy(gnss[:, 2], gnss[:, 1])
        if self.map_layers is not None:
            xmin, ymin, xmax, ymax = self._extent
        elif self.start is not None:
            xmin, ymin = frame.to_xy(self.start.lon, self.start.lat)
            xmax, ymax = xmin, ymin
        else:
            xmin = xmax = float(np.atleast_1d(x)[0])
            ymin = ymax = float(np.atleast_1d(y)[0])
        dist = np.hypot(
            np.maximum(0, np.maximum(xmin - x, x - xmax)), np.maximum(0, np.maximum(ymin - y, y - ymax))
        )
        far = np.atleast_1d(~(dist <= self.limits.max_fix_distance_m))
        if far.any():
            row = int(np.argmax(far))
            what = "the map's extent" if self.map_layers is not None else "the session's first position"
            raise CurbsideInputError(
                f"gnss[{row}].lat,lon",
                f"({gnss[row, 1]:g}, {gnss[row, 2]:g}) lies {np.atleast_1d(dist)[row] / 1000:.0f} km from "
                f"{what} (degrees, lat before lon?)",
            )

    def _push_imu(self, imu: np.ndarray, columns: tuple[str, ...]) -> None:
        if self.ronin is not None:
            try:
                self.ronin.push_rows(imu, columns)
            except CurbsideInputError as exc:  # the start-up decision: rate, gyroscope, quaternion
                self.failed = exc.problem
                raise
        self.imu_columns = columns
        self.last_imu_t = float(imu[-1, 0])
        window = self.limits.gravity_window_rows
        self._recent_norms = np.concatenate([self._recent_norms, accel_norms(imu[-window:])])[-window:]
        if self.steps is not None:
            found = self.steps.push(imu[:, 0], imu[:, 1:4], imu[:, 4:7])
            if len(found):
                self._step_times.append(found)

    def _push_gnss(self, gnss: np.ndarray) -> None:
        self.last_gnss_t = float(gnss[-1, 0])
        usable = int((gnss[:, 3] > 0).sum())  # NaN compares False: an invalid fix
        self._usable_fixes += usable
        self._unusable_fixes += len(gnss) - usable
        if self.frame is None:
            self.frame = LocalFrame.around(float(gnss[0, 2]), float(gnss[0, 1]))
            self._make_engine()
        self._gnss.append(gnss)

    def take_windows(self) -> tuple[np.ndarray, np.ndarray]:
        """RoNIN windows cut since the last call: ``(t_mid (K,), windows (K, 6, 200) float32)``."""
        if self.ronin is None:
            return np.zeros(0), np.zeros((0, 6, RoninStreamConfig().window), np.float32)
        self._tail_taken = self.finished
        t, windows = self.ronin.take_windows()
        self._windows_out += len(t)
        return t, windows

    def push_velocity(self, t: np.ndarray, velocity_en: np.ndarray) -> None:
        """The model's velocities (m/s east, north) for the windows taken, in the same order."""
        if len(t):
            self._velocity.append(np.column_stack([t, velocity_en]))
            self._velocities_in += len(t)

    def lose_velocity(self, t: np.ndarray, reason: str) -> None:
        """The windows at ``t`` will get no velocity (inference failed): the session cannot go on."""
        self._velocities_in += len(t)
        self.failed = self.failed or reason

    @property
    def drained(self) -> bool:
        """Input has ended and every RoNIN window taken has its velocity back: the track can be finished."""
        return self.finished and (
            self.ronin is None or (self._tail_taken and self._windows_out == self._velocities_in)
        )

    # -- output -------------------------------------------------------------------------------------

    @property
    def received_until(self) -> float:
        """The latest row time received on either stream."""
        return max(self.last_imu_t, self.last_gnss_t)

    def advance(self) -> list[Row]:
        """Hand the engine what is final and make the updates it allows; return the new rows."""
        if self.engine is None:
            return []
        until = math.inf if self.finished else self.received_until - self.limits.fix_delay_s
        self._release(until)
        # The engine's finish decides on what it has (e.g. the start heading), so it waits for the last
        # velocities, which may still be at the inference thread.
        return self.engine.finish() if self.drained else self.engine.advance()

    def _release(self, until: float) -> None:
        engine = self.engine
        if self._gnss:
            rows = np.concatenate(self._gnss)
            self._gnss = []
            engine.push_gnss(pd.DataFrame(rows, columns=_GNSS_INDEX, copy=False))
        if self._velocity:
            rows = np.concatenate(self._velocity)
            n = int(np.searchsorted(rows[:, 0], until, side="right"))
            if n:
                engine.push_velocity(rows[:n, 0], rows[:n, 1:])
            self._velocity = [rows[n:]] if n < len(rows) else []
        if self.steps is not None:
            times = np.concatenate(self._step_times) if self._step_times else np.zeros(0)
            n = int(np.searchsorted(times, until, side="right"))
            engine.push_steps(times[:n], min(until, self.steps.complete_until))
            self._step_times = [times[n:]] if n < len(times) else []
        self._released_until = max(self._released_until, until)

    def finish_streams(self) -> None:
        """End of input: flush the detectors' tails (take the last windows after this)."""
        if self.finished:
            return
        self.finished = True
        if self.ronin is not None and math.isfinite(self.last_imu_t) and not self.failed:
            try:
                self.ronin.finish()
            except CurbsideInputError as exc:  # a stream shorter than the start-up decision
                self.failed = exc.problem
                logger.warning("%s: %s", self.name, exc.problem)
        if self.steps is not None:
            tail = self.steps.finish()
            if len(tail):
                self._step_times.append(tail)

    def notices(self) -> list[str]:
        """What keeps the estimate from answering for now, in a line each: the filter waits for IMU rows
        (none yet, or none for :attr:`LiveLimits.stall_warning_s` of data while fixes come) or, without a
        start pose, for a first usable fix; or the estimate lies off the map."""
        if self.finished or self.failed or not math.isfinite(self.first_t):
            return []
        out = []
        wait_s = self.limits.stall_warning_s
        imu_since = self.last_imu_t if math.isfinite(self.last_imu_t) else self.first_t
        behind_s = self.received_until - imu_since
        if (self.ronin is not None or self.steps is not None) and behind_s > wait_s:
            needs = "footsteps and velocities come" if self.ronin is not None else "footsteps come"
            if math.isfinite(self.last_imu_t):
                out.append(f"no IMU rows for the last {behind_s:.0f} s of data: the estimate waits for them")
            else:
                out.append(
                    f"no IMU rows in {behind_s:.0f} s of data: the estimate waits for them ({needs} from the "
                    "IMU; without one, use mode gnss with engine.step_source cadence)"
                )
        span_s = self.received_until - self.first_t
        if not self.rows and self.start is None and self._usable_fixes == 0 and span_s > wait_s:
            out.append(
                f"no usable fix in {span_s:.0f} s of data ({self._unusable_fixes} without a positive "
                "accuracy_m) and no start pose: the filter starts at the first usable fix"
            )
        if self.rows and self._extent is not None:
            row = self.rows[-1]
            xmin, ymin, xmax, ymax = self._extent
            off_m = math.hypot(max(0.0, xmin - row.x, row.x - xmax), max(0.0, ymin - row.y, row.y - ymax))
            if off_m > self.config.engine.extent_tolerance_m:
                out.append(f"the estimate lies {off_m:.0f} m outside the map's extent: no sidewalk there")
        return out

    @property
    def rows(self) -> list[Row]:
        """Every update so far."""
        return [] if self.engine is None else self.engine.rows

    @property
    def recoveries(self) -> int:
        """Collapses of the particle cloud so far."""
        tracker = None if self.engine is None else self.engine.tracker
        return 0 if tracker is None else tracker.recoveries

    def result(self) -> TrackResult | None:
        """The whole track as :func:`~curbside.localize.pipeline.track_session` returns it (``None``
        without any update)."""
        if not self.rows:
            return None
        tracker = self.engine.tracker
        segments = tracker is not None and tracker.segments is not None
        track = track_table(self.rows, self.frame, self.map_layers, segments=segments)
        return TrackResult(
            track, self.config, self.velocity_source, self.step_source, **tracker_record(tracker),
            unseen_velocity_from_s=self.engine.unseen_velocity_from_s,
            familiar_velocity=self.engine.familiar_velocity,
            fix_lag=None if self.engine.lag is None else {"mode": self.config.fix_lag.mode,
                                                          "lag_s": self.engine.lag.lag_s},
        )


def stream_session(
    session: Session,
    map_layers: MapLayers | None,
    config: RunConfig,
    model: RoninResNet | None = None,
    chunk_s: float = math.inf,
    limits: LiveLimits | None = None,
) -> TrackResult:
    """Track a recorded session through a :class:`LiveSession`, fed ``chunk_s`` seconds at a time.

    With the whole recording in one chunk this is what ``localize run`` computes for a session with
    ``imu.csv`` and no ``velocity.csv``; any ``chunk_s`` gives the same track.

    Parameters
    ----------
    session
        A recording with ``imu`` (and usually ``gnss``).
    map_layers
        The map, or ``None``.
    config
        The run configuration.
    model
        A loaded RoNIN model (default: the bundled one).
    chunk_s
        Seconds of rows per push.
    limits
        Input bounds (default :class:`LiveLimits`).

    Raises
    ------
    CurbsideInputError
        Bad rows, or no estimate at all.
    """
    from curbside.localize.ronin.infer import load_model

    raster = None
    if map_layers is not None and config.mode != "gnss":
        fm = config.filter.map
        raster = load_or_build_raster(map_layers, fm.raster_resolution_m, fm.segment_reach_m)
    start = session.start_pose
    pose = (
        None if start is None else StartPose(start["lat"], start["lon"], start["heading_deg"], start.get("t"))
    )
    live = LiveSession(config, map_layers, raster, start=pose, limits=limits, name=session.name)
    queue = InferenceQueue(model if model is not None else load_model())
    columns = IMU_QUAT_COLUMNS if "qw" in session.imu.columns else IMU_COLUMNS
    imu = session.imu[list(columns)].to_numpy(float)
    gnss = None if session.gnss is None else session.gnss[list(GNSS_COLUMNS)].to_numpy(float)
    t0, t1 = session.time_span()
    edges = np.arange(t0, t1, chunk_s) if math.isfinite(chunk_s) else np.array([t0])
    for lo, hi in zip(edges, [*edges[1:], math.inf], strict=True):
        first = lo == edges[0]
        pick_imu = imu[((imu[:, 0] >= lo) | first) & (imu[:, 0] < hi)]
        pick_gnss = None if gnss is None else gnss[((gnss[:, 0] >= lo) | first) & (gnss[:, 0] < hi)]
        live.push(pick_imu, pick_gnss, columns)
        queue.collect(live)
        queue.run()
        live.advance()
    live.finish_streams()
    queue.collect(live)
    queue.run()
    live.advance()
    result = live.result()
    if result is None:
        require_rows(live.engine, session.name)
    return result
