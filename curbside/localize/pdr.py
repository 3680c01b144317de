"""Pedestrian dead reckoning (PDR): the classical inertial-velocity baseline, one footstep at a time.

Velocity comes from three classical pieces:

- **footsteps** (:func:`curbside.localize.steps.detect_steps`, :class:`~curbside.localize.steps.StepDetector`
  in a live service, or given);
- **step length** by Weinberg's model, ``L = K * (a_max - a_min) ** 0.25``, with ``a`` the low-passed
  accelerometer magnitude over the step and ``K = PdrConfig.weinberg_k`` (calibrated on the IPIN 2023
  trials, see ``docs/steps.md``);
- **heading** from the orientation quaternion (device-to-ENU, ``qx,qy,qz,qw``, scipy's order). The
  walking direction of a phone held in front of the walker is its "forward" axis: the top edge
  (device +y) when the phone is flat, the back of the phone (device -z) when it is upright. Their
  sum ``y - z`` has a horizontal part pointing forward for every pitch from flat to upright and
  beyond, so its projection on the horizontal plane gives the heading without a singularity at
  either pose. The heading is averaged as unit vectors (no wrap-around) over the step.

The result has one row per footstep: the row at step time ``t_k`` holds the mean velocity over
``(t_{k-1}, t_k]``, i.e. ``L_k / (t_k - t_{k-1})`` along the step's heading, so integrating the
velocity piecewise-constant backwards from each row gives exactly the step's displacement. The first
step gets a row of zero velocity (nothing is known before it). After a stop (a gap longer than
``PdrConfig.max_step_interval_s``) the step still moves ``L_k``, and its length and heading come from
the last ``max_step_interval_s`` only.

**Streaming.** A step's row depends only on the IMU rows within ``StepConfig.fir_margin_s`` of its own
interval (the low-pass is a centred FIR on a grid anchored at the interval's start), so a live
service can call :func:`step_velocity` for each new footstep with a rolling buffer of rows and get
exactly what :func:`pdr_velocity` gives for the whole recording.
"""

from __future__ import annotations

import argparse
import logging
import math
import sys
from dataclasses import dataclass

import numpy as np
import pandas as pd
from scipy.spatial.transform import Rotation
from tqdm import tqdm

from curbside.errors import CurbsideInputError
from curbside.evaluate import metrics
from curbside.localize.readers import ipin
from curbside.localize.steps import StepConfig, detect_steps, fir_centered, lowpass_taps
from curbside.projection import LocalFrame

logger = logging.getLogger(__name__)

#: Device-frame axis whose horizontal projection is the walking direction (see the module docstring).
FORWARD_AXIS = np.array([0.0, 1.0, -1.0])


@dataclass(frozen=True)
class PdrConfig:
    """Parameters of the PDR velocity.

    Attributes
    ----------
    weinberg_k
        Weinberg step-length constant K (m per (m/s^2)^(1/4)): step = K * (a_max - a_min)^(1/4). Chosen
        so that the PDR path length matches the surveyed one (median ratio 1.00) over the 38
        single-floor IPIN 2023 trials with the default footstep detector (``docs/steps.md``).
    max_step_interval_s
        A longer interval between footsteps is a stop: the step's length and heading come from its last
        ``max_step_interval_s`` only.

    The magnitude is low-passed on the footstep detector's grid with its FIR (a
    :class:`~curbside.localize.steps.StepConfig`, passed alongside), so that ``a_max`` and ``a_min`` are
    the humps the detector saw.
    """

    weinberg_k: float = 0.447
    max_step_interval_s: float = 1.5


def forward_heading_vectors(imu: pd.DataFrame) -> np.ndarray:
    """Unit horizontal (east, north) vectors of the phone's forward direction at every IMU sample.

    Parameters
    ----------
    imu
        Table with ``qx,qy,qz,qw`` (device-to-ENU unit quaternions).

    Returns
    -------
    numpy.ndarray
        ``(N, 2)`` east/north unit vectors (zero where the forward axis is vertical).
    """
    world = Rotation.from_quat(imu[["qx", "qy", "qz", "qw"]].to_numpy(float)).apply(FORWARD_AXIS)
    horizontal = world[:, :2]
    norm = np.linalg.norm(horizontal, axis=1, keepdims=True)
    return np.divide(horizontal, norm, out=np.zeros_like(horizontal), where=norm > 1e-9)


def heading_deg(imu: pd.DataFrame) -> np.ndarray:
    """Heading of the phone's forward direction, degrees clockwise from north, per IMU sample."""
    v = forward_heading_vectors(imu)
    return np.degrees(np.arctan2(v[:, 0], v[:, 1])) % 360.0


