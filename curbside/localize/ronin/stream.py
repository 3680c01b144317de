"""Streaming RoNIN input: IMU rows in any chunking, model-ready windows out, bit-identical either way.

A live session pushes IMU rows in small batches; the batch command pushes the whole file at once.
Both go through :class:`RoninStream`, whose output does not depend on the chunking:

1. :class:`~curbside.localize.imu.WorldFrameStream` rotates the rows into the gravity-aligned world
   frame at their own times, segment by segment (gaps longer than ``max_gap_s`` split).
2. :class:`WindowCutter` resamples each segment linearly onto a ``rate_hz`` grid anchored at the
   segment's first sample (``t0 + j / rate_hz``) and cuts a ``window``-sample window every
   ``stride`` samples from the segment's start. A grid sample is made as soon as an input sample
   at or after its time exists, always from the same two input samples, so its value never depends
   on where a chunk ended.

Windows from any number of sessions can then be stacked and passed to
:func:`curbside.localize.ronin.infer.infer_windows`, whose fixed-shape batches make each window's
velocity independent of what else is in the batch; :class:`InferenceQueue` does that for the live
sessions of :mod:`curbside.localize.live`.
"""

from __future__ import annotations

import logging
import weakref
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np
import pandas as pd

from curbside.configio import positive
from curbside.localize.imu import ImuConfig, RepeatedWarning, WorldFrameStream, WorldSamples
from curbside.localize.runconstants import RONIN_STRIDE

if TYPE_CHECKING:
    from curbside.localize.live import LiveSession
    from curbside.localize.ronin.model import RoninResNet

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class RoninStreamConfig:
    """Parameters of the streaming RoNIN input (recorded in a run's ``run.json``).

    Attributes
    ----------
    rate_hz, window
        Grid rate (Hz) and window length (samples): those the model was trained with (RoNIN's
        200 Hz and one-second windows); checked against the model's config.
    stride
        Grid samples between window starts. 20 (a velocity every 100 ms) halves RoNIN's 10 for the
        same held-out accuracy (median ATE, RTE and speed error within 0.02 m, 0.1 m and 0.001 m/s
        of stride 10 on MS Indoor and IPIN 2023); 40 is slightly worse on IPIN and saves little more,
        as the streaming preprocessing then dominates. Measured in ``docs/ronin.md``.
    batch_size
        Fixed inference batch shape of :func:`~curbside.localize.ronin.infer.infer_windows`: a
        shorter batch is zero-padded to it, which makes a window's velocity independent of the
        other windows in its batch. 128 gets 90 % of the throughput of 256 on one CPU thread
        (``benchmarks/bench_ronin.py``) and wastes less on padding when few windows are ready.
    imu
        World-frame preprocessing (gaps, rate, quaternion convention, saturation).
    """

    rate_hz: float = 200.0
    window: int = 200
    stride: int = RONIN_STRIDE
    batch_size: int = 128
    imu: ImuConfig = field(default_factory=ImuConfig)

    def __post_init__(self) -> None:
        if not 1 <= self.stride <= self.window:
            raise ValueError(f"stride must be between 1 and the window ({self.window}), not {self.stride}")
        positive(self, "batch_size", "rate_hz")

    @property
    def half_window_s(self) -> float:
        """Time from a window's first (or last) sample to its centre (s)."""
        return (self.window - 1) / (2.0 * self.rate_hz)

    def window_centres(self, t0: float, starts: np.ndarray) -> np.ndarray:
        """Centre times of windows starting at grid indices ``starts`` of a segment beginning at ``t0``."""
        return 0.5 * ((t0 + starts / self.rate_hz) + (t0 + (starts + self.window - 1) / self.rate_hz))


