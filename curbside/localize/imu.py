"""IMU preprocessing for learned inertial odometry: phone-frame samples to a gravity-aligned world frame.

The RoNIN input is the gyroscope and the accelerometer (gravity kept) expressed in a world frame whose
z axis is up and whose yaw is whatever the orientation source says (the game rotation vector's
arbitrary yaw, or magnetic north for Android's rotation vector). This module turns an ``imu.csv``
table into such streams, on a uniform clock:

1. **Validation.** The accelerometer and gyroscope columns are required (no gyroscope is an error,
   and so is a gyroscope that reads exactly zero throughout: some loggers fill the column when the
   sensor is absent). Rows holding NaN are dropped and their hole treated like any other gap.
   Timestamps must increase strictly. Rates below ``settings.imu_min_rate_hz`` are refused.
2. **Saturation.** A channel whose extreme value is hit repeatedly (a flat top) and lies above a
   plausible floor (``settings.imu_saturation_floor_accel_ms2`` / ``..._gyro_rads``) is saturated:
   the samples are flagged (:attr:`WorldImu.saturated`) and a warning is logged; the values are kept
   as they are (clipped by the sensor), since there is nothing better to put there.
3. **Gaps.** Gaps up to ``settings.imu_max_interp_gap_s`` (0.5 s) are linearly interpolated; longer
   gaps split the recording into segments processed separately (orientation from gyroscope
   integration restarts after such a gap). Segments shorter than ``min_duration_s`` are dropped with
   a warning.
4. **Orientation.** With ``qx,qy,qz,qw`` columns the quaternion is used, after checking its
   convention: the four readings (scalar last or first, device-to-world or its inverse) are tried on
   the accelerometer, and the one that rotates the mean specific force closest to +z (up) wins; a
   reading other than the documented one is logged as a warning. Without a quaternion the gyroscope
   is integrated (see :func:`integrate_gyroscope`).
5. **Resampling.** The world-frame vectors are linearly interpolated onto a uniform grid at
   ``rate_hz`` (200 Hz for RoNIN). Lower-rate phones (50 Hz) are thus upsampled.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
import pandas as pd
from scipy.spatial.transform import Rotation

from curbside import settings
from curbside.errors import CurbsideInputError

logger = logging.getLogger(__name__)

ACC_COLUMNS = ("ax", "ay", "az")
GYRO_COLUMNS = ("gx", "gy", "gz")
QUAT_COLUMNS = ("qx", "qy", "qz", "qw")

#: The four readings of a logged quaternion tried by :func:`detect_quaternion_order`: column
#: permutation into scipy's scalar-last order, and whether the rotation is world-to-device.
QUATERNION_READINGS: dict[str, tuple[tuple[int, int, int, int], bool]] = {
    "xyzw": ((0, 1, 2, 3), False),
    "wxyz": ((1, 2, 3, 0), False),
    "xyzw-inverse": ((0, 1, 2, 3), True),
    "wxyz-inverse": ((1, 2, 3, 0), True),
}


@dataclass
class WorldImu:
    """One contiguous stretch of IMU data in the gravity-aligned world frame, on a uniform clock.

    Attributes
    ----------
    t
        ``(N,)`` sample times in seconds, uniform at ``rate_hz``.
    gyro
        ``(N, 3)`` angular rate in rad/s, world frame (x, y horizontal, z up).
    acc
        ``(N, 3)`` specific force in m/s^2 including gravity, world frame.
    saturated
        ``(N,)`` True where any input channel was at its saturation value.
    rate_hz
        Sampling rate of the grid.
    """

    t: np.ndarray
    gyro: np.ndarray
    acc: np.ndarray
    saturated: np.ndarray
    rate_hz: float

    @property
    def features(self) -> np.ndarray:
        """``(N, 6)`` float32 network input: world-frame gyroscope then accelerometer."""
        return np.concatenate([self.gyro, self.acc], axis=1).astype(np.float32)


def _check_columns(imu: pd.DataFrame, source: str) -> bool:
    missing_gyro = [c for c in GYRO_COLUMNS if c not in imu.columns]
    if missing_gyro:
        raise CurbsideInputError(source, f"no gyroscope: missing column(s) {missing_gyro}")
    missing = [c for c in ("t", *ACC_COLUMNS) if c not in imu.columns]
    if missing:
        raise CurbsideInputError(source, f"missing column(s) {missing}")
    has_q = [c in imu.columns for c in QUAT_COLUMNS]
    if any(has_q) and not all(has_q):
        raise CurbsideInputError(source, "partial quaternion columns: need all of qx,qy,qz,qw or none")
    return all(has_q)


def _drop_nan_rows(imu: pd.DataFrame, columns: list[str], source: str) -> pd.DataFrame:
    try:
        values = imu[columns].apply(pd.to_numeric, errors="raise").astype(float)
    except (ValueError, TypeError) as exc:
        raise CurbsideInputError(source, f"non-numeric value ({exc})") from None
    finite = np.isfinite(values.to_numpy()).all(axis=1)
    if not finite.all():
        logger.warning(
            "%s: %d row(s) with NaN/inf dropped; their holes are handled as gaps", source,
            int((~finite).sum()),
        )
        values = values[finite]
    if len(values) < 2:
        raise CurbsideInputError(source, "fewer than two usable IMU rows")
    t = values["t"].to_numpy(copy=True)
    dt = np.diff(t)
    if (dt <= 0).any():
        i = int(np.argmax(dt <= 0))
        raise CurbsideInputError(
            source, f"timestamps not strictly increasing at data row {i + 2} (t={t[i + 1]!r})"
        )
    return values.reset_index(drop=True)


def saturation_mask(values: np.ndarray, floors: np.ndarray, min_repeats: int = 3) -> np.ndarray:
    """Flag samples where a channel sits at a repeated extreme above a plausibility floor.

    Parameters
    ----------
    values
        ``(N, C)`` raw sensor values.
    floors
        ``(C,)`` smallest absolute value that may be a saturation level (e.g. 2 g for an
        accelerometer): flat tops below it are quantisation, not clipping.
    min_repeats
        How many samples must share the extreme value.

    Returns
    -------
    numpy.ndarray
        ``(N,)`` bool, True where any channel is saturated.
    """
    mag = np.abs(values)
    peak = mag.max(axis=0)
    at_peak = mag >= peak * (1.0 - 1e-6)
    channel_saturated = (at_peak.sum(axis=0) >= min_repeats) & (peak >= floors)
    return (at_peak & channel_saturated).any(axis=1)


def detect_quaternion_order(acc: np.ndarray, quat: np.ndarray, source: str = "imu") -> str:
    """Which reading of the logged quaternion columns makes the accelerometer point up.

    A phone's accelerometer measures the specific force, which averages to +g along the world's up
    axis. Each reading in :data:`QUATERNION_READINGS` is applied to the accelerometer and the one
    whose mean world-frame specific force is best aligned with +z is returned.

    Parameters
    ----------
    acc
        ``(N, 3)`` accelerometer in the device frame, m/s^2 with gravity.
    quat
        ``(N, 4)`` the four quaternion columns as logged (``qx,qy,qz,qw`` by SPEC).
    source
        Name used in messages.

    Returns
    -------
    str
        A key of :data:`QUATERNION_READINGS`; ``"xyzw"`` is the SPEC convention.

    Raises
    ------
    CurbsideInputError
        No reading brings gravity within 30 degrees of up (not an orientation of this IMU).
    """
    acc, quat = np.array(acc, dtype=float), np.array(quat, dtype=float)  # writable copies for scipy
    norms = np.linalg.norm(quat, axis=1)
    if not (np.abs(norms - 1.0) < 0.05).mean() > 0.95:
        raise CurbsideInputError(
            source, f"quaternion columns are not unit quaternions (median norm {np.median(norms):.3f})"
        )
    step = max(1, len(acc) // 2000)
    cosines = {}
    for name, (perm, inverse) in QUATERNION_READINGS.items():
        rot = Rotation.from_quat(quat[::step, list(perm)])
        rot = rot.inv() if inverse else rot
        mean_up = rot.apply(acc[::step]).mean(axis=0)
        cosines[name] = mean_up[2] / max(np.linalg.norm(mean_up), 1e-9)
    best = max(cosines, key=lambda k: cosines[k])
    if cosines[best] < np.cos(np.radians(30.0)):
        raise CurbsideInputError(
            source, "no quaternion convention rotates the accelerometer's gravity to up: not an orientation"
        )
    # Keep the documented order unless another reading is clearly better (a still, level phone
    # can make several readings agree).
    if best != "xyzw" and cosines["xyzw"] > cosines[best] - 1e-3:
        best = "xyzw"
    if best != "xyzw":
        logger.warning(
            "%s: quaternion columns read as %s (gravity check); SPEC order is qx,qy,qz,qw", source, best
        )
    return best


def _quat_mul(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Hamilton product of scalar-last quaternion arrays, ``p * q`` row by row."""
    px, py, pz, pw = p.T
    qx, qy, qz, qw = q.T
    return np.stack(
        [
            pw * qx + px * qw + py * qz - pz * qy,
            pw * qy - px * qz + py * qw + pz * qx,
            pw * qz + px * qy - py * qx + pz * qw,
            pw * qw - px * qx - py * qy - pz * qz,
        ],
        axis=1,
    )


