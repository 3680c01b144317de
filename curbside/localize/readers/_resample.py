"""Put accelerometer, gyroscope and orientation streams on one clock: the accelerometer's.

Phones sample their sensors at different rates (on the IPIN Galaxy A5 the gyroscope runs at 100 Hz
and the accelerometer at 50 Hz), while ``imu.csv`` holds one row per sample time. Rates are linearly
interpolated; the orientation quaternion is interpolated by normalised linear interpolation after
making consecutive quaternions lie in the same hemisphere (q and -q are the same rotation; without
that, nlerp between them passes through zero). At 50 Hz the angle between consecutive samples is a
few degrees, where nlerp and slerp differ by well under 0.01 degree.
"""

from __future__ import annotations

import logging

import numpy as np
import pandas as pd

from curbside.errors import CurbsideInputError

logger = logging.getLogger(__name__)


def continuous_quaternions(q: np.ndarray) -> np.ndarray:
    """Flip signs so that consecutive quaternions have a non-negative dot product.

    Parameters
    ----------
    q
        ``(N, 4)`` quaternions in any component order.

    Returns
    -------
    numpy.ndarray
        ``(N, 4)``, each row ``q`` or ``-q``.
    """
    q = np.asarray(q, float)
    if len(q) < 2:
        return q.copy()
    flips = np.einsum("ij,ij->i", q[1:], q[:-1]) < 0
    sign = np.concatenate([[1.0], np.cumprod(np.where(flips, -1.0, 1.0))])
    return q * sign[:, None]


