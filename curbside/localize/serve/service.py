"""The tracking service's core: live sessions, a worker thread, RoNIN on its own thread, expiry, saved tracks.

:class:`TrackingService` knows nothing of HTTP (:mod:`curbside.localize.serve.app` puts it on the web).
It holds one :class:`~curbside.localize.live.LiveSession` per walker. Two threads share the work:

- the event loop (uvicorn) parses and validates JSON, queues each batch, and runs *ticks*: a tick
  takes the batches queued since the previous one (at most ``TICK_BUDGET_S`` of work, 20 ms, so that
  the loop keeps reading requests), pushes their rows into their sessions (footsteps, RoNIN windows),
  hands over the velocities the RoNIN thread has finished, advances the filters, and answers each
  request with its session's latest estimate. Under load ticks grow, and their cost per request falls;
- the *RoNIN* thread runs the queued windows of all sessions through the model in fixed-shape batches
  (torch releases the GIL, so it runs beside the loop on the other core). Whole batches (64 windows)
  go as soon as they fill; a partial batch (zero-padded to the smallest shape that gives the full
  shape's velocities bit for bit, usually 16: :class:`~curbside.localize.ronin.stream.InferenceQueue`)
  waits at most ``inference_wait_s`` for more windows, so a lone walker costs one small batch every
  quarter second,
  not one per request. A reply never waits for inference: the velocities reach the filter at the next
  tick, which adds milliseconds to the estimate's lag of seconds.

The ticks run on the loop itself, not on a worker thread: the filter work holds the GIL, and handing
every tick to a thread and back made replies under load ten times slower (p50 105 ms against 9 ms
with 100 walkers, ``benchmarks/bench_serve.py``).

The padding makes every window's velocity independent of the others in its batch, and every stage is
chunk-invariant: a session's track is the one ``localize run`` computes for its recording.

A session ends with :meth:`TrackingService.end` (``DELETE``), after ``idle_timeout_s`` without a
request, or when the service stops; once its last windows are back, its track is written under
``DATA_DIR/tracks`` (:class:`~curbside.localize.serve.store.TrackStore`) by a third thread, so that
formatting a long track holds no other session up; the session answers 409 until its track is written
and its ``DELETE`` is answered. If finishing it fails (a bug),
it ends all the same, with the track it has so far: no request waits for good, nor does the shutdown.
A track goes with ``DELETE /tracks/{id}`` (:meth:`TrackingService.delete_track`) or by the opt-in
retention limits, applied on the same thread while the service answers; the count limit is also kept as
each track is written (:meth:`~curbside.localize.serve.store.TrackStore.save`). The tracks' part of the
service is :class:`~curbside.localize.serve.track_keeping.TrackKeeping`.
"""

from __future__ import annotations

import asyncio
import contextlib
import gc
import logging
import secrets
import time
from collections import deque
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import shapely

from curbside.errors import CurbsideInputError
from curbside.localize.engine import StartPose
from curbside.localize.live import IMU_COLUMNS, IMU_QUAT_COLUMNS, InferenceQueue, LiveSession
from curbside.localize.pipeline import resolve_config
from curbside.localize.runconfig import RunConfig
from curbside.localize.serve.answers import estimate_of
from curbside.localize.serve.common import ServiceConfig, ServiceError, as_service_error, session_label
from curbside.localize.serve.configs import config_key, session_config
from curbside.localize.serve.intake import ImuRateCheck, push_batch
from curbside.localize.serve.store import TrackStore
from curbside.localize.serve.track_keeping import TrackKeeping, now_iso
from curbside.osmseg.places import SidewalkPlace, sidewalk_places

logger = logging.getLogger(__name__)


@dataclass(eq=False)
class SessionEntry:
    """An open session: its filter, when it was opened and last heard from, whether it is ending."""

    id: str
    live: LiveSession
    created: str
    last_seen: float
    rate: ImuRateCheck | None = None  # the IMU rate check of a session with RoNIN
    ending: bool = False