def _moving_mean(x: np.ndarray, width: int) -> np.ndarray:
    """Centred moving mean along axis 0 with shrinking windows at the ends."""
    n = len(x)
    c = np.concatenate([np.zeros((1, x.shape[1])), np.cumsum(x, axis=0)])
    half = width // 2
    lo = np.clip(np.arange(n) - half, 0, n)
    hi = np.clip(np.arange(n) + half + 1, 0, n)
    return (c[hi] - c[lo]) / (hi - lo)[:, None]


def integrate_gyroscope(t: np.ndarray, gyro: np.ndarray, acc: np.ndarray,
                        tilt_window_s: float = 2.0) -> Rotation:
    """Device-to-world orientation from the gyroscope, tilt held to gravity: a game rotation vector.

    The body-frame increments ``exp(omega dt)`` are chained by a parallel prefix product (log2 N
    vectorised steps instead of a Python loop over samples), starting from the tilt given by the
    first half second of the accelerometer and zero yaw. Gyroscope bias makes the tilt drift, which
    would leak gravity into the horizontal channels, so each sample's tilt is then corrected by the
    smallest rotation taking the low-passed world-frame specific force to +z. That correction has
    no yaw component: yaw drifts as it does in Android's game rotation vector.

    Parameters
    ----------
    t
        ``(N,)`` sample times (s), increasing.
    gyro
        ``(N, 3)`` rad/s, device frame.
    acc
        ``(N, 3)`` m/s^2 with gravity, device frame.
    tilt_window_s
        Width of the low-pass used for the tilt correction.

    Returns
    -------
    scipy.spatial.transform.Rotation
        ``N`` device-to-world rotations.
    """
    t, gyro, acc = (np.array(a, dtype=float) for a in (t, gyro, acc))  # writable copies for scipy
    n = len(t)
    dt = np.diff(t, prepend=t[0])
    omega = np.vstack([gyro[:1], 0.5 * (gyro[1:] + gyro[:-1])])
    prefix = Rotation.from_rotvec(omega * dt[:, None]).as_quat()
    d = 1
    while d < n:
        prefix[d:] = _quat_mul(prefix[:-d], prefix[d:])
        prefix /= np.linalg.norm(prefix, axis=1, keepdims=True)
        d *= 2
    rate = 1.0 / max(float(np.median(np.diff(t))) if n > 1 else 1.0, 1e-6)
    head = acc[: max(1, int(0.5 * rate))].mean(axis=0)
    start, _ = Rotation.align_vectors([[0.0, 0.0, 1.0]], [head])
    rot = start * Rotation.from_quat(prefix)
    up = _moving_mean(rot.apply(acc), max(1, int(tilt_window_s * rate)))
    up /= np.linalg.norm(up, axis=1, keepdims=True)
    axis = np.cross(up, [0.0, 0.0, 1.0])
    sin = np.linalg.norm(axis, axis=1, keepdims=True)
    angle = np.arctan2(sin[:, 0], up[:, 2])
    axis = np.divide(axis, sin, out=np.zeros_like(axis), where=sin > 1e-12)
    return Rotation.from_rotvec(axis * angle[:, None]) * rot