class WindowCutter:
    """World-frame samples (any chunking) to windows on each segment's uniform grid.

    Parameters
    ----------
    config
        Grid rate, window and stride.
    source
        Name used in messages.
    """

    def __init__(self, config: RoninStreamConfig, source: str = "imu.csv") -> None:
        self.config = config
        self.source = source
        self.finished = False
        self._segment: int | None = None
        self._t0 = 0.0
        self._next_grid = 0  # grid index of the next grid sample to make
        self._last: tuple[float, np.ndarray] | None = None  # the segment's last input sample
        self._grid = np.zeros((0, 6), np.float32)  # grid samples from index _grid_base on
        self._grid_base = 0
        self._next_start = 0  # grid index of the next window's first sample
        self._queue_t: list[np.ndarray] = []
        self._queue_w: list[np.ndarray] = []
        self._short = RepeatedWarning(logger, source, "stretches between gaps shorter than one window")

    @property
    def complete_until(self) -> float:
        """Every window centred at or before this time has been cut (``inf`` once finished)."""
        if self.finished:
            return np.inf
        if self._segment is None:
            return -np.inf
        return float(np.nextafter(self.config.window_centres(self._t0, np.array(self._next_start)), -np.inf))

    @property
    def due_at(self) -> float:
        """The next window is cut once a sample of the segment at or after this time is added
        (``-inf`` before the first sample)."""
        if self._segment is None:
            return -np.inf
        return self._t0 + (self._next_start + self.config.window - 1) / self.config.rate_hz

    def add(self, samples: WorldSamples) -> None:
        """Append world-frame samples (they follow the previous ones in time)."""
        if self.finished:
            raise RuntimeError("add() after finish()")
        segment, n = samples.segment, len(samples.t)
        if n == 0:
            return
        # segment numbers only grow: one segment, the usual case, needs no search for its cuts
        cuts = [] if segment[0] == segment[-1] else (np.flatnonzero(np.diff(segment)) + 1).tolist()
        for lo, hi in zip([0, *cuts], [*cuts, n], strict=True):
            if samples.segment[lo] != self._segment:
                self._start_segment(int(samples.segment[lo]), float(samples.t[lo]))
            self._extend_grid(samples.t[lo:hi], samples.values[lo:hi])
            self._cut()

    def finish(self) -> None:
        """No more samples: close the last segment."""
        if not self.finished:
            self._end_segment()
            self._short.finish()
            self.finished = True

    def take(self) -> tuple[np.ndarray, np.ndarray]:
        """``(t_mid (K,), windows (K, 6, window) float32)`` cut since the last call, now dequeued."""
        if not self._queue_t:
            return np.zeros(0), np.zeros((0, 6, self.config.window), np.float32)
        t_mid, windows = np.concatenate(self._queue_t), np.concatenate(self._queue_w)
        self._queue_t, self._queue_w = [], []
        return t_mid, windows

    def _start_segment(self, segment: int, t0: float) -> None:
        self._end_segment()
        self._segment, self._t0 = segment, t0
        self._next_grid, self._last = 0, None
        self._grid, self._grid_base, self._next_start = self._grid[:0], 0, 0

    def _end_segment(self) -> None:
        if self._segment is not None and self._next_start == 0 and self._last is not None:
            self._short.warn("%s: a %.2f s stretch at t=%.2f s between gaps is shorter than one window: "
                             "no velocity there", self.source, self._last[0] - self._t0, self._t0)

    def _extend_grid(self, t: np.ndarray, values: np.ndarray) -> None:
        if self._last is not None:
            t = np.concatenate([[self._last[0]], t])
            values = np.vstack([self._last[1], values])
        self._last = (float(t[-1]), values[-1])
        rate = self.config.rate_hz
        last = int(np.floor((t[-1] - self._t0) * rate))
        while last >= 0 and self._t0 + last / rate > t[-1]:
            last -= 1
        while self._t0 + (last + 1) / rate <= t[-1]:
            last += 1
        if last < self._next_grid:
            return
        grid_t = self._t0 + np.arange(self._next_grid, last + 1) / rate
        after = np.searchsorted(t, grid_t, side="left")  # first input sample at or after each grid time
        before = np.maximum(after - 1, 0)
        exact = t[after] == grid_t
        span = np.where(exact, 1.0, t[after] - t[before])
        weight = np.where(exact, 0.0, (grid_t - t[before]) / span)[:, None]
        start = np.where(exact[:, None], values[after], values[before])
        made = start + weight * (values[after] - start)
        self._grid = np.vstack([self._grid, made.astype(np.float32)])
        self._next_grid = last + 1

    def _cut(self) -> None:
        cfg = self.config
        if self._next_grid - cfg.window < self._next_start:
            return  # no window ends in the samples made so far (nor can any sample be dropped)
        starts = np.arange(self._next_start, self._next_grid - cfg.window + 1, cfg.stride)
        if len(starts):
            view = np.lib.stride_tricks.sliding_window_view(self._grid, cfg.window, axis=0)
            self._queue_w.append(np.ascontiguousarray(view[starts - self._grid_base]))
            self._queue_t.append(cfg.window_centres(self._t0, starts))
            self._next_start = int(starts[-1]) + cfg.stride
        drop = self._next_start - self._grid_base
        if drop > 0:
            self._grid, self._grid_base = self._grid[drop:], self._next_start