def _magnitude_swing(t: np.ndarray, mag: np.ndarray, start: float, end: float, steps: StepConfig) -> float:
    """``a_max - a_min`` of the low-passed magnitude on the grid ``start + j / rate``, ``[start, end]``."""
    rate = steps.rate_hz
    half = steps.lowpass_taps // 2
    n = int((end - start) * rate)
    while start + n / rate > end:  # guard the truncation against rounding
        n -= 1
    grid = start + np.arange(-half, n + half + 1, dtype=float) / rate
    smooth = fir_centered(np.interp(grid, t, mag), lowpass_taps(steps))
    return float(smooth.max() - smooth.min())


def step_velocity(
    imu: pd.DataFrame, steps: np.ndarray, previous: float | None = None, config: PdrConfig | None = None,
    step_config: StepConfig | None = None,
) -> pd.DataFrame:
    """Velocity rows of footsteps from the IMU rows around each step only (the streaming entry point).

    Parameters
    ----------
    imu
        ``t,ax,ay,az`` and ``qx,qy,qz,qw``. It must hold every row of the recording within
        ``step_config.fir_margin_s`` of each step interval ``(t_{k-1}, t_k]`` (a rolling buffer is
        enough).
    steps
        Increasing footstep times (s) that follow ``previous``.
    previous
        The footstep before ``steps[0]``; ``None`` when ``steps[0]`` is the recording's first footstep
        (its row is then zero).
    config, step_config
        Parameters (defaults when ``None``); ``step_config`` is the footstep detector's.

    Returns
    -------
    pandas.DataFrame
        ``t,ve,vn`` (s, m/s east, m/s north), one row per footstep: the mean velocity since the footstep
        before. Calling this step by step gives exactly the rows of one call over all steps.

    Raises
    ------
    CurbsideInputError
        ``imu`` has no quaternion columns.
    """
    if not {"qx", "qy", "qz", "qw"} <= set(imu.columns):
        raise CurbsideInputError("imu.csv", "PDR needs the orientation quaternion columns qx,qy,qz,qw")
    config = config or PdrConfig()
    step_config = step_config or StepConfig()
    steps = np.asarray(steps, float)
    t = imu["t"].to_numpy(float)
    acc = imu[["ax", "ay", "az"]].to_numpy(float)
    mag = np.sqrt(acc[:, 0] * acc[:, 0] + acc[:, 1] * acc[:, 1] + acc[:, 2] * acc[:, 2])
    forward = forward_heading_vectors(imu)
    velocity = np.zeros((len(steps), 2))
    starts = np.concatenate([[np.nan if previous is None else previous], steps[:-1]])[: len(steps)]
    for k, (start, end) in enumerate(zip(starts, steps, strict=True)):
        if not np.isfinite(start) or end <= start or len(t) == 0:
            continue
        window_start = max(start, end - config.max_step_interval_s)
        length = config.weinberg_k * _magnitude_swing(t, mag, window_start, end, step_config) ** 0.25
        lo, hi = np.searchsorted(t, [window_start, end], side="right")
        lo = min(lo, max(hi - 1, 0))
        direction = forward[lo:hi].sum(axis=0)
        norm = float(np.hypot(*direction))
        if norm > 1e-9:
            velocity[k] = direction / norm * length / (end - start)
    return pd.DataFrame({"t": steps, "ve": velocity[:, 0], "vn": velocity[:, 1]})


def step_lengths(imu: pd.DataFrame, steps: np.ndarray, config: PdrConfig | None = None,
                 step_config: StepConfig | None = None) -> np.ndarray:
    """Weinberg step length (m) of each step interval ``(steps[k-1], steps[k]]``.

    Parameters
    ----------
    imu
        ``t,ax,ay,az`` (m/s^2).
    steps
        Increasing footstep times (s), at least two.
    config, step_config
        Parameters (defaults when ``None``); ``step_config`` is the footstep detector's.

    Returns
    -------
    numpy.ndarray
        ``len(steps) - 1`` lengths.
    """
    config = config or PdrConfig()
    step_config = step_config or StepConfig()
    t = imu["t"].to_numpy(float)
    acc = imu[["ax", "ay", "az"]].to_numpy(float)
    mag = np.sqrt(acc[:, 0] * acc[:, 0] + acc[:, 1] * acc[:, 1] + acc[:, 2] * acc[:, 2])
    steps = np.asarray(steps, float)
    limit = config.max_step_interval_s
    return np.array([
        config.weinberg_k * _magnitude_swing(t, mag, max(a, b - limit), b, step_config) ** 0.25
        for a, b in zip(steps[:-1], steps[1:], strict=True)
    ])


