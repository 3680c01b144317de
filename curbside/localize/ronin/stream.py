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
velocity independent of what else is in the batch.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from curbside.localize.imu import ImuConfig, WorldFrameStream, WorldSamples

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
        Grid samples between window starts. 20 (one velocity every 100 ms) costs half the inference
        of RoNIN's 10 for the same accuracy on the held-out recordings; see ``docs/ronin.md``.
    batch_size
        Fixed inference batch shape of :func:`~curbside.localize.ronin.infer.infer_windows`: a
        shorter batch is zero-padded to it, which makes a window's velocity independent of the
        other windows in its batch. Must be the same everywhere results are compared.
    imu
        World-frame preprocessing (gaps, rate, quaternion convention, saturation).
    """

    rate_hz: float = 200.0
    window: int = 200
    stride: int = 20
    batch_size: int = 64
    imu: ImuConfig = field(default_factory=ImuConfig)

    def __post_init__(self) -> None:
        if not 1 <= self.stride <= self.window:
            raise ValueError(f"stride must be between 1 and the window ({self.window}), not {self.stride}")
        if self.batch_size < 1 or self.rate_hz <= 0:
            raise ValueError("batch_size and rate_hz must be positive")

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

    @property
    def complete_until(self) -> float:
        """Every window centred at or before this time has been cut (``inf`` once finished)."""
        if self.finished:
            return np.inf
        if self._segment is None:
            return -np.inf
        return float(np.nextafter(self.config.window_centres(self._t0, np.array(self._next_start)), -np.inf))

    def add(self, samples: WorldSamples) -> None:
        """Append world-frame samples (they follow the previous ones in time)."""
        if self.finished:
            raise RuntimeError("add() after finish()")
        cuts = np.flatnonzero(np.diff(samples.segment)) + 1
        for lo, hi in zip(np.r_[0, cuts], np.r_[cuts, len(samples.t)], strict=True):
            if hi <= lo:
                continue
            if samples.segment[lo] != self._segment:
                self._start_segment(int(samples.segment[lo]), float(samples.t[lo]))
            self._extend_grid(samples.t[lo:hi], samples.values[lo:hi])
            self._cut()

    def finish(self) -> None:
        """No more samples: close the last segment."""
        if not self.finished:
            self._end_segment()
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
            logger.warning("%s: a %.2f s stretch at t=%.2f s between gaps is shorter than one window: "
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
    >>> stream.push(rows)                    # any number of rows, any number of times
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
        """IMU samples found at a sensor's saturation value so far."""
        return self._world.saturated_samples

    def push(self, imu: pd.DataFrame) -> None:
        """Append rows ``t,ax,ay,az,gx,gy,gz[,qx,qy,qz,qw]`` (see :meth:`WorldFrameStream.push`)."""
        self._world.push(imu)
        self._cutter.add(self._world.take())

    def finish(self) -> None:
        """End of the session: flush the tail into the queue."""
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
