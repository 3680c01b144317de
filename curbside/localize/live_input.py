"""What a live session accepts: the columns of its batches, its limits, and the checks on each batch.

Validation (:func:`check_imu`, :func:`check_gnss`) follows
:func:`curbside.localize.session.validate_table` (finite values, strictly increasing ``t`` per stream,
across pushes too, lat/lon in range) and adds unit checks a live feed needs: accelerations in m/s²
with gravity (the median ``|a|`` between 4 and 25 m/s²: 1 means g, ~0 means gravity removed; taken over
a batch and the rows before it, at least a second of them, since a walker's single rows range from 0.6
to 34 m/s²), rotation rates in rad/s (no component above 35 rad/s, the 2000 °/s full scale of phone
gyroscopes), unit quaternions, times that read as seconds (``|t|`` under :data:`MAX_ABS_T_S`: epoch
milliseconds or nanoseconds are not), and no time jump or clock mismatch that would make the engine fill
hours of updates. A batch that fails changes nothing.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from curbside.errors import CurbsideInputError

#: Columns of an IMU batch without and with the orientation quaternion (SPEC ``imu.csv``).
IMU_COLUMNS = ("t", "ax", "ay", "az", "gx", "gy", "gz")
IMU_QUAT_COLUMNS = (*IMU_COLUMNS, "qx", "qy", "qz", "qw")
#: Columns of a GNSS batch (SPEC ``gnss.csv``); ``accuracy_m`` NaN or <= 0 marks an invalid fix.
GNSS_COLUMNS = ("t", "lat", "lon", "accuracy_m")
#: Largest ``|t|`` a row (or a start pose) may have, s: Unix time in seconds is 1.7e9 today, in
#: milliseconds 1.7e12. Larger values also break the stages' float arithmetic (a 1 s window is below
#: the resolution of a float at 1e20).
MAX_ABS_T_S = 1e10


def check_time_value(t: float, where: str) -> None:
    """Raise :class:`CurbsideInputError` (naming ``where``) unless ``t`` reads as seconds on a clock.

    Parameters
    ----------
    t
        A time, s.
    where
        The field, for the message (``imu[3].t``, ``start.t``).
    """
    if not math.isfinite(t):
        raise CurbsideInputError(where, "not a finite number")
    if abs(t) >= MAX_ABS_T_S:
        bound = f"{MAX_ABS_T_S:.0e}".replace("e+", "e")
        raise CurbsideInputError(
            where,
            f"t={float(t)!r} is not seconds on a clock (|t| must be under {bound} s; milliseconds or "
            "nanoseconds?)",
        )


@dataclass(frozen=True)
class LiveLimits:
    """What a live session accepts, and how long fixes may lag the IMU.

    These bound the input, not the method: a run's result does not depend on them (``run.json``
    records the method's parameters).

    Attributes
    ----------
    fix_delay_s
        A fix may arrive this long after the IMU rows of its time (see the module docstring). Adds
        to the estimate's lag.
    max_time_jump_s
        Largest step of ``t`` between consecutive rows of a stream (the engine fills gaps on a 1 s
        grid: a jump of days would be millions of updates).
    max_clock_skew_s
        A fix may not be further than this ahead of the latest IMU row (the streams share one clock).
    max_fix_distance_m
        A fix further than this from the map's extent (or, without a map, from the session's frame
        origin point) is rejected: lat/lon in radians or swapped land far away.
    gravity_range_ms2
        The median ``|a|`` of an IMU batch and the rows before it (:attr:`gravity_window_rows` in all)
        must lie in this range (m/s²; gravity is 9.81).
    gravity_window_rows, gravity_min_rows
        The rows that median is taken over (a batch and the rows before it; a whole batch when it is
        longer), and the fewest it is judged on: a session's first rows are judged once this many are in.
        On IPIN 2023 walks the median of 5 consecutive rows leaves the range once in 260, of 25 never.
    max_gyro_rads
        No rotation-rate component may exceed this (rad/s).
    quaternion_norm_tolerance
        ``| |q| - 1 |`` allowed for the orientation quaternion.
    stall_warning_s
        Seconds of data after which an estimate warns that the filter waits: for IMU rows (none yet, or
        none for this long while fixes come), or, without a start pose, for a first usable fix.
    """

    fix_delay_s: float = 1.0
    max_time_jump_s: float = 600.0
    max_clock_skew_s: float = 60.0
    max_fix_distance_m: float = 50_000.0
    gravity_range_ms2: tuple[float, float] = (4.0, 25.0)
    max_gyro_rads: float = 35.0
    quaternion_norm_tolerance: float = 0.1
    gravity_window_rows: int = 50
    gravity_min_rows: int = 25
    stall_warning_s: float = 10.0


def _check_times(t: np.ndarray, last_t: float, max_jump_s: float, source: str) -> None:
    """Times (finite: checked before) that read as seconds, increase, and jump at most ``max_jump_s``."""
    huge = np.abs(t) >= MAX_ABS_T_S
    if huge.any():
        i = int(np.argmax(huge))
        check_time_value(float(t[i]), f"{source}[{i}].t")
    dt = np.diff(np.concatenate([[last_t], t])) if math.isfinite(last_t) else np.diff(t)
    offset = 0 if math.isfinite(last_t) else 1
    if (dt <= 0).any():
        i = int(np.argmax(dt <= 0))
        before = last_t if i + offset == 0 else float(t[i + offset - 1])
        raise CurbsideInputError(
            f"{source}[{i + offset}].t",
            f"{float(t[i + offset])!r} is not after the previous row's {before!r} (time must increase)",
        )
    if (dt > max_jump_s).any():
        i = int(np.argmax(dt > max_jump_s))
        raise CurbsideInputError(
            f"{source}[{i + offset}].t",
            f"jumps {float(dt[i]):.0f} s past the previous row (more than {max_jump_s:g} s: another clock?)",
        )


def _row_norms(values: np.ndarray) -> np.ndarray:
    """``np.linalg.norm(values, axis=1)`` computed as it does, without its overhead (a batch may be
    one row)."""
    return np.sqrt(np.add.reduce(values * values, axis=1))


def accel_norms(values: np.ndarray) -> np.ndarray:
    """``|a|`` (m/s²) of IMU rows in :data:`IMU_COLUMNS` order (the gravity check's input)."""
    return _row_norms(values[:, 1:4])


def check_imu(
    values: np.ndarray,
    last_t: float,
    limits: LiveLimits,
    source: str = "imu",
    recent_norms: np.ndarray | None = None,
) -> None:
    """Raise :class:`CurbsideInputError` unless an IMU batch is usable (see the module docstring).

    Parameters
    ----------
    values
        ``(N, 7)`` or ``(N, 11)`` rows in :data:`IMU_COLUMNS` / :data:`IMU_QUAT_COLUMNS` order.
    last_t
        Time of the session's previous IMU row (``-inf`` before the first).
    limits
        The bounds.
    source
        Name of the batch in messages (``imu[12].ax``...).
    recent_norms
        ``|a|`` of the session's latest accepted rows (:func:`accel_norms`), oldest first: the gravity
        check takes its median over them and the batch, so that a batch of a few rows is not judged
        alone.
    """
    finite = np.isfinite(values)
    if not finite.all():
        row, col = np.argwhere(~finite)[0]
        raise CurbsideInputError(f"{source}[{row}].{IMU_QUAT_COLUMNS[col]}", "not a finite number")
    _check_times(values[:, 0], last_t, limits.max_time_jump_s, source)
    _check_gravity(values, limits, source, recent_norms)
    gyro = np.abs(values[:, 4:7])
    if (gyro > limits.max_gyro_rads).any():
        row, col = np.argwhere(gyro > limits.max_gyro_rads)[0]
        raise CurbsideInputError(
            f"{source}[{row}].{IMU_COLUMNS[4 + col]}",
            f"{values[row, 4 + col]:g} rad/s exceeds {limits.max_gyro_rads:g}: rotation rates must be "
            "in rad/s (deg/s?)",
        )
    if values.shape[1] == len(IMU_QUAT_COLUMNS):
        norm = _row_norms(values[:, 7:11])
        bad = np.abs(norm - 1.0) > limits.quaternion_norm_tolerance
        if bad.any():
            row = int(np.argmax(bad))
            raise CurbsideInputError(
                f"{source}[{row}].qx,qy,qz,qw", f"norm {norm[row]:.3g}: expected a unit quaternion"
            )


def _check_gravity(
    values: np.ndarray, limits: LiveLimits, source: str, recent_norms: np.ndarray | None
) -> None:
    norms = accel_norms(values)
    if recent_norms is not None and len(norms) < limits.gravity_window_rows:
        norms = np.concatenate([recent_norms, norms])[-limits.gravity_window_rows :]
    if len(norms) < limits.gravity_min_rows:
        return  # a session's first few rows: judged once there are enough
    low, high = limits.gravity_range_ms2
    ordered = np.sort(norms)  # the median as np.median gives it, at a tenth of its cost
    mid = len(ordered) // 2
    median_g = float(ordered[mid] if len(ordered) % 2 else (ordered[mid - 1] + ordered[mid]) / 2)
    if not low <= median_g <= high:
        hint = (
            "in g, not m/s²?" if 0.7 < median_g < 1.5 else "gravity removed?" if median_g < low else "units?"
        )
        raise CurbsideInputError(
            f"{source}.ax,ay,az",
            f"median |a| is {median_g:.2f} m/s² over the latest {len(norms)} rows; expected m/s² with "
            f"gravity (~9.8) ({hint})",
        )


def check_gnss(values: np.ndarray, last_t: float, limits: LiveLimits, source: str = "gnss") -> None:
    """Raise :class:`CurbsideInputError` unless a GNSS batch is usable.

    Parameters
    ----------
    values
        ``(N, 4)`` rows ``t, lat, lon, accuracy_m`` (accuracy NaN: an invalid fix, allowed).
    last_t
        Time of the session's previous fix (``-inf`` before the first).
    limits
        The bounds.
    source
        Name of the batch in messages.
    """
    finite = np.isfinite(values[:, :3])
    if not finite.all():
        row, col = np.argwhere(~finite)[0]
        raise CurbsideInputError(f"{source}[{row}].{GNSS_COLUMNS[col]}", "not a finite number")
    if np.isinf(values[:, 3]).any():
        raise CurbsideInputError(
            f"{source}[{int(np.argmax(np.isinf(values[:, 3])))}].accuracy_m",
            "infinite (use null for an unknown accuracy)",
        )
    _check_times(values[:, 0], last_t, limits.max_time_jump_s, source)
    bad = (np.abs(values[:, 1]) > 90) | (np.abs(values[:, 2]) > 180)
    if bad.any():
        row = int(np.argmax(bad))
        raise CurbsideInputError(
            f"{source}[{row}].lat,lon",
            f"({values[row, 1]:g}, {values[row, 2]:g}) outside WGS84 degree ranges",
        )