def pdr_velocity(
    imu: pd.DataFrame, steps: np.ndarray | None = None, config: PdrConfig | None = None,
    step_config: StepConfig | None = None,
) -> pd.DataFrame:
    """World-frame walking velocity of a whole recording (the batch entry point).

    Parameters
    ----------
    imu
        ``imu.csv`` table with ``t,ax,ay,az`` and the quaternion ``qx,qy,qz,qw``.
    steps
        Footstep times (s); detected with :func:`~curbside.localize.steps.detect_steps` when ``None``.
    config, step_config
        Parameters (defaults when ``None``); ``step_config`` is the footstep detector's.

    Returns
    -------
    pandas.DataFrame
        ``t,ve,vn`` (s, m/s east, m/s north) with one row per footstep; the row at ``t_k`` is the mean
        velocity over ``(t_{k-1}, t_k]`` and the first row is zero. Empty when there are no steps.

    Raises
    ------
    CurbsideInputError
        ``imu`` has no quaternion columns.
    """
    if not {"qx", "qy", "qz", "qw"} <= set(imu.columns):
        raise CurbsideInputError("imu.csv", "PDR needs the orientation quaternion columns qx,qy,qz,qw")
    steps = detect_steps(imu, step_config) if steps is None else np.asarray(steps, float)
    return step_velocity(imu, steps, None, config, step_config)


def integrate_velocity(velocity: pd.DataFrame, t_start: float, t: np.ndarray) -> np.ndarray:
    """Displacement (east, north, m) from ``t_start`` to each time ``t`` of a ``t,ve,vn`` table.

    Each row's velocity holds over the interval since the previous row (the convention of
    :func:`pdr_velocity`), so the cumulative displacement is piecewise linear between rows and is
    interpolated exactly; times outside the table hold the end values.

    Parameters
    ----------
    velocity
        ``t,ve,vn`` table.
    t_start
        Time (s) of zero displacement.
    t
        Times (s) at which to evaluate.

    Returns
    -------
    numpy.ndarray
        ``(len(t), 2)`` east/north displacements.
    """
    tv = velocity["t"].to_numpy(float)
    dt = np.diff(tv, prepend=tv[0])
    east = np.cumsum(velocity["ve"].to_numpy(float) * dt)
    north = np.cumsum(velocity["vn"].to_numpy(float) * dt)
    t = np.asarray(t, float)
    return np.column_stack([
        np.interp(t, tv, east) - np.interp(t_start, tv, east),
        np.interp(t, tv, north) - np.interp(t_start, tv, north),
    ])


def dead_reckoned_track(
    velocity: pd.DataFrame, waypoints: pd.DataFrame, align_heading: bool = False
) -> pd.DataFrame:
    """The velocity dead-reckoned from the first waypoint, sampled at every waypoint's time.

    With ``align_heading`` the track is rotated so that its displacement between the first two
    waypoints points along the surveyed one (the known start heading of the paper's setting);
    otherwise the rotation vector's absolute heading is used as it is.

    Returns
    -------
    pandas.DataFrame
        ``t, lat, lon`` at the waypoints' times.
    """
    frame = LocalFrame.around(float(waypoints["lon"].iat[0]), float(waypoints["lat"].iat[0]))
    x, y = frame.to_xy(waypoints["lon"].to_numpy(), waypoints["lat"].to_numpy())
    track = integrate_velocity(velocity, float(waypoints["t"].iat[0]), waypoints["t"].to_numpy())
    if align_heading:
        angle = math.atan2(y[1] - y[0], x[1] - x[0]) - math.atan2(track[1, 1], track[1, 0])
        c, s = math.cos(angle), math.sin(angle)
        track = track @ np.array([[c, s], [-s, c]])
    lon, lat = frame.to_lonlat(x[0] + track[:, 0], y[0] + track[:, 1])
    return pd.DataFrame({"t": waypoints["t"].to_numpy(float), "lat": lat, "lon": lon})


def waypoint_errors(
    velocity: pd.DataFrame, waypoints: pd.DataFrame, align_heading: bool = False
) -> np.ndarray:
    """Distance (m) between dead-reckoned and surveyed positions at each waypoint after the first.

    Scored by :func:`curbside.evaluate.metrics.waypoint_errors` on :func:`dead_reckoned_track`.
    """
    track = dead_reckoned_track(velocity, waypoints, align_heading)
    return metrics.waypoint_errors(track, waypoints)["error_m"].to_numpy()