class RoninStream:
    """One session's IMU stream to RoNIN windows, chunk-invariant (see the module docstring).

    Parameters
    ----------
    config
        Stream parameters (defaults: :class:`RoninStreamConfig`).
    source
        Name used in messages (the file or the session).

    Attributes
    ----------
    latency_s
        A velocity row stamped ``t`` is produced once an IMU sample at or after ``t + latency_s``
        has been pushed (in the same gap-free stretch, and after the first ``imu.decision_s``
        seconds of the stream, which decide the quaternion convention).

    Examples
    --------
    >>> stream = RoninStream(source="walk")  # doctest: +SKIP
    >>> stream.push(rows)                    # any number of rows, any number of times (or push_rows)
    >>> t_mid, windows = stream.take_windows()
    >>> velocity = infer_windows(model, windows)  # or stacked with other sessions' windows
    >>> stream.finish(); t_tail, tail = stream.take_windows()
    """

    def __init__(self, config: RoninStreamConfig | None = None, source: str = "imu.csv") -> None:
        self.config = config or RoninStreamConfig()
        self.source = source
        self.latency_s = self.config.half_window_s
        self._world = WorldFrameStream(self.config.imu, source)
        self._cutter = WindowCutter(self.config, source)
        self._held: list[np.ndarray] = []  # rows of push_rows not yet through the world frame
        self._held_columns: tuple[str, ...] = ()
        self._held_index = pd.Index([], dtype=object)  # their column index (str dtype: 10x slower to read)
        self._pushed_until = -np.inf  # the last row of push_rows

    @property
    def complete_until(self) -> float:
        """Every velocity row at or before this time has been produced (``-inf`` before the first,
        ``inf`` after :meth:`finish`)."""
        held = self._world.next_time
        if np.isfinite(held) and not np.isfinite(self._cutter.complete_until):
            first = self.config.window_centres(held, np.array(0))
            return float(np.nextafter(first, -np.inf))
        return self._cutter.complete_until

    @property
    def saturated_samples(self) -> int:
        """IMU samples found at a sensor's saturation value so far (in the rows held by
        :meth:`push_rows` once they are released)."""
        return self._world.saturated_samples

    def push(self, imu: pd.DataFrame) -> None:
        """Append rows ``t,ax,ay,az,gx,gy,gz[,qx,qy,qz,qw]`` (see :meth:`WorldFrameStream.push`), after
        any held by :meth:`push_rows`."""
        self._release()
        self._world.push(imu)
        self._cutter.add(self._world.take())

    def push_rows(self, rows: np.ndarray, columns: tuple[str, ...]) -> None:
        """Append rows the caller has checked (finite, later than every row before, unit quaternions,
        the same ``columns`` each time: :func:`~curbside.localize.live_input.check_imu`).

        Unlike :meth:`push`, the rows are held until they complete a window, or start a segment after
        a gap, or the stream is still making its start-up decision: then all the rows held go through
        the world frame and the grid at once. The windows come out at the same push and bit-identical
        (every stage is chunk-invariant); a session that sends one row per request pays the per-call
        work once a window (every ``stride`` grid samples), not once a row.

        Parameters
        ----------
        rows
            ``(N, len(columns))`` float rows (kept, not copied, until they go through: do not change
            them).
        columns
            ``t,ax,ay,az,gx,gy,gz[,qx,qy,qz,qw]``, their order in ``rows``.
        """
        if not len(rows):
            return
        t = rows[:, 0]
        gap_s = self.config.imu.max_gap_s
        new_segment = t[0] - self._pushed_until > gap_s or (len(t) > 1 and bool((np.diff(t) > gap_s).any()))
        self._pushed_until = float(t[-1])
        self._held.append(rows)
        if tuple(columns) != self._held_columns:
            self._held_columns, self._held_index = tuple(columns), pd.Index(columns, dtype=object)
        if new_segment or t[-1] >= self._cutter.due_at:
            self._release()

    def _release(self) -> None:
        """Push the rows held by :meth:`push_rows`."""
        if self._held:
            rows = self._held[0] if len(self._held) == 1 else np.concatenate(self._held)
            self._held = []
            self._world.push(pd.DataFrame(rows, columns=self._held_index, copy=False))
            self._cutter.add(self._world.take())

    def finish(self) -> None:
        """End of the session: flush the tail into the queue."""
        self._release()
        self._world.finish()
        self._cutter.add(self._world.take())
        self._cutter.finish()

    def take_windows(self) -> tuple[np.ndarray, np.ndarray]:
        """Windows ready for inference, removed from the queue.

        Returns
        -------
        t_mid, windows
            ``(K,)`` window centre times (s) and ``(K, 6, window)`` float32 world-frame gyroscope and
            accelerometer, oldest first.
        """
        return self._cutter.take()