@dataclass(eq=False)
class SessionOp:
    """A request queued for the worker (a batch of rows or an end), with its answer or error."""

    kind: str  # "push" or "end"
    entry: SessionEntry
    future: asyncio.Future
    imu: np.ndarray | None = None
    columns: tuple[str, ...] = IMU_COLUMNS
    gnss: np.ndarray | None = None
    reason: str = "deleted"
    result: Any = None
    error: Exception | None = None


#: Longest a tick spends on requests before it answers them and lets the event loop read more (s).
TICK_BUDGET_S = 0.02
#: Longest the shutdown waits for the open sessions to end and save their tracks (s).
STOP_WAIT_S = 60.0


class TrackingService(TrackKeeping):
    """Live sessions of many walkers (see the module docstring).

    Parameters
    ----------
    config
        The service's settings.
    model
        A loaded RoNIN model (default: the bundled one).

    Raises
    ------
    CurbsideInputError
        Unreadable map, bad overrides in ``config`` (among them values no session may have: more than
        ``max_particles`` particles).
    """

    def __init__(self, config: ServiceConfig, model=None) -> None:
        from curbside.localize.raster import load_or_build_raster
        from curbside.localize.ronin.infer import load_model
        from curbside.osmseg.mapio import read_map

        self.config = config
        self.base = self._base_config(config.mode)
        try:  # what the service imposes on every session must hold for its own configuration
            session_config({}, self._base_config, self.base.filter.map, config.max_particles)
        except CurbsideInputError as exc:
            key = exc.source.removeprefix("config.")
            problem = f"{exc.problem} (every session would be refused)"
            raise CurbsideInputError(f"--set {key}", problem) from None
        self.map_layers = read_map(config.map_path) if config.map_path else None
        self.places: dict[str, SidewalkPlace] = {}
        self.raster = None
        if self.map_layers is not None:
            self.places = sidewalk_places(self.map_layers)
            fm = self.base.filter.map
            self.raster = load_or_build_raster(self.map_layers, fm.raster_resolution_m, fm.segment_reach_m)
        self.queue = InferenceQueue(model if model is not None else load_model())
        days = config.keep_tracks_days
        max_age_s = None if days is None else days * 86400.0
        self.store = TrackStore(Path(config.data_dir) / "tracks", max_age_s, config.max_tracks)
        self._warm_up()
        self.sessions: dict[str, SessionEntry] = {}
        #: Ticks run and their total seconds (for the load test).
        self.ticks = 0
        self.tick_seconds = 0.0
        self._ops: deque[SessionOp] = deque()
        self._ending: list[SessionOp] = []  # waiting for their last RoNIN windows
        self._writing: list[SessionOp] = []  # their tracks being written
        self._written: list[SessionOp] = []  # to be answered
        self._inference_executor = ThreadPoolExecutor(1, thread_name_prefix="curbside-ronin")
        self._io_executor = ThreadPoolExecutor(1, thread_name_prefix="curbside-tracks")
        self._inference: asyncio.Future | None = None
        self._inferred: tuple | None = None
        self._wake: asyncio.Event | None = None
        self._tasks: list[asyncio.Task] = []
        self._pending_since: float | None = None

    def _warm_up(self) -> None:
        """Run six seconds of a synthetic walk through every stage once, so that the first session
        does not pay for loading the filter's compiled kernels (0.7 s, all other requests waiting)."""
        t = np.arange(0.0, 6.0, 0.02)
        bounce = 1.5 * np.sin(2 * np.pi * 1.8 * t)
        zeros, ones = np.zeros_like(t), np.ones_like(t)
        imu = np.column_stack(
            [t, zeros, zeros, 9.81 + bounce, 0.01 * ones, zeros, zeros, zeros, zeros, zeros, ones]
        )
        lon = lat = 0.0
        if self.map_layers is not None:  # on a sidewalk, if there is one: not in a building
            layer = self.map_layers.layer("sidewalk")
            where = (layer if len(layer) else self.map_layers.gdf).to_crs(4326).geometry.iloc[0]
            lon, lat = shapely.point_on_surface(where).coords[0]
        gnss = np.column_stack([t[::50], np.full(6, lat), np.full(6, lon), np.full(6, 5.0)])
        live = self._new_live(self.base, StartPose(lat, lon, 0.0), "warm-up")
        queue = InferenceQueue(self.queue.model)
        live.push(imu, gnss, IMU_QUAT_COLUMNS)
        live.finish_streams()
        queue.collect(live)
        queue.run()
        live.advance()

    def _base_config(self, mode: str | None) -> RunConfig:
        return resolve_config(None, mode or self.config.mode).with_overrides(self.config.overrides)

    # -- life cycle ---------------------------------------------------------------------------------

    async def start(self) -> None:
        """Start the worker, the expiry check and the retention passes (call from the event loop)."""
        # The map, the model and the libraries make ~335,000 objects that live as long as the service:
        # a full garbage collection scans them all, 200 ms with every request waiting. Frozen, they are
        # never scanned again.
        gc.collect()
        gc.freeze()
        self._wake = asyncio.Event()
        self._tasks = [asyncio.create_task(self._worker()), asyncio.create_task(self._expire())]
        if self.store.max_age_s is not None or self.store.max_count is not None:
            # the first pass in the background: over a backlog of 2,500 tracks it took 18 s
            self._tasks.append(asyncio.create_task(self._retain()))

    async def stop(self) -> None:
        """End every open session (tracks saved, reason ``shutdown``), then stop the worker.

        Waits at most :data:`STOP_WAIT_S` for the sessions to end; a request still unanswered then gets
        a 503, so that a session that cannot end never holds the process up.
        """
        for entry in list(self.sessions.values()):
            if not entry.ending:
                self._submit_end(entry, "shutdown")
        ending = {op.future for op in (*self._ops, *self._ending, *self._writing) if op.kind == "end"}
        if ending and not all(task.done() for task in self._tasks):
            _, late = await asyncio.wait(ending, timeout=STOP_WAIT_S)
            if late:
                logger.error("%d session(s) did not end within %g s of the shutdown", len(late), STOP_WAIT_S)
        for task in self._tasks:
            task.cancel()
        await asyncio.gather(*self._tasks, return_exceptions=True)
        self._io_executor.shutdown(wait=True)  # a track being written is finished
        for op in (*self._ops, *self._ending, *self._writing, *self._written):
            if not op.future.done():
                op.future.set_exception(ServiceError(503, "the service is stopping"))
        self._ops.clear()
        self._ending, self._writing, self._written = [], [], []
        self._inference_executor.shutdown(wait=True)

    # -- requests -----------------------------------------------------------------------------------

    async def create(self, start: dict[str, Any] | None, overrides: dict[str, Any]) -> SessionEntry:
        """Open a session; ``start`` as ``meta.json``'s, ``overrides`` as ``--set`` (``mode`` too).

        Raises
        ------
        ServiceError
            503 when full; 422 for a bad override or start pose.
        """
        if len(self.sessions) >= self.config.max_sessions:
            raise ServiceError(503, f"the service holds its maximum of {self.config.max_sessions} sessions")
        config = self._session_config(overrides)
        pose = (
            None
            if start is None
            else StartPose(start["lat"], start["lon"], start["heading_deg"], start.get("t"))
        )
        session_id = secrets.token_urlsafe(24)
        try:
            live = self._new_live(config, pose, session_label(session_id))
        except CurbsideInputError as exc:
            source = config_key(exc.source) if exc.source.startswith("engine.") else exc.source
            raise ServiceError(422, f"{source}: {exc.problem}") from None
        imu = None if live.ronin is None else live.ronin.config.imu
        rate = None if imu is None else ImuRateCheck(imu.min_rate_hz, imu.decision_s)
        entry = SessionEntry(session_id, live, now_iso(), time.monotonic(), rate)
        self.sessions[session_id] = entry
        return entry

    def _session_config(self, overrides: dict[str, Any]) -> RunConfig:
        try:
            fixed_map, max_particles = self.base.filter.map, self.config.max_particles
            return session_config(overrides, self._base_config, fixed_map, max_particles)
        except CurbsideInputError as exc:
            raise ServiceError(422, str(exc)) from None

    def _new_live(self, config: RunConfig, pose: StartPose | None, name: str) -> LiveSession:
        raster = self.raster if config.mode != "gnss" else None
        return LiveSession(config, self.map_layers, raster, start=pose, limits=self.config.limits, name=name)

    def entry(self, session_id: str) -> SessionEntry:
        """The open session ``session_id``.

        Raises
        ------
        ServiceError
            410 for an ended session whose track is stored, else 404.
        """
        entry = self.sessions.get(session_id)
        if entry is not None:
            return entry
        if self.store.folder(session_id) is not None:
            raise ServiceError(410, "the session has ended; its track is at /tracks/{id}")
        raise ServiceError(404, "no such session")

    async def push(
        self, session_id: str, imu: np.ndarray | None, columns: tuple[str, ...], gnss: np.ndarray | None
    ) -> dict[str, Any]:
        """Feed a batch of rows; return the session's latest estimate (:meth:`estimate`'s dict).

        Raises
        ------
        ServiceError
            404/410 unknown or ended session, 409 ending, 422 rows refused (the session is unchanged).
        """
        entry = self.entry(session_id)
        if entry.ending:
            raise ServiceError(409, "the session is ending")
        entry.last_seen = time.monotonic()
        op = SessionOp("push", entry, asyncio.get_running_loop().create_future(), imu, columns, gnss)
        self._submit(op)
        return await op.future

    def estimate(self, session_id: str) -> dict[str, Any]:
        """The session's latest estimate (fields of :class:`~curbside.localize.serve.models.Estimate`)."""
        entry = self.entry(session_id)
        entry.last_seen = time.monotonic()
        return estimate_of(entry.live, self.places)

    async def end(self, session_id: str, reason: str = "deleted") -> dict[str, Any]:
        """End a session: finish the filter, save the track; return a summary (``TrackSummary``).
        ``reason``: ``deleted`` (``DELETE``) or ``ended`` (the WebSocket's ``end``)."""
        entry = self.entry(session_id)
        if entry.ending:
            raise ServiceError(409, "the session is ending")
        return await self._submit_end(entry, reason)

    def _submit_end(self, entry: SessionEntry, reason: str) -> asyncio.Future:
        entry.ending = True
        op = SessionOp("end", entry, asyncio.get_running_loop().create_future(), reason=reason)
        op.future.add_done_callback(_log_failure)
        self._submit(op)
        return op.future

    def _submit(self, op: SessionOp) -> None:
        self._ops.append(op)
        self._wake.set()

    # -- the worker ---------------------------------------------------------------------------------

    async def _worker(self) -> None:
        loop = asyncio.get_running_loop()
        while True:
            if not self._ops and not self._inferred and not self._written:
                timeout = None
                if self._inference is None and self.queue.pending and self._pending_since is not None:
                    timeout = max(0.0, self._pending_since + self.config.inference_wait_s - time.monotonic())
                with contextlib.suppress(asyncio.TimeoutError):  # a partial RoNIN batch waited long enough
                    await asyncio.wait_for(self._wake.wait(), timeout)
            self._wake.clear()
            inferred, self._inferred = self._inferred, None
            ops: list[SessionOp] = []
            written, self._written = self._written, []
            t0 = time.perf_counter()
            try:
                answered = self._tick(ops, inferred) + written
            except Exception as exc:  # a bug: answer every request rather than hang them
                logger.exception("tick failed")
                answered = ops + self._ending + written
                self._ending = []
                for op in answered:
                    op.error = op.error or exc
            self.ticks += 1
            self.tick_seconds += time.perf_counter() - t0
            for op in answered:
                if op.kind == "end":
                    self.sessions.pop(op.entry.id, None)
                    self.queue.drop(op.entry.live)
                if op.future.done():
                    continue
                if op.error is not None:
                    op.future.set_exception(as_service_error(op.error))
                else:
                    op.future.set_result(op.result)
            self._start_inference(loop)
            await asyncio.sleep(0)  # read the requests that came in meanwhile before the next tick

    def _start_inference(self, loop: asyncio.AbstractEventLoop) -> None:
        """Send queued RoNIN windows to the inference thread (one batch set at a time): whole batches,
        or everything once a partial batch has waited ``inference_wait_s`` or a session is ending."""
        if self._inference is not None or not self.queue.pending:
            return
        now = time.monotonic()
        if self._pending_since is None:
            self._pending_since = now
        stale = now - self._pending_since >= self.config.inference_wait_s
        taken = self.queue.take(whole_batches_only=not (stale or self._ending), max_batches=8)
        if not taken:
            return
        self._pending_since = None if not self.queue.pending else now
        future = loop.run_in_executor(self._inference_executor, self.queue.infer, taken)

        def done(f: asyncio.Future) -> None:
            self._inference = None
            self._inferred = (taken, f)
            self._wake.set()

        self._inference = future
        future.add_done_callback(done)

    def _tick(self, ops: list[SessionOp], inferred: tuple | None) -> list[SessionOp]:
        """One round of work (see the module docstring): the requests queued, up to :data:`TICK_BUDGET_S`
        of them (appended to ``ops``; the rest wait for the next tick); returns the answered ops."""
        touched: set[LiveSession] = set()
        if inferred is not None:
            taken, future = inferred
            if future.exception() is None:
                touched |= self.queue.deliver(taken, future.result())
            else:  # a bug: those sessions cannot go on
                logger.error("RoNIN inference failed: %s", future.exception())
                for live, t, _ in taken:
                    live.lose_velocity(t, "internal error (RoNIN inference)")
        budget_end = time.perf_counter() + TICK_BUDGET_S
        while self._ops and time.perf_counter() < budget_end:
            op = self._ops.popleft()
            ops.append(op)
            live = op.entry.live
            try:
                if op.kind == "push":
                    op.result = push_batch(live, op.entry.rate, op.imu, op.gnss, op.columns)
                else:
                    live.finish_streams()
                    self._ending.append(op)
            except CurbsideInputError as exc:
                op.error = exc
            except Exception as exc:  # a bug: this request fails, the others go on
                logger.exception("%s: %s failed", live.name, op.kind)
                op.error = exc
            self.queue.collect(live)
            touched.add(live)
        for live in touched:
            try:
                live.advance()
            except Exception as exc:  # a bug: the session stops, the others go on
                logger.exception("%s: filter update failed", live.name)
                live.failed = live.failed or f"internal error ({type(exc).__name__})"
        answered = [op for op in ops if op.kind == "push" or op.error is not None]
        for op in answered:
            if op.kind == "end":  # finishing its streams failed: it ends now, with what it has
                op.error = self._abandon(op.entry, op.reason, op.error)
            elif op.error is None:
                op.result = estimate_of(op.entry.live, self.places, op.result)
        for op in list(self._ending):
            live = op.entry.live
            if not live.drained:
                continue  # its last windows are at the inference thread
            self._ending.remove(op)
            try:
                self._write(op)
            except Exception as exc:
                logger.exception("%s: saving its track failed", live.name)
                op.error = exc
                answered.append(op)
        return answered

    async def _expire(self) -> None:
        period = max(0.05, min(self.config.idle_timeout_s / 4.0, 10.0))
        while True:
            await asyncio.sleep(period)
            now = time.monotonic()
            for entry in list(self.sessions.values()):
                if not entry.ending and now - entry.last_seen > self.config.idle_timeout_s:
                    logger.info("%s expired", entry.live.name)
                    self._submit_end(entry, "expired")


def _log_failure(future: asyncio.Future) -> None:
    if not future.cancelled() and future.exception() is not None:
        logger.error("ending a session failed: %s", future.exception())
