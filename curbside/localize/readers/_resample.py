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


def merge_imu(
    acce: pd.DataFrame,
    gyro: pd.DataFrame,
    quat: pd.DataFrame | None,
    source: str,
) -> pd.DataFrame:
    """Resample gyroscope (and orientation) onto the accelerometer clock: an ``imu.csv`` table.

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

    Returns
    -------
    pandas.DataFrame
        ``t,ax,ay,az,gx,gy,gz[,qx,qy,qz,qw]`` on the accelerometer samples that lie inside the span
        of every stream (no extrapolation).

    Raises
    ------
    CurbsideInputError
        The streams do not overlap in time.
    """
    streams = [acce, gyro] + ([quat] if quat is not None else [])
    t0 = max(float(s["t"].iat[0]) for s in streams)
    t1 = min(float(s["t"].iat[-1]) for s in streams)
    keep = (acce["t"] >= t0) & (acce["t"] <= t1)
    if keep.sum() < 2:
        raise CurbsideInputError(source, "accelerometer, gyroscope and orientation do not overlap in time")
    if (~keep).any():
        logger.info("%s: %d accelerometer sample(s) outside the other streams' span dropped", source,
                    int((~keep).sum()))
    out = acce.loc[keep, ["t", "ax", "ay", "az"]].reset_index(drop=True)
    t = out["t"].to_numpy()
    for col in ("gx", "gy", "gz"):
        out[col] = np.interp(t, gyro["t"].to_numpy(), gyro[col].to_numpy())
    if quat is not None:
        q = interp_quaternions(t, quat["t"].to_numpy(), quat[["qx", "qy", "qz", "qw"]].to_numpy())
        out[["qx", "qy", "qz", "qw"]] = q
    return out
