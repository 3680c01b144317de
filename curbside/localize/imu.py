"""IMU preprocessing for learned inertial odometry: phone-frame samples to a gravity-aligned world frame.

The RoNIN input is the gyroscope and the accelerometer (gravity kept) expressed in a world frame whose
z axis is up and whose yaw is whatever the orientation source says (the game rotation vector's
arbitrary yaw, or magnetic north for Android's rotation vector). :class:`WorldFrameStream` turns
``imu.csv`` rows, pushed in chunks of any size, into such samples at the input sample times. Every
decision depends only on data within a bounded horizon, so the output is **bit-identical whatever
the chunking** (a live session streamed in small batches gives what the whole file gives):

1. **Validation** (per chunk, before anything changes). The accelerometer and gyroscope columns are
   required, and a chunk must have the columns of the first one. Rows holding NaN/inf (or an
   all-zero quaternion) are dropped and their hole treated like any other gap. Timestamps must
   increase strictly, across chunks too.
2. **Start-up decision** on the first :attr:`ImuConfig.decision_s` seconds of data (gaps not
   counted), then held for the whole stream: the rate must reach :attr:`ImuConfig.min_rate_hz`, the
   gyroscope must not read exactly zero throughout (loggers fill the column when the sensor is
   absent), and the quaternion convention is chosen (:func:`detect_quaternion_order`). Nothing is
   emitted before the decision.
3. **Gaps.** A gap longer than :attr:`ImuConfig.max_gap_s` starts a new segment (its number is
   emitted with every sample); shorter gaps are bridged by the resampling downstream.
4. **Orientation.** With ``qx,qy,qz,qw`` the quaternion, read in the chosen convention. Without it
   the gyroscope is integrated causally per segment
   (:class:`~curbside.localize.gyro.GyroscopeIntegrator`).
5. **Saturation.** A sample where a channel sits in a flat top above a plausible floor (three equal
   values in a row above 2 g or 4 rad/s) counts as saturated (:func:`saturation_mask`); the count is
   kept and logged, values are left as clipped by the sensor.

Resampling onto the model's clock and cutting windows is :mod:`curbside.localize.ronin.stream`.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
import pandas as pd
from scipy.spatial.transform import Rotation

from curbside.errors import CurbsideInputError
from curbside.localize.gyro import GyroscopeIntegrator, norm_rows, rotate_vectors

logger = logging.getLogger(__name__)

ACC_COLUMNS = ("ax", "ay", "az")
GYRO_COLUMNS = ("gx", "gy", "gz")
QUAT_COLUMNS = ("qx", "qy", "qz", "qw")
WORLD_COLUMNS = ("wgx", "wgy", "wgz", "wax", "way", "waz")

#: The four readings of a logged quaternion tried by :func:`detect_quaternion_order`: column
#: permutation into scipy's scalar-last order, and whether the rotation is world-to-device.
QUATERNION_READINGS: dict[str, tuple[tuple[int, int, int, int], bool]] = {
    "xyzw": ((0, 1, 2, 3), False),
    "wxyz": ((1, 2, 3, 0), False),
    "xyzw-inverse": ((0, 1, 2, 3), True),
    "wxyz-inverse": ((1, 2, 3, 0), True),
}

@dataclass(frozen=True)
class ImuConfig:
    """Parameters of the IMU preprocessing (recorded in a run's ``run.json``).

    Attributes
    ----------
    max_gap_s
        Longest gap bridged by interpolation; a longer one splits the stream into segments. 0.5 s:
        a phone's sensor hub drops batches of a few hundred milliseconds, a walker moves < 1 m.
    min_rate_hz
        Lowest accepted IMU rate; slower logs cannot resolve footsteps (a step lasts ~0.5 s).
    decision_s
        Seconds of data (gaps not counted) on which the rate, the gyroscope and the quaternion
        convention are judged before anything is emitted. 2 s spans about four footsteps, over
        which the walking accelerations average out against gravity; it is also the start-up
        latency of a stream.
    saturation_floor_accel_ms2, saturation_floor_gyro_rads
        A flat top counts as clipping only above these magnitudes (2 g; 4 rad/s, the lowest full
        scales of phone IMUs are 2 g and 250 deg/s); flat tops below are quantisation.
    saturation_min_repeats
        Equal consecutive values that make a flat top.
    tilt_window_s
        Trailing window of the gravity estimate that holds the gyroscope-integrated tilt.
    quaternion_tolerance_deg
        The SPEC quaternion reading is kept while the mean specific force over the decision window
        lies within this angle of up (:func:`detect_quaternion_order`). Over the first 2 s of the
        913 MS Indoor and IPIN 2023 recordings (all SPEC order) that angle has a median of 1.6
        degrees, a 99th percentile of 5.0 and a maximum of 12.3 (a start with a jolt); a wrongly
        read quaternion tilts it by twice the phone's tilt, or far more.
    """

    max_gap_s: float = 0.5
    min_rate_hz: float = 20.0
    decision_s: float = 2.0
    saturation_floor_accel_ms2: float = 19.6
    saturation_floor_gyro_rads: float = 4.0
    saturation_min_repeats: int = 3
    tilt_window_s: float = 2.0
    quaternion_tolerance_deg: float = 15.0


@dataclass(frozen=True)
class WorldSamples:
    """World-frame IMU samples at their input times, as emitted by :class:`WorldFrameStream`.

    Attributes
    ----------
    t
        ``(N,)`` sample times (s), increasing.
    values
        ``(N, 6)`` world-frame gyroscope (rad/s) then specific force (m/s^2, gravity on +z).
    segment
        ``(N,)`` segment number; it increases by one after every gap longer than ``max_gap_s``.
    """

    t: np.ndarray
    values: np.ndarray
    segment: np.ndarray

    @classmethod
    def empty(cls) -> WorldSamples:
        """No samples."""
        return cls(np.zeros(0), np.zeros((0, 6)), np.zeros(0, np.int64))

    @classmethod
    def concatenate(cls, parts: list[WorldSamples]) -> WorldSamples:
        """The parts one after the other."""
        if not parts:
            return cls.empty()
        return cls(np.concatenate([p.t for p in parts]), np.concatenate([p.values for p in parts]),
                   np.concatenate([p.segment for p in parts]))


def saturation_mask(values: np.ndarray, floors: np.ndarray, min_repeats: int = 3) -> np.ndarray:
    """Flag samples in a flat top: ``min_repeats`` equal consecutive values above a floor.

    A clipped channel repeats its full-scale value exactly; a real signal above 2 g changes from one
    sample to the next. The rule looks ``min_repeats - 1`` samples either side, no further.

    Parameters
    ----------
    values
        ``(N, C)`` raw sensor values.
    floors
        ``(C,)`` smallest absolute value that may be a saturation level (e.g. 2 g for an
        accelerometer): flat tops below it are quantisation, not clipping.
    min_repeats
        How many equal consecutive samples make a flat top.

    Returns
    -------
    numpy.ndarray
        ``(N,)`` bool, True where any channel is in a flat top.
    """
    n = len(values)
    flagged = np.zeros(n, dtype=bool)
    if n < min_repeats:
        return flagged
    same = (values[1:] == values[:-1]) & (np.abs(values[1:]) >= floors)  # (N-1, C)
    runs = np.lib.stride_tricks.sliding_window_view(same, min_repeats - 1, axis=0).all(axis=-1).any(axis=1)
    for k in range(min_repeats):  # a run starting at i covers samples i .. i + min_repeats - 1
        flagged[k : k + len(runs)] |= runs
    return flagged


def detect_quaternion_order(acc: np.ndarray, quat: np.ndarray, source: str = "imu",
                            tolerance_deg: float = 15.0) -> str:
    """Which reading of the logged quaternion columns makes the accelerometer point up.

    A phone's accelerometer measures the specific force, which averages to +g along the world's up
    axis. The SPEC reading (``qx,qy,qz,qw``, device to world) is kept while it brings the mean
    specific force within ``tolerance_deg`` of up; otherwise the reading of
    :data:`QUATERNION_READINGS` that aligns it best is used (with a warning). Gravity cannot tell a
    level phone's rotation from its inverse (both keep z up; only the sign of the yaw differs), so
    the SPEC reading is never traded for a reading that is merely a little better aligned: over a
    couple of seconds the walker's own acceleration tilts the mean by a few degrees.

    Parameters
    ----------
    acc
        ``(N, 3)`` accelerometer in the device frame, m/s^2 with gravity.
    quat
        ``(N, 4)`` the four quaternion columns as logged (``qx,qy,qz,qw`` by SPEC).
    source
        Name used in messages.
    tolerance_deg
        Largest angle between the mean specific force and up that the SPEC reading may leave.

    Returns
    -------
    str
        A key of :data:`QUATERNION_READINGS`; ``"xyzw"`` is the SPEC convention.

    Raises
    ------
    CurbsideInputError
        Not unit quaternions, or no reading brings gravity within 30 degrees of up.
    """
    acc, quat = np.array(acc, dtype=float), np.array(quat, dtype=float)  # writable copies for scipy
    norms = norm_rows(quat)
    if not (np.abs(norms - 1.0) < 0.05).mean() > 0.95:
        raise CurbsideInputError(
            source, f"quaternion columns are not unit quaternions (median norm {np.median(norms):.3f})"
        )
    tilt_deg = {}
    for name, (perm, inverse) in QUATERNION_READINGS.items():
        rot = Rotation.from_quat(quat[:, list(perm)])
        rot = rot.inv() if inverse else rot
        mean_up = rot.apply(acc).mean(axis=0)
        cosine = mean_up[2] / max(np.linalg.norm(mean_up), 1e-9)
        tilt_deg[name] = float(np.degrees(np.arccos(np.clip(cosine, -1.0, 1.0))))
    if tilt_deg["xyzw"] <= tolerance_deg:
        return "xyzw"
    best = min(tilt_deg, key=lambda k: tilt_deg[k])
    if tilt_deg[best] > 30.0:
        raise CurbsideInputError(
            source, "no quaternion convention rotates the accelerometer's gravity to up: not an orientation"
        )
    if best != "xyzw":
        logger.warning("%s: quaternion columns read as %s (gravity %.0f degrees from up as qx,qy,qz,qw, "
                       "%.0f as %s)", source, best, tilt_deg["xyzw"], tilt_deg[best], best)
    return best


def _check_columns(columns: set, source: str) -> bool:
    missing_gyro = [c for c in GYRO_COLUMNS if c not in columns]
    if missing_gyro:
        raise CurbsideInputError(source, f"no gyroscope: missing column(s) {missing_gyro}")
    missing = [c for c in ("t", *ACC_COLUMNS) if c not in columns]
    if missing:
        raise CurbsideInputError(source, f"missing column(s) {missing}")
    has_q = [c in columns for c in QUAT_COLUMNS]
    if any(has_q) and not all(has_q):
        raise CurbsideInputError(source, "partial quaternion columns: need all of qx,qy,qz,qw or none")
    return all(has_q)


def low_rate_problem(median_interval_s: float, min_rate_hz: float) -> str | None:
    """What is wrong with an IMU whose rows come ``median_interval_s`` apart (``None``: nothing).

    Rows 2 s to 1000 s apart are an IMU of 1-500 Hz whose ``t`` counts milliseconds from the app's
    start (the epoch-sized times that :func:`curbside.localize.live_input.check_time_value` refuses are
    the other milliseconds), so the message asks.
    """
    rate_hz = 1.0 / median_interval_s
    if rate_hz >= min_rate_hz:
        return None
    hint = ""
    if 2.0 <= median_interval_s <= 1000.0:
        hint = f" (rows {median_interval_s:g} s apart: is t in milliseconds? it must be in seconds)"
    rate = f"{rate_hz:.1f}" if rate_hz >= 0.1 else f"{rate_hz:.2g}"  # 0.05 Hz is not "0.1 Hz"
    return f"IMU rate {rate} Hz is below the {min_rate_hz:g} Hz minimum for RoNIN{hint}"


#: Intervals after which a stream whose every row is a gap from the one before (a 1 Hz log) is judged.
MIN_DECISION_INTERVALS = 10


class RepeatedWarning:
    """A warning that may recur once per gap of a stream: the first :attr:`SHOWN` are logged, the rest at
    DEBUG (``-vv``), and :meth:`finish` says in one line how many more there were. A phone logging at
    1 Hz has a gap between every two rows: one line each was hundreds of lines.

    Parameters
    ----------
    log
        The logger of the module that warns.
    source
        The stream's name, the first word of the summary line.
    what
        What one occurrence is, plural (``"gaps that split the recording"``).
    """

    SHOWN = 3

    def __init__(self, log: logging.Logger, source: str, what: str) -> None:
        self.log, self.source, self.what = log, source, what
        self.count = 0

    def warn(self, message: str, *args: object) -> None:
        """One occurrence: ``log.warning(message, *args)`` for the first :attr:`SHOWN`."""
        self.count += 1
        level = logging.WARNING if self.count <= self.SHOWN else logging.DEBUG
        self.log.log(level, message, *args)

    def finish(self) -> None:
        """The stream has ended: say how many occurrences were not shown."""
        if self.count > self.SHOWN:
            extra = self.count - self.SHOWN
            self.log.warning("%s: %d more %s (-vv lists each)", self.source, extra, self.what)


class WorldFrameStream:
    """Phone IMU rows in, world-frame samples out, chunk by chunk (see the module docstring).

    Parameters
    ----------
    config
        Preprocessing parameters (defaults: :class:`ImuConfig`).
    source
        Name used in messages (the file or the session).

    Examples
    --------
    >>> stream = WorldFrameStream(source="walk/imu.csv")  # doctest: +SKIP
    >>> for chunk in chunks:
    ...     stream.push(chunk)
    ...     samples = stream.take()
    >>> stream.finish(); tail = stream.take()
    """

    def __init__(self, config: ImuConfig | None = None, source: str = "imu.csv") -> None:
        self.config = config or ImuConfig()
        self.source = source
        #: Quaternion reading chosen at start-up (a key of :data:`QUATERNION_READINGS`), None without one.
        self.quaternion_order: str | None = None
        #: Samples found in a flat top so far (final up to ``saturation_min_repeats - 1`` samples back).
        self.saturated_samples = 0
        self.finished = False
        self._columns: list[str] | None = None
        self._rows_seen = 0
        self._decided = False
        self._pending = np.zeros((0, 0))  # rows held until the start-up decision
        self._last_t = -np.inf  # last row accepted
        self._emitted_t = -np.inf  # last row emitted
        self._segment = -1
        self._gaps = RepeatedWarning(logger, source, "gaps that split the recording")
        self._integrator: GyroscopeIntegrator | None = None
        self._sat_buffer = np.zeros((0, 6))
        self._sat_final = 0
        self._out: list[WorldSamples] = []

    @property
    def has_quaternion(self) -> bool:
        """Whether the rows carry ``qx,qy,qz,qw`` (known after the first push)."""
        return self._columns is not None and len(self._columns) == 11

    @property
    def next_time(self) -> float:
        """Time of the first row not yet emitted (``inf`` when none is held back)."""
        return float(self._pending[0, 0]) if len(self._pending) else np.inf

    def push(self, imu: pd.DataFrame) -> None:
        """Append rows ``t,ax,ay,az,gx,gy,gz[,qx,qy,qz,qw]`` (SPEC ``imu.csv``), any number.

        Raises
        ------
        CurbsideInputError
            Missing or changed columns, non-numeric values, timestamps not increasing (the stream
            is left as it was); at the start-up decision: rate below ``min_rate_hz``, all-zero
            gyroscope, unusable quaternion (the stream is then unusable).
        """
        if self.finished:
            raise RuntimeError("push() after finish()")
        rows = self._validate(imu)
        self._count_saturation(rows[:, 1:7], final=False)
        self._pending = rows if not len(self._pending) else np.vstack([self._pending, rows])
        self._advance(final=False)

    def finish(self) -> None:
        """Declare the end of the stream: decide on what there is and emit everything held back."""
        if self.finished:
            return
        self.finished = True
        self._count_saturation(np.zeros((0, 6)), final=True)
        self._advance(final=True)
        self._gaps.finish()
        if self.saturated_samples:
            logger.warning("%s: %d sample(s) at a sensor's saturation value; velocities there are "
                           "unreliable", self.source, self.saturated_samples)

    def take(self) -> WorldSamples:
        """World-frame samples emitted since the last call, removed from the stream."""
        out = WorldSamples.concatenate(self._out)
        self._out = []
        return out

    def _validate(self, imu: pd.DataFrame) -> np.ndarray:
        has_quat = _check_columns(set(imu.columns), self.source)
        columns = ["t", *ACC_COLUMNS, *GYRO_COLUMNS] + (list(QUAT_COLUMNS) if has_quat else [])
        if self._columns is not None and columns != self._columns:
            raise CurbsideInputError(self.source, "the columns changed from one chunk to the next")
        names = list(imu.columns)
        try:
            try:  # the fast path: a numeric table (selecting columns in pandas costs ~10x more)
                values = imu.to_numpy(dtype=float)[:, [names.index(c) for c in columns]]
            except (ValueError, TypeError):
                values = imu[columns].apply(pd.to_numeric, errors="raise").to_numpy(dtype=float)
        except (ValueError, TypeError) as exc:
            raise CurbsideInputError(self.source, f"non-numeric value ({exc})") from None
        usable = np.isfinite(values).all(axis=1)
        if has_quat:
            usable &= norm_rows(values[:, 7:]) > 0.0
        if not usable.all():
            logger.warning("%s: %d row(s) with NaN/inf or a zero quaternion dropped; their holes are "
                           "handled as gaps", self.source, int((~usable).sum()))
        row_number = self._rows_seen + 1 + np.flatnonzero(usable)
        values = values[usable]
        t = np.concatenate([[self._last_t], values[:, 0]])
        bad = np.flatnonzero(np.diff(t) <= 0)
        if len(bad):
            raise CurbsideInputError(self.source, f"timestamps not strictly increasing at data row "
                                                  f"{row_number[bad[0]]} (t={float(t[bad[0] + 1])!r})")
        self._columns = columns
        self._rows_seen += len(imu)
        if len(values):
            self._last_t = values[-1, 0]
        return values

    def _count_saturation(self, raw: np.ndarray, final: bool) -> None:
        repeats = self.config.saturation_min_repeats
        buffer = np.vstack([self._sat_buffer, raw])
        floors = np.array([self.config.saturation_floor_accel_ms2] * 3
                          + [self.config.saturation_floor_gyro_rads] * 3)
        final_end = len(buffer) if final else max(len(buffer) - (repeats - 1), 0)
        found = int(saturation_mask(buffer, floors, repeats)[self._sat_final : final_end].sum())
        if found and not self.saturated_samples:
            logger.warning("%s: a sensor sits at its saturation value near t=%.2f s", self.source,
                           self._last_t)
        self.saturated_samples += found
        drop = max(len(buffer) - 2 * (repeats - 1), 0)
        self._sat_buffer = buffer[drop:]
        self._sat_final = max(final_end - drop, 0)

    def _decision_rows(self, final: bool) -> int | None:
        """Rows of the start-up decision window, or None while more data is needed."""
        t = self._pending[:, 0]
        dt = np.diff(t)
        covered = np.concatenate([[0.0], np.cumsum(np.where(dt <= self.config.max_gap_s, dt, 0.0))])
        enough = np.flatnonzero(covered >= self.config.decision_s)
        if len(enough):
            return int(enough[0]) + 1
        if len(dt) >= MIN_DECISION_INTERVALS and not np.any(dt <= self.config.max_gap_s):
            return len(t)  # rows that all come further apart than a gap never cover decision_s
        return len(t) if final and len(t) else None

    def _decide(self, rows: np.ndarray) -> None:
        dt = np.diff(rows[:, 0])
        if np.any(dt <= self.config.max_gap_s):
            dt = dt[dt <= self.config.max_gap_s]
        # else every row is a gap from the one before (a 1 Hz log): the rate is theirs
        if len(dt):
            problem = low_rate_problem(float(np.median(dt)), self.config.min_rate_hz)
            if problem is not None:
                raise CurbsideInputError(self.source, problem)
        if not np.any(rows[:, 4:7]):
            raise CurbsideInputError(self.source, "gyroscope columns are all zero: no gyroscope data")
        if self.has_quaternion:
            self.quaternion_order = detect_quaternion_order(rows[:, 1:4], rows[:, 7:11], self.source,
                                                            self.config.quaternion_tolerance_deg)
        self._decided = True

    def _advance(self, final: bool) -> None:
        if not len(self._pending):
            return
        if not self._decided:
            n = self._decision_rows(final)
            if n is None:
                return
            self._decide(self._pending[:n])
        rows, self._pending = self._pending, self._pending[:0]
        t = rows[:, 0]
        new_segment = np.diff(t, prepend=self._emitted_t) > self.config.max_gap_s
        for start, stop in _runs(new_segment):
            if new_segment[start]:
                self._start_segment(t[start], t[start - 1] if start else self._emitted_t)
            self._out.append(self._to_world(rows[start:stop]))
        self._emitted_t = t[-1]

    def _start_segment(self, t0: float, previous: float) -> None:
        if self._segment >= 0:
            self._gaps.warn("%s: %.2f s gap at t=%.2f s splits the recording", self.source, t0 - previous,
                            previous)
        self._segment += 1
        self._integrator = GyroscopeIntegrator(self.config.tilt_window_s)

    def _to_world(self, rows: np.ndarray) -> WorldSamples:
        acc, gyro = rows[:, 1:4], rows[:, 4:7]
        if self.has_quaternion:
            perm, inverse = QUATERNION_READINGS[self.quaternion_order]
            quat = rows[:, 7:11][:, list(perm)]
            quat = quat / norm_rows(quat)[:, None]
            if inverse:
                quat[:, :3] = -quat[:, :3]
        else:
            quat = self._integrator.update(rows[:, 0], gyro, acc).as_quat()
        values = np.hstack([rotate_vectors(quat, gyro), rotate_vectors(quat, acc)])
        return WorldSamples(rows[:, 0].copy(), values, np.full(len(rows), self._segment))


def _runs(new_segment: np.ndarray) -> list[tuple[int, int]]:
    """``(start, stop)`` of the stretches of rows between segment starts."""
    cuts = np.concatenate([[0], np.flatnonzero(new_segment[1:]) + 1, [len(new_segment)]])
    return [(int(a), int(b)) for a, b in zip(cuts[:-1], cuts[1:], strict=True) if b > a]


def world_frame_segments(imu: pd.DataFrame, source: str = "imu.csv", config: ImuConfig | None = None,
                         min_duration_s: float = 1.0) -> list[pd.DataFrame]:
    """A whole ``imu.csv`` table through :class:`WorldFrameStream`, split into segments.

    Parameters
    ----------
    imu
        ``t,ax,ay,az,gx,gy,gz[,qx,qy,qz,qw]`` (SPEC ``imu.csv``).
    source
        File name used in messages.
    config
        Preprocessing parameters.
    min_duration_s
        Segments shorter than this are dropped (with a warning).

    Returns
    -------
    list of pandas.DataFrame
        Per segment: ``t, wgx, wgy, wgz, wax, way, waz`` at the input sample times.

    Raises
    ------
    CurbsideInputError
        Bad input (see :meth:`WorldFrameStream.push`), or no segment lasts ``min_duration_s``.
    """
    stream = WorldFrameStream(config, source)
    stream.push(imu)
    stream.finish()
    samples = stream.take()
    segments = []
    for seg in np.unique(samples.segment):
        inside = samples.segment == seg
        t = samples.t[inside]
        if t[-1] - t[0] < min_duration_s:
            logger.warning("%s: dropped a %.2f s segment at t=%.2f (too short)", source, t[-1] - t[0], t[0])
            continue
        frame = pd.DataFrame(samples.values[inside], columns=list(WORLD_COLUMNS))
        frame.insert(0, "t", t)
        segments.append(frame)
    if not segments:
        raise CurbsideInputError(source, f"no stretch of IMU data without gaps lasts {min_duration_s:g} s")
    return segments