def interp_quaternions(t_new: np.ndarray, t: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Normalised linear interpolation of quaternions ``q`` sampled at ``t`` onto ``t_new``.

    Parameters
    ----------
    t_new
        Target times (s); values outside ``[t[0], t[-1]]`` take the end quaternion.
    t
        Increasing sample times (s).
    q
        ``(N, 4)`` unit quaternions (any component order; the order is preserved).

    Returns
    -------
    numpy.ndarray
        ``(len(t_new), 4)`` unit quaternions.
    """
    q = continuous_quaternions(q)
    out = np.column_stack([np.interp(t_new, t, q[:, k]) for k in range(4)])
    return out / np.linalg.norm(out, axis=1, keepdims=True)


#: Longest interval (s) between two samples of an IMU stream taken as ordinary jitter; a longer gap
#: (the sensor paused, rows deleted) is reported with a warning, since it is filled by interpolation.
MAX_GAP_S = 0.5

#: Seconds of accelerometer data that may be cut at the ends, where the other streams have not
#: started yet or have already stopped, before the cut is reported as a warning (not an info line).
MAX_SILENT_CUT_S = 1.0


def report_gaps(t: np.ndarray, source: str, effect: str, span: tuple[float, float] | None = None) -> int:
    """Log one WARNING listing the gaps longer than :data:`MAX_GAP_S` between samples ``t``.

    Parameters
    ----------
    t
        Increasing sample times (s) of one stream.
    source
        The stream's file, named in the message.
    effect
        What happens to the gaps downstream, e.g. ``"filled by linear interpolation"``.
    span
        Only gaps overlapping this ``(start, end)`` interval count (the part of the stream used).

    Returns
    -------
    int
        The number of gaps reported.
    """
    t = np.asarray(t, float)
    if len(t) < 2:
        return 0
    steps = np.diff(t)
    big = steps > MAX_GAP_S
    if span is not None:
        big &= (t[1:] > span[0]) & (t[:-1] < span[1])
    where = np.flatnonzero(big)
    if len(where) == 0:
        return 0
    listed = ", ".join(f"{steps[i]:.1f} s from t={t[i]:.1f} s" for i in where[:3])
    if len(where) > 3:
        listed += f" and {len(where) - 3} more"
    logger.warning("%s: %d gap(s) longer than %.1f s (%s); %s", source, len(where), MAX_GAP_S, listed, effect)
    return len(where)


def _report_cut(acce: pd.DataFrame, t0: float, t1: float, firsts: dict[str, float], lasts: dict[str, float],
                source: str, dropped: int) -> None:
    """Say how much of the accelerometer recording the other streams' shorter span cuts off."""
    a0, a1 = float(acce["t"].iat[0]), float(acce["t"].iat[-1])
    late = max(firsts, key=firsts.get)
    early = min(lasts, key=lasts.get)
    lost_start, lost_end = max(t0 - a0, 0.0), max(a1 - t1, 0.0)
    if lost_start + lost_end <= MAX_SILENT_CUT_S:
        logger.info("%s: %d accelerometer sample(s) outside the other streams' span dropped", source, dropped)
        return
    parts = []
    if lost_start > 0.05:
        parts.append(f"{late} starts {lost_start:.1f} s after the accelerometer")
    if lost_end > 0.05:
        parts.append(f"{early} ends {lost_end:.1f} s before the accelerometer")
    logger.warning("%s: imu.csv cut to t=%.1f-%.1f s (%.1f s of the %.1f s accelerometer recording lost)",
                   "; ".join(parts), t0, t1, lost_start + lost_end, a1 - a0)


def merge_imu(
    acce: pd.DataFrame,
    gyro: pd.DataFrame,
    quat: pd.DataFrame | None,
    source: str,
    names: tuple[str, str, str] | None = None,
) -> pd.DataFrame:
    """Resample gyroscope (and orientation) onto the accelerometer clock: an ``imu.csv`` table.

    Accelerometer samples outside the span of the other streams are dropped (no extrapolation); when
    that loses more than :data:`MAX_SILENT_CUT_S`, a warning names the short stream and the seconds
    lost. Gaps longer than :data:`MAX_GAP_S` in any stream are reported too (:func:`report_gaps`).

    Parameters
    ----------
    acce
        ``t,ax,ay,az`` (m/s^2 including gravity), strictly increasing ``t``.
    gyro
        ``t,gx,gy,gz`` (rad/s).
    quat
        ``t,qx,qy,qz,qw`` device-to-world unit quaternions, or ``None``.
    source
        Name used in log lines and errors.
    names
        How messages name the accelerometer, gyroscope and orientation streams (their files);
        ``"SOURCE accelerometer"`` and so on when ``None``.

    Returns
    -------
    pandas.DataFrame
        ``t,ax,ay,az,gx,gy,gz[,qx,qy,qz,qw]`` on the accelerometer samples that lie inside the span
        of every stream.

    Raises
    ------
    CurbsideInputError
        The streams do not overlap in time.
    """
    names = names or (f"{source} accelerometer", f"{source} gyroscope", f"{source} orientation")
    streams = dict(zip(names, [acce, gyro, quat], strict=True))
    streams = {name: s for name, s in streams.items() if s is not None}
    firsts = {name: float(s["t"].iat[0]) for name, s in streams.items()}
    lasts = {name: float(s["t"].iat[-1]) for name, s in streams.items()}
    t0, t1 = max(firsts.values()), min(lasts.values())
    keep = (acce["t"] >= t0) & (acce["t"] <= t1)
    if keep.sum() < 2:
        raise CurbsideInputError(source, "accelerometer, gyroscope and orientation do not overlap in time")
    if (~keep).any():
        _report_cut(acce, t0, t1, firsts, lasts, source, int((~keep).sum()))
    for name, s in streams.items():
        effect = "imu.csv has no rows there" if s is acce else "filled by interpolation in imu.csv"
        report_gaps(s["t"].to_numpy(), name, effect, span=(t0, t1))
    out = acce.loc[keep, ["t", "ax", "ay", "az"]].reset_index(drop=True)
    t = out["t"].to_numpy()
    for col in ("gx", "gy", "gz"):
        out[col] = np.interp(t, gyro["t"].to_numpy(), gyro[col].to_numpy())
    if quat is not None:
        q = interp_quaternions(t, quat["t"].to_numpy(), quat[["qx", "qy", "qz", "qw"]].to_numpy())
        out[["qx", "qy", "qz", "qw"]] = q
    return out