def world_frame_segments(
    imu: pd.DataFrame,
    source: str = "imu.csv",
    max_gap_s: float | None = None,
    min_duration_s: float = 1.0,
) -> list[pd.DataFrame]:
    """Rotate an ``imu.csv`` table into the world frame at its own sample times, split at long gaps.

    Parameters
    ----------
    imu
        ``t,ax,ay,az,gx,gy,gz[,qx,qy,qz,qw]`` (SPEC ``imu.csv``).
    source
        File name used in messages.
    max_gap_s
        Longest gap bridged by interpolation (default ``settings.imu_max_interp_gap_s``).
    min_duration_s
        Segments shorter than this are dropped (with a warning).

    Returns
    -------
    list of pandas.DataFrame
        Per segment: ``t, wgx, wgy, wgz, wax, way, waz, saturated`` at the input sample times.

    Raises
    ------
    CurbsideInputError
        Missing gyroscope or accelerometer, all-zero gyroscope, non-numeric values, timestamps not
        increasing, rate below ``settings.imu_min_rate_hz``, unusable quaternion, no segment long enough.
    """
    max_gap_s = settings.imu_max_interp_gap_s if max_gap_s is None else max_gap_s
    has_quat = _check_columns(imu, source)
    columns = ["t", *ACC_COLUMNS, *GYRO_COLUMNS] + (list(QUAT_COLUMNS) if has_quat else [])
    values = _drop_nan_rows(imu, columns, source)
    t = values["t"].to_numpy(copy=True)
    acc = values[list(ACC_COLUMNS)].to_numpy(copy=True)
    gyro = values[list(GYRO_COLUMNS)].to_numpy(copy=True)
    if not np.any(gyro):
        raise CurbsideInputError(source, "gyroscope columns are all zero: no gyroscope data")
    rate = 1.0 / float(np.median(np.diff(t)))
    if rate < settings.imu_min_rate_hz:
        raise CurbsideInputError(
            source, f"IMU rate {rate:.1f} Hz is below the {settings.imu_min_rate_hz:g} Hz minimum for RoNIN"
        )
    floors = np.array(
        [settings.imu_saturation_floor_accel_ms2] * 3 + [settings.imu_saturation_floor_gyro_rads] * 3
    )
    saturated = saturation_mask(np.hstack([acc, gyro]), floors)
    if saturated.any():
        logger.warning(
            "%s: %d sample(s) (%.1f %%) at a sensor's saturation value; velocities there are unreliable",
            source, int(saturated.sum()), 100.0 * saturated.mean(),
        )
    if has_quat:
        quat = values[list(QUAT_COLUMNS)].to_numpy(copy=True)
        perm, inverse = QUATERNION_READINGS[detect_quaternion_order(acc, quat, source)]
        rot_all = Rotation.from_quat(quat[:, list(perm)])
        rot_all = rot_all.inv() if inverse else rot_all

    breaks = np.flatnonzero(np.diff(t) > max_gap_s) + 1
    if len(breaks):
        logger.warning("%s: %d gap(s) longer than %.2f s split the recording", source, len(breaks), max_gap_s)
    segments = []
    for lo, hi in zip(np.r_[0, breaks], np.r_[breaks, len(t)], strict=True):
        if t[hi - 1] - t[lo] < min_duration_s:
            logger.warning(
                "%s: dropped a %.2f s segment at t=%.2f (too short)", source, t[hi - 1] - t[lo], t[lo]
            )
            continue
        sl = slice(lo, hi)
        rot = rot_all[sl] if has_quat else integrate_gyroscope(t[sl], gyro[sl], acc[sl])
        seg = pd.DataFrame(
            np.hstack([t[sl, None], rot.apply(gyro[sl]), rot.apply(acc[sl])]),
            columns=["t", "wgx", "wgy", "wgz", "wax", "way", "waz"],
        )
        seg["saturated"] = saturated[sl]
        segments.append(seg)
    if not segments:
        raise CurbsideInputError(source, f"no stretch of IMU data without gaps lasts {min_duration_s:g} s")
    return segments


