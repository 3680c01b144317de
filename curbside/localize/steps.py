"""Footstep detection from the accelerometer, streaming and chunk-invariant.

Each footstep shows as a hump of the acceleration magnitude ``|a|`` 1.3-2.5 times a second, whether
the phone is held in front, swung in the hand, carried in a trouser pocket or in a bag: the magnitude
does not depend on how the phone is turned. :class:`StepDetector` finds them in five local stages:

1. **Grid.** Rows are resampled (linear interpolation) onto a fixed-rate grid anchored at the first
   row's time, ``t0 + k / rate_hz``. Phone timestamps jitter and Android and iOS log at 50-100 Hz;
   the grid makes every later stage independent of both.
2. **Low-pass.** A linear-phase FIR low-pass (``lowpass_hz``) keeps the gait fundamental and removes
   heel-strike ringing. It is centred, so a hump keeps its time.
3. **Candidates.** A grid sample is a candidate footstep when it is the largest low-passed value
   within ``peak_halfwidth_s`` on either side, the low-passed signal swings by at least
   ``min_swing_ms2`` within ``range_halfwidth_s`` (a phone held still, or in a trembling hand, does
   not), and it rises above the deeper of the two troughs within ``2 * peak_halfwidth_s`` by at least
   ``min_prominence_ms2`` and by ``rel_prominence`` times that swing (an adaptive threshold: it follows
   a soft or a heavy gait, and a phone in a trouser pocket whose two legs give humps of different
   heights).
4. **Handling.** Where a gyroscope is given, candidates are dropped while the rotation rate's RMS
   within ``handling_halfwidth_s`` exceeds ``handling_gyro_rms_rads``: waving or turning the phone
   over rotates it several times faster than any way of carrying it while walking.
5. **Runs.** Walking is a train of footsteps at a regular pace. A candidate closer than
   ``min_interval_s`` to the one before is a second peak of the same footstep and is ignored. A
   candidate counts only inside a run of at least ``min_run`` candidates whose intervals lie in
   ``[min_interval_s, max_interval_s]``; from a run's third interval on, each interval must also be
   within a factor ``max_interval_ratio`` of the pace, the mean of the two intervals before it (with a
   phone in one pocket the intervals alternate between short and long). A few bumps (putting the
   phone down, shifting weight, tapping the screen) make no step; the first footsteps of a walk are
   reported once its run is long enough.

Every stage is a finite window or a sequential rule over candidates, computed element by element in a
fixed order, so the steps do not depend on how the rows are split into pushes: for any split,
the concatenated outputs of :meth:`StepDetector.push` and :meth:`StepDetector.finish` equal
:func:`detect_steps` on the whole table, bit for bit (``tests/test_steps.py`` checks it with
hypothesis). ``docs/steps.md`` explains the defaults and the labelled recordings they were checked on.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd
from numpy.lib.stride_tricks import as_strided
from scipy.signal import firwin

from curbside.configio import check, positive
from curbside.errors import CurbsideInputError


@dataclass(frozen=True)
class StepConfig:
    """Parameters of :class:`StepDetector` (defaults checked on the labelled set of ``docs/steps.md``).

    Attributes
    ----------
    rate_hz
        Grid rate. 50 Hz is the lowest rate phones log at; a footstep hump lasts 0.3-0.5 s.
    lowpass_hz
        Cut-off of the FIR low-pass. Walking cadence is 1.3-2.5 steps/s; 3 Hz keeps it and removes the
        heel-strike transients that split one hump into several.
    lowpass_taps
        FIR length (odd). 41 taps at 50 Hz span 0.8 s: a transition band of about 2 Hz.
    peak_halfwidth_s
        A candidate is the largest value within this on either side. 0.25 s merges the double peaks
        of one footstep and still separates footsteps at 2 steps/s.
    range_halfwidth_s
        Half-width of the window whose low-passed range scales the adaptive threshold.
    min_prominence_ms2
        Absolute floor (m/s^2) of a candidate's rise above its troughs. Sensor noise of a phone lying
        still is ~0.05 m/s^2; raising the floor to 0.8 loses 3 % of the footsteps of the IPIN walks.
    min_swing_ms2
        Least range (m/s^2) of the low-passed magnitude within ``range_halfwidth_s``. A standing person
        fidgeting with the phone swings it by under 1 m/s^2; 1.2 brings the footsteps found while
        standing on the 43 IPIN trials from 12 to 1 and loses 1 % of those found while walking.
    rel_prominence
        Rise above the troughs as a fraction of the local swing: 0.25 keeps the weaker leg's footstep
        with a phone in one trouser pocket, whose hump is a third of the other leg's.
    handling_gyro_rms_rads
        Candidates are dropped where the gyroscope's RMS rate exceeds this (rad/s). Hand-held walking
        stays under 2.2 rad/s on all 43 IPIN 2023 trials, a phone swung in the hand by +-60 degrees at
        1.8 steps/s turns at 4.2 rad/s RMS; the phone waved to calibrate its compass at the start of
        those trials turns at 3-13 rad/s (median 5.8).
    handling_halfwidth_s
        Half-width of the window of that RMS.
    min_interval_s, max_interval_s
        Footstep intervals that can link two candidates of a run: 0.25-1.1 s covers cadences from 55
        to 240 steps/min.
    max_interval_ratio
        An interval may differ from the pace (mean of the two before) by at most this factor. Walking
        paces change gradually; 1.5 passes the alternating intervals of a phone in a trouser pocket
        (0.44/0.70 s in the labelled set) and rejects the irregular bumps of handling.
    min_run
        Fewest linked candidates that count as walking. With 4, the IPIN 2023 trials show 12 footsteps
        while standing against 32 with 3 (before ``min_swing_ms2``); it sets most of
        :attr:`StepDetector.latency_s`.
    """

    rate_hz: float = 50.0
    lowpass_hz: float = 3.0
    lowpass_taps: int = 41
    peak_halfwidth_s: float = 0.25
    range_halfwidth_s: float = 0.75
    min_prominence_ms2: float = 0.5
    min_swing_ms2: float = 1.2
    rel_prominence: float = 0.25
    handling_gyro_rms_rads: float = 5.0
    handling_halfwidth_s: float = 0.75
    min_interval_s: float = 0.25
    max_interval_s: float = 1.1
    max_interval_ratio: float = 1.5
    min_run: int = 4

    def __post_init__(self) -> None:
        positive(self, "rate_hz", "lowpass_hz", "min_interval_s", "min_run")
        check(self.lowpass_hz < self.rate_hz / 2,
              f"lowpass_hz must be under half of rate_hz, got {self.lowpass_hz} and {self.rate_hz}")
        check(self.lowpass_taps >= 3 and self.lowpass_taps % 2 == 1,
              f"lowpass_taps must be odd and at least 3, got {self.lowpass_taps}")
        check(self.min_interval_s < self.max_interval_s, "min_interval_s must be under max_interval_s, got "
              f"{self.min_interval_s} and {self.max_interval_s}")

    @property
    def fir_margin_s(self) -> float:
        """Data needed on each side of a stretch to low-pass it exactly (half the FIR plus one grid step)."""
        return (self.lowpass_taps // 2 + 1) / self.rate_hz

    def samples(self, seconds: float) -> int:
        """Number of grid samples in ``seconds`` (at least 1)."""
        return max(1, int(round(seconds * self.rate_hz)))


def lowpass_taps(config: StepConfig) -> np.ndarray:
    """The FIR low-pass of ``config`` (Hamming window, unit DC gain)."""
    return firwin(config.lowpass_taps, config.lowpass_hz, fs=config.rate_hz)


#: Outputs up to which :func:`fir_centered` sums with one accumulate (faster for short signals only).
_FIR_ACCUMULATE_MAX = 128


def _windows(x: np.ndarray, width: int) -> np.ndarray:
    """Read-only view ``(len(x) - width + 1, width)`` whose row ``i`` is ``x[i : i + width]``."""
    return as_strided(x, (len(x) - width + 1, width), (x.strides[0],) * 2, writeable=False)


def fir_centered(x: np.ndarray, taps: np.ndarray) -> np.ndarray:
    """Centred FIR filter, ``y[i] = sum_k taps[k] * x[i + k]`` for ``len(x) - len(taps) + 1`` outputs.

    The sum runs over the taps in the same order for every output, so an output does not depend on
    which slice of a longer signal it is computed in (``np.convolve`` gives no such guarantee). A
    short signal (a streamed push) is summed by ``np.add.accumulate`` along each output's window, the
    same additions in the same order in a few calls instead of one per tap.
    """
    n = len(x) - len(taps) + 1
    if 0 < n <= _FIR_ACCUMULATE_MAX:
        return np.add.accumulate(_windows(x, len(taps)) * taps, axis=1)[:, -1]
    y = taps[0] * x[:n]
    for k in range(1, len(taps)):
        y = y + taps[k] * x[k : k + n]
    return y


class StepDetector:
    """Streaming footstep detector: push IMU rows as they come, get footstep times back.

    Parameters
    ----------
    config
        Parameters; :class:`StepConfig` defaults when ``None``.

    Attributes
    ----------
    latency_s
        A footstep at time ``t`` is reported once rows up to ``t + latency_s`` have been pushed.
    complete_until
        Every footstep at or before this time (s) has been reported (``-inf`` before the first row,
        ``inf`` after :meth:`finish`).

    Examples
    --------
    >>> detector = StepDetector()
    >>> steps = [detector.push(chunk.t, chunk.acc, chunk.gyro) for chunk in chunks]  # doctest: +SKIP
    >>> steps.append(detector.finish())  # doctest: +SKIP
    """

    def __init__(self, config: StepConfig | None = None) -> None:
        self.config = config or StepConfig()
        c = self.config
        self._taps = lowpass_taps(c)
        self._half_fir = c.lowpass_taps // 2
        self._w = c.samples(c.peak_halfwidth_s)
        self._range = c.samples(c.range_halfwidth_s)
        self._gyro_half = c.samples(c.handling_halfwidth_s)
        # Low-passed samples needed on each side of a candidate, and raw grid samples beyond those.
        self._lp_reach = max(self._range, 2 * self._w)
        self._reach = max(self._half_fir + self._lp_reach, self._gyro_half)
        self.latency_s = self._reach / c.rate_hz + (c.min_run - 1) * c.max_interval_s
        self.complete_until = -np.inf
        self._t0: float | None = None
        self._last: np.ndarray | None = None  # last accepted row: t, ax, ay, az, gyro^2
        self._use_gyro: bool | None = None
        self._n_grid = 0  # grid samples produced (absolute indices 0 .. n_grid - 1)
        self._buf0 = 0  # absolute index of _mag[0] (negative: left padding)
        self._mag = np.empty(0)
        self._gyro2 = np.empty(0)
        self._n_done = 0  # grid samples whose candidacy is decided
        self._run_len = 0  # candidates in the open run
        self._tail: list[float] = []  # its last three candidates (for the pace)
        self._pending: list[float] = []  # its candidates not reported yet (while shorter than min_run)
        self._finished = False

    # --- public API -------------------------------------------------------------------------------

    def push(self, t: np.ndarray, acc: np.ndarray, gyro: np.ndarray | None = None) -> np.ndarray:
        """Add IMU rows; return the footsteps (s, increasing) decided by them.

        Parameters
        ----------
        t
            Row times (s). Rows at or before the previous row's time are ignored, as are rows with a
            non-finite value.
        acc
            ``(N, 3)`` accelerations (m/s^2, gravity included).
        gyro
            ``(N, 3)`` rotation rates (rad/s) or ``None``. Give it in every push or in none.

        Returns
        -------
        numpy.ndarray
            New footstep times, later than every time returned before.

        Raises
        ------
        CurbsideInputError
            Shapes do not match, or the gyroscope is given in some pushes and not in others.
        RuntimeError
            :meth:`finish` was already called.
        """
        if self._finished:
            raise RuntimeError("StepDetector.push after finish(); make a new detector")
        rows = self._accept_rows(t, acc, gyro)
        if len(rows):
            self._extend_grid(rows)
        return self._decide(final=False)

    def finish(self) -> np.ndarray:
        """Decide the tail (the signal is held at its last value) and return its footsteps."""
        if self._finished:
            return np.empty(0)
        self._finished = True
        if self._t0 is None:
            self.complete_until = np.inf
            return np.empty(0)
        pad = self._reach + 1
        self._mag = np.concatenate([self._mag, np.repeat(self._mag[-1], pad)])
        self._gyro2 = np.concatenate([self._gyro2, np.repeat(self._gyro2[-1], pad)])
        out = self._decide(final=True)
        self.complete_until = np.inf
        return out

    # --- stage 1: rows onto the grid --------------------------------------------------------------

    def _accept_rows(self, t, acc, gyro) -> np.ndarray:
        """Rows as ``(N, 5)``: t, ax, ay, az, |gyro|^2 (0 without gyro), finite and strictly increasing."""
        t = np.asarray(t, float).reshape(-1)
        acc = np.asarray(acc, float).reshape(-1, 3) if np.size(acc) else np.empty((0, 3))
        if len(acc) != len(t):
            raise CurbsideInputError("imu", f"{len(t)} times but {len(acc)} accelerometer rows")
        has_gyro = gyro is not None
        if self._use_gyro is None and len(t):
            self._use_gyro = has_gyro
        elif len(t) and has_gyro != self._use_gyro:
            raise CurbsideInputError("imu", "the gyroscope must be given in every push or in none")
        if has_gyro:
            g = np.asarray(gyro, float).reshape(-1, 3) if np.size(gyro) else np.empty((0, 3))
            if len(g) != len(t):
                raise CurbsideInputError("imu", f"{len(t)} times but {len(g)} gyroscope rows")
            g2 = g[:, 0] * g[:, 0] + g[:, 1] * g[:, 1] + g[:, 2] * g[:, 2]
        else:
            g2 = np.zeros(len(t))
        rows = np.concatenate([t[:, None], acc, g2[:, None]], axis=1)
        if not np.isfinite(rows).all():
            rows = rows[np.isfinite(rows).all(axis=1)]
        if len(rows) == 0:
            return rows
        # Keep a row only if it is later than every row before it (a running maximum is the same
        # whichever way the rows were split, given the last accepted time).
        floor = -np.inf if self._last is None else self._last[0]
        if rows[0, 0] > floor and (len(rows) == 1 or (rows[1:, 0] > rows[:-1, 0]).all()):
            return rows  # increasing, as a live session's rows are: nothing to drop
        before = np.maximum.accumulate(np.concatenate([[floor], rows[:-1, 0]]))
        return rows[rows[:, 0] > before]

    def _extend_grid(self, rows: np.ndarray) -> None:
        c = self.config
        if self._t0 is None:
            self._t0 = float(rows[0, 0])
            first = rows[0]
            mag0 = np.sqrt(first[1] * first[1] + first[2] * first[2] + first[3] * first[3])
            pad = self._reach + self._half_fir + self._lp_reach + 1
            self._mag = np.repeat(mag0, pad)
            self._gyro2 = np.repeat(first[4], pad)
            self._buf0 = -pad
            self._last = first
            self._n_grid = 1
            self._mag = np.append(self._mag, mag0)
            self._gyro2 = np.append(self._gyro2, first[4])
            rows = rows[1:]
            if len(rows) == 0:
                return
        known = np.concatenate([self._last[None, :], rows])
        t_end = known[-1, 0]
        k_end = int((t_end - self._t0) * c.rate_hz)  # grid indices < k_end have times <= t_end
        while self._t0 + k_end / c.rate_hz <= t_end:
            k_end += 1
        while k_end > 0 and self._t0 + (k_end - 1) / c.rate_hz > t_end:
            k_end -= 1
        if k_end > self._n_grid:
            tg = self._t0 + np.arange(self._n_grid, k_end, dtype=float) / c.rate_hz
            j = np.searchsorted(known[:, 0], tg, side="right") - 1
            at_end = j == len(known) - 1  # a grid time equal to the last row's: take the row as it is
            j = np.minimum(j, len(known) - 2)
            lo, hi = known[j], known[j + 1]
            frac = (tg - lo[:, 0]) / (hi[:, 0] - lo[:, 0])
            vals = lo[:, 1:] + (hi[:, 1:] - lo[:, 1:]) * frac[:, None]
            vals[at_end] = known[-1, 1:]
            mag = np.sqrt(vals[:, 0] * vals[:, 0] + vals[:, 1] * vals[:, 1] + vals[:, 2] * vals[:, 2])
            self._mag = np.concatenate([self._mag, mag])
            self._gyro2 = np.concatenate([self._gyro2, vals[:, 3]])
            self._n_grid = k_end
        self._last = known[-1]

    # --- stages 2-4: candidates -------------------------------------------------------------------

    def _candidates(self, stop: int) -> np.ndarray:
        """Candidate grid indices in ``[self._n_done, stop)`` (absolute).

        Only the peaks (a few per second) get their troughs, swing and gyroscope RMS: a push of one row
        decides one grid sample, and computing those for every sample was most of its cost. Maxima and
        minima are exact in any order; the sums run in the order :func:`fir_centered` gives.
        """
        c = self.config
        start, n, reach = self._n_done, stop - self._n_done, self._lp_reach
        # Low-pass over [start - lp_reach, stop + lp_reach), from magnitudes half_fir further out.
        m0 = start - reach - self._half_fir - self._buf0
        m1 = stop + reach + self._half_fir - self._buf0
        lp = fir_centered(self._mag[m0:m1], self._taps)  # lp[i] is grid index start - lp_reach + i
        w, r = self._w, self._range
        near = _windows(lp[reach - w : reach + n + w], 2 * w + 1)  # row j: centred on j
        core = near[:, w]
        peaks = np.flatnonzero((core > near[:, :w].max(axis=1)) & (core >= near[:, w + 1 :].max(axis=1)))
        if not len(peaks):
            return peaks
        at = peaks + reach  # the peaks' positions in lp
        trough_l = lp[at[:, None] + np.arange(-2 * w, 0)].min(axis=1)
        trough_r = lp[at[:, None] + np.arange(1, 2 * w + 1)].min(axis=1)
        prominence = lp[at] - np.maximum(trough_l, trough_r)
        around = lp[at[:, None] + np.arange(-r, r + 1)]
        swing = around.max(axis=1) - around.min(axis=1)
        keep = swing >= c.min_swing_ms2
        keep &= prominence >= np.maximum(c.min_prominence_ms2, c.rel_prominence * swing)
        if self._use_gyro:
            g = self._gyro_half
            seg = self._gyro2[(start - self._buf0 + peaks)[:, None] + np.arange(-g, g + 1)]
            total = np.add.accumulate(seg, axis=1)[:, -1]
            keep &= total <= (2 * g + 1) * c.handling_gyro_rms_rads**2
        index = start + peaks[keep]
        return index[index >= 0]

    # --- stage 5: runs ----------------------------------------------------------------------------

    def _decide(self, final: bool) -> np.ndarray:
        c = self.config
        if self._t0 is None:
            return np.empty(0)
        stop = self._n_grid if final else self._n_grid - self._reach
        out: list[float] = []
        if stop > self._n_done:
            for i in self._candidates(stop):
                out.extend(self._link(self._t0 + i / c.rate_hz))
            self._n_done = stop
            self._trim()
        frontier = self._t0 + (self._n_done - 1) / c.rate_hz  # every candidate up to here is known
        if self._run_len and frontier - self._tail[-1] > c.max_interval_s:
            self._reset_run()  # nothing later can link to it
        if not final:
            self.complete_until = frontier - (c.min_run - 1) * c.max_interval_s
        return np.asarray(out, float)

    def _link(self, t: float) -> list[float]:
        """Add candidate ``t`` to the open run (or open a new one); return the footsteps it decides."""
        c = self.config
        if self._run_len:
            last = self._tail[-1]
            gap = t - last
            if gap < c.min_interval_s:  # too close to be another footstep: a second peak of the last one
                return []
            in_range = c.min_interval_s <= gap <= c.max_interval_s
            # The pace: the mean of the last two intervals (with a phone in one pocket, or a limp, they
            # alternate); a run's first two intervals are only checked against the range.
            pace = (last - self._tail[0]) / 2 if len(self._tail) == 3 else gap
            regular = in_range and max(gap, pace) <= c.max_interval_ratio * min(gap, pace)
            if not regular:
                last_reported = self._run_len >= c.min_run
                self._reset_run()
                if in_range:  # only the pace changed: the last candidate opens the next run
                    self._run_len, self._tail = 1, [last]
                    self._pending = [] if last_reported else [last]
        if self._run_len:
            self._run_len += 1
            self._tail = [*self._tail[-2:], t]
            self._pending.append(t)
        else:
            self._run_len, self._tail, self._pending = 1, [t], [t]
        if self._run_len < c.min_run:
            return []
        out, self._pending = self._pending, []
        return out

    def _reset_run(self) -> None:
        """Forget the open run; its unreported candidates (a run too short to be walking) are dropped."""
        self._run_len, self._tail, self._pending = 0, [], []

    def _trim(self) -> None:
        """Drop grid samples that no later decision can reach."""
        keep_from = self._n_done - self._reach - self._half_fir - self._lp_reach - 1
        cut = keep_from - self._buf0
        if cut > 4096:
            self._mag = self._mag[cut:]
            self._gyro2 = self._gyro2[cut:]
            self._buf0 += cut


def detect_steps(imu: pd.DataFrame, config: StepConfig | None = None) -> np.ndarray:
    """Footstep times of a whole recording: :class:`StepDetector` with every row pushed, then finished.

    Parameters
    ----------
    imu
        ``imu.csv`` table: ``t`` (s) and ``ax,ay,az`` (m/s^2, gravity included); ``gx,gy,gz`` (rad/s)
        are used when present.
    config
        Detector parameters (:class:`StepConfig` defaults when ``None``).

    Returns
    -------
    numpy.ndarray
        Increasing footstep times (s) on the ``imu`` clock; empty when nobody walks.

    Raises
    ------
    CurbsideInputError
        ``imu`` lacks ``t`` or an accelerometer column.
    """
    missing = [col for col in ("t", "ax", "ay", "az") if col not in imu.columns]
    if missing:
        raise CurbsideInputError("imu.csv", f"footstep detection needs the columns {', '.join(missing)}")
    gyro = imu[["gx", "gy", "gz"]].to_numpy(float) if {"gx", "gy", "gz"} <= set(imu.columns) else None
    detector = StepDetector(config)
    first = detector.push(imu["t"].to_numpy(float), imu[["ax", "ay", "az"]].to_numpy(float), gyro)
    return np.concatenate([first, detector.finish()])