#: Shapes a partial RoNIN batch may be padded to instead of the full one, smallest first.
PARTIAL_SHAPES = (16, 32, 64)
_exact_shapes: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def exact_partial_shapes(model: RoninResNet, batch_size: int) -> tuple[int, ...]:
    """The shapes of :data:`PARTIAL_SHAPES` that give the velocities of ``batch_size`` bit for bit.

    torch picks its kernels by batch shape, CPU and thread count (batches of 1 to 8 windows round
    differently on the development machine), so this is checked here, on windows of noise, once per
    model, shape and thread count (0.1 s of CPU on one thread).

    Parameters
    ----------
    model
        A loaded RoNIN model.
    batch_size
        The full batch shape (:attr:`RoninStreamConfig.batch_size`).

    Returns
    -------
    tuple of int
        The exact smaller shapes, increasing (empty where none is).
    """
    import torch

    from curbside.localize.ronin.infer import infer_windows

    known = _exact_shapes.setdefault(model, {})
    key = (batch_size, torch.get_num_threads())
    if key not in known:
        shape = (max(PARTIAL_SHAPES), model.config.in_channels, model.config.window)
        noise = np.random.default_rng(0).normal(0.0, 3.0, shape).astype(np.float32)
        full = infer_windows(model, noise, batch_size)
        smaller = [s for s in PARTIAL_SHAPES if s < batch_size]
        known[key] = tuple(s for s in smaller if np.array_equal(infer_windows(model, noise, s), full))
    return known[key]


class InferenceQueue:
    """RoNIN windows of many sessions, run through the model together in fixed-shape batches.

    Windows are queued in the order they are taken, so each session gets its velocities back in time
    order. Because :func:`~curbside.localize.ronin.infer.infer_windows` pads every batch to one shape,
    a window's velocity does not depend on which other windows share its batch. The windows left over
    after the whole batches go in the smallest shape of :func:`exact_partial_shapes` that holds them:
    a lone walker's few windows every quarter second cost a batch of 16, not of 128.

    Parameters
    ----------
    model
        A loaded RoNIN model (:func:`~curbside.localize.ronin.infer.load_model`).
    batch_size
        The fixed batch shape (``RoninStreamConfig.batch_size``, the batch command's).
    """

    def __init__(self, model: RoninResNet, batch_size: int | None = None) -> None:
        from curbside.localize.ronin.infer import check_compatible

        config = RoninStreamConfig()
        check_compatible(model, config)
        self.model = model
        self.batch_size = batch_size or config.batch_size
        self._queue: list[tuple[LiveSession, np.ndarray, np.ndarray]] = []
        self.pending = 0

    def collect(self, session: LiveSession) -> None:
        """Queue the windows ``session`` has cut since the last call."""
        t, windows = session.take_windows()
        if len(t):
            self._queue.append((session, t, windows))
            self.pending += len(t)

    def take(self, whole_batches_only: bool = False, max_batches: int | None = None) -> list[tuple]:
        """Dequeue windows for one inference: all of them, or only whole batches (the rest stays), at
        most ``max_batches`` batches; ``[(session, t, windows), ...]`` in queue order."""
        n = self.pending - self.pending % self.batch_size if whole_batches_only else self.pending
        if max_batches is not None:
            n = min(n, max_batches * self.batch_size)
        taken, left = [], n
        while left:
            session, t, windows = self._queue[0]
            k = min(left, len(t))
            taken.append((session, t[:k], windows[:k]))
            if k == len(t):
                self._queue.pop(0)
            else:
                self._queue[0] = (session, t[k:], windows[k:])
            left -= k
        self.pending -= n
        return taken

    def infer(self, taken: list[tuple]) -> np.ndarray:
        """Velocities ``(K, 2)`` of the windows :meth:`take` returned (touches no session: it may run on
        another thread than the one that feeds the sessions)."""
        from curbside.localize.ronin.infer import infer_windows

        windows = np.concatenate([w for _, _, w in taken])
        left = len(windows) % self.batch_size
        whole = len(windows) - left
        shape = min((s for s in exact_partial_shapes(self.model, self.batch_size) if s >= left), default=None)
        velocity = [infer_windows(self.model, windows[:whole], self.batch_size)] if whole or not left else []
        if left:
            velocity.append(infer_windows(self.model, windows[whole:], shape or self.batch_size))
        return np.concatenate(velocity)

    @staticmethod
    def deliver(taken: list[tuple], velocity: np.ndarray) -> set[LiveSession]:
        """Hand each session its velocities; return the sessions that got some."""
        i = 0
        for session, t, _ in taken:
            session.push_velocity(t, velocity[i : i + len(t)])
            i += len(t)
        return {session for session, _, _ in taken}

    def run(self, whole_batches_only: bool = False) -> set[LiveSession]:
        """:meth:`take`, :meth:`infer` and :meth:`deliver` in one go; return the sessions served."""
        taken = self.take(whole_batches_only)
        return self.deliver(taken, self.infer(taken)) if taken else set()

    def holds(self, session: LiveSession) -> bool:
        """Whether windows of ``session`` are queued."""
        return any(entry[0] is session for entry in self._queue)

    def drop(self, session: LiveSession) -> None:
        """Forget the queued windows of ``session``."""
        kept = [entry for entry in self._queue if entry[0] is not session]
        self.pending = sum(len(t) for _, t, _ in kept)
        self._queue = kept