def evaluate_ipin(
    path: str, trials: list[str] | None = None, config: PdrConfig | None = None
) -> tuple[pd.DataFrame, pd.DataFrame]:
    """PDR on IPIN trials, scored against the surveyed waypoints.

    Footsteps are counted and dead reckoning is scored between the first and last waypoint, starting
    from the first waypoint's position.

    Parameters
    ----------
    path
        The IPIN ``.h5``.
    trials
        Trial names (default: all).
    config
        PDR and footstep parameters (:class:`PdrConfig` defaults when ``None``).

    Returns
    -------
    trials : pandas.DataFrame
        One row per trial: ``trial, device, floors, steps, walk_s, surveyed_m, pdr_m, ratio``
        (PDR / surveyed path length) and ``err_median_m, err_p90_m`` (absolute heading) and
        ``aligned_median_m, aligned_p90_m`` (heading aligned on the first segment).
    waypoints : pandas.DataFrame
        One row per scored waypoint: ``trial, waypoint`` (index, from 1), ``err_m, aligned_err_m``.
    """
    config = config or PdrConfig()
    rows, scored = [], []
    names = trials or ipin.list_trials(path)
    for name in tqdm(names, desc="PDR", unit="trial", disable=not sys.stderr.isatty()):
        session = ipin.read_trial(path, name)
        wp = session.waypoints
        if wp is None or len(wp) < 2:
            logger.warning("%s: no surveyed waypoints to score PDR against; skipped", name)
            continue
        t0, t1 = float(wp["t"].iat[0]), float(wp["t"].iat[-1])
        steps = detect_steps(session.imu)
        velocity = pdr_velocity(session.imu, steps, config)
        walk = (steps > t0) & (steps <= t1)
        frame = LocalFrame.around(float(wp["lon"].iat[0]), float(wp["lat"].iat[0]))
        x, y = frame.to_xy(wp["lon"].to_numpy(), wp["lat"].to_numpy())
        surveyed = float(np.hypot(np.diff(x), np.diff(y)).sum())
        inside = (velocity["t"] > t0) & (velocity["t"] <= t1)
        dt = np.diff(velocity["t"].to_numpy(), prepend=velocity["t"].iat[0])
        pdr_m = float((np.hypot(velocity["ve"], velocity["vn"]) * dt)[inside].sum())
        err = waypoint_errors(velocity, wp)
        aligned = waypoint_errors(velocity, wp, align_heading=True)
        rows.append({
            "trial": session.name, "device": session.meta["device"],
            "floors": ",".join(map(str, session.meta["floors"])), "steps": int(walk.sum()),
            "walk_s": t1 - t0, "surveyed_m": surveyed, "pdr_m": pdr_m, "ratio": pdr_m / surveyed,
            "err_median_m": float(np.median(err)), "err_p90_m": float(np.percentile(err, 90)),
            "aligned_median_m": float(np.median(aligned)), "aligned_p90_m": float(np.percentile(aligned, 90)),
        })
        index = np.arange(1, len(err) + 1)
        scored.append(pd.DataFrame(
            {"trial": session.name, "waypoint": index, "err_m": err, "aligned_err_m": aligned}
        ))
    return pd.DataFrame(rows), pd.concat(scored, ignore_index=True)


def main(argv: list[str] | None = None) -> int:
    """``python -m curbside.localize.pdr FILE.h5``: the PDR baseline scored on every IPIN trial."""
    parser = argparse.ArgumentParser(prog="python -m curbside.localize.pdr", description=main.__doc__)
    parser.add_argument("h5", help="IPIN 2023 .h5 (../shared/data/ipin2023/ipin2023-t3.h5)")
    parser.add_argument("--csv", help="also write the per-trial table here")
    parser.add_argument("--weinberg-k", type=float, default=PdrConfig.weinberg_k,
                        help="Weinberg step-length constant (default %(default)s)")
    args = parser.parse_args(argv)
    table, scored = evaluate_ipin(args.h5, config=PdrConfig(weinberg_k=args.weinberg_k))
    if args.csv:
        table.to_csv(args.csv, index=False, float_format="%.3f")
    with pd.option_context("display.width", 200, "display.max_rows", 100, "display.precision", 2):
        print(table.to_string(index=False))
    straight = ~table["floors"].str.contains(",")
    groups = {"all": np.ones(len(table), bool), "single floor": straight.to_numpy(),
              "floor changes": (~straight).to_numpy()}
    for label, mask in groups.items():
        if not mask.any():
            continue
        sub = table[mask]
        picked = scored[scored["trial"].isin(sub["trial"])]
        err, aligned = picked["err_m"].to_numpy(), picked["aligned_err_m"].to_numpy()
        q25, q50, q75 = sub["ratio"].quantile([0.25, 0.5, 0.75])
        print(f"{label}: {mask.sum()} trials, {sub['steps'].sum()} steps, ratio median "
              f"{q50:.3f} (IQR {q25:.3f}-{q75:.3f}); "
              f"waypoint error median/p90 {np.median(err):.1f}/{np.percentile(err, 90):.1f} m, "
              f"heading-aligned {np.median(aligned):.1f}/{np.percentile(aligned, 90):.1f} m "
              f"({len(err)} waypoints)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