def resample_world(segment: pd.DataFrame, rate_hz: float) -> WorldImu:
    """Linearly interpolate one world-frame segment onto a uniform clock.

    Parameters
    ----------
    segment
        One element of :func:`world_frame_segments`.
    rate_hz
        Output rate (200 Hz for RoNIN).

    Returns
    -------
    WorldImu
    """
    t_in = segment["t"].to_numpy()
    t = t_in[0] + np.arange(int(np.floor((t_in[-1] - t_in[0]) * rate_hz)) + 1) / rate_hz
    cols = segment[["wgx", "wgy", "wgz", "wax", "way", "waz"]].to_numpy()
    out = np.column_stack([np.interp(t, t_in, cols[:, k]) for k in range(6)])
    # a grid sample is saturated when either input sample it is interpolated from is
    flags = segment["saturated"].to_numpy()
    right = np.clip(np.searchsorted(t_in, t, side="right"), 0, len(t_in) - 1)
    left = np.clip(right - 1, 0, len(t_in) - 1)
    return WorldImu(
        t=t, gyro=out[:, :3], acc=out[:, 3:], saturated=flags[left] | flags[right], rate_hz=rate_hz,
    )


def preprocess(imu: pd.DataFrame, rate_hz: float = 200.0, source: str = "imu.csv",
               min_duration_s: float = 1.0) -> list[WorldImu]:
    """``imu.csv`` table to world-frame, uniformly sampled segments (see the module docstring).

    Parameters
    ----------
    imu
        ``t,ax,ay,az,gx,gy,gz[,qx,qy,qz,qw]``.
    rate_hz
        Output rate.
    source
        File name used in messages.
    min_duration_s
        Shortest segment kept.

    Returns
    -------
    list of WorldImu
        One per stretch without a gap longer than ``settings.imu_max_interp_gap_s``.
    """
    segments = world_frame_segments(imu, source, min_duration_s=min_duration_s)
    return [resample_world(seg, rate_hz) for seg in segments]
