"""Pedestrian dead reckoning (PDR): the classical inertial-velocity baseline.

Velocity comes from three classical pieces:

- **footsteps** (:func:`curbside.localize.steps.detect_steps`, or given);
- **step length** by Weinberg's model, ``L = K * (a_max - a_min) ** 0.25``, with ``a`` the low-passed
  accelerometer magnitude over the step and ``K = settings.pdr_weinberg_k`` (calibrated on the IPIN
  2023 trials, see ``docs/sessions.md``);
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
``settings.pdr_max_step_interval_s``) the step still moves ``L_k``, and its heading is averaged over
the last ``pdr_max_step_interval_s`` only.
"""

from __future__ import annotations

import argparse
import sys

import numpy as np
import pandas as pd
from scipy.spatial.transform import Rotation
from tqdm import tqdm

from curbside import settings
from curbside.errors import CurbsideInputError
from curbside.localize.readers import ipin
from curbside.localize.steps import detect_steps, lowpass, uniform_magnitude
from curbside.projection import LocalFrame

#: Device-frame axis whose horizontal projection is the walking direction (see the module docstring).
FORWARD_AXIS = np.array([0.0, 1.0, -1.0])


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


def step_lengths(imu: pd.DataFrame, steps: np.ndarray, weinberg_k: float | None = None) -> np.ndarray:
    """Weinberg step length (m) of each step interval ``(steps[k-1], steps[k]]``.

    Parameters
    ----------
    imu
        ``t,ax,ay,az`` (m/s^2).
    steps
        Increasing footstep times (s), at least two.
    weinberg_k
        Override ``settings.pdr_weinberg_k``.

    Returns
    -------
    numpy.ndarray
        ``len(steps) - 1`` lengths.
    """
    k = settings.pdr_weinberg_k if weinberg_k is None else weinberg_k
    t, mag = uniform_magnitude(imu)
    smooth = lowpass(mag, 1.0 / (t[1] - t[0]), settings.step_lowpass_hz)
    # Sample index ranges [edges[k-1], edges[k]) are the step intervals; reduceat takes max/min over
    # consecutive ranges in one pass.
    edges = np.searchsorted(t, steps, side="right").clip(max=len(t) - 1)
    a_max = np.maximum.reduceat(smooth, edges)[:-1]
    a_min = np.minimum.reduceat(smooth, edges)[:-1]
    return k * np.maximum(a_max - a_min, 0.0) ** 0.25


def pdr_velocity(
    imu: pd.DataFrame,
    steps: np.ndarray | None = None,
    *,
    weinberg_k: float | None = None,
    max_step_interval_s: float | None = None,
) -> pd.DataFrame:
    """World-frame walking velocity from footsteps, Weinberg step lengths and the rotation vector.

    Parameters
    ----------
    imu
        ``imu.csv`` table with ``t,ax,ay,az`` and the quaternion ``qx,qy,qz,qw``.
    steps
        Footstep times (s); detected with :func:`~curbside.localize.steps.detect_steps` when ``None``.
    weinberg_k
        Override ``settings.pdr_weinberg_k``.
    max_step_interval_s
        Override ``settings.pdr_max_step_interval_s``.

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
    max_gap = settings.pdr_max_step_interval_s if max_step_interval_s is None else max_step_interval_s
    steps = detect_steps(imu) if steps is None else np.asarray(steps, float)
    if len(steps) == 0:
        return pd.DataFrame({"t": [], "ve": [], "vn": []})
    t_imu = imu["t"].to_numpy(float)
    lengths = step_lengths(imu, steps, weinberg_k) if len(steps) > 1 else np.empty(0)
    dt = np.diff(steps)

    # Mean forward vector over the last <= max_gap seconds of each step, from cumulative sums.
    forward = forward_heading_vectors(imu)
    csum = np.vstack([np.zeros((1, 2)), np.cumsum(forward, axis=0)])
    lo = np.searchsorted(t_imu, np.maximum(steps[:-1], steps[1:] - max_gap), side="right")
    hi = np.searchsorted(t_imu, steps[1:], side="right")
    hi = np.maximum(hi, lo + 1).clip(max=len(t_imu))
    lo = np.minimum(lo, hi - 1)
    mean_forward = csum[hi] - csum[lo]
    norm = np.linalg.norm(mean_forward, axis=1, keepdims=True)
    direction = np.divide(mean_forward, norm, out=np.zeros_like(mean_forward), where=norm > 1e-9)

    speed = lengths / dt
    ve = np.concatenate([[0.0], speed * direction[:, 0]])
    vn = np.concatenate([[0.0], speed * direction[:, 1]])
    return pd.DataFrame({"t": steps, "ve": ve, "vn": vn})


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


def waypoint_errors(
    velocity: pd.DataFrame, waypoints: pd.DataFrame, align_heading: bool = False
) -> np.ndarray:
    """Distance (m) between dead-reckoned and surveyed positions at each waypoint after the first.

    The track starts at the first waypoint at its time. With ``align_heading`` the track is also
    rotated so that its displacement between the first two waypoints points along the surveyed one
    (the known start heading of the paper's setting); otherwise the rotation vector's absolute
    heading is used as it is.

    Parameters
    ----------
    velocity
        ``t,ve,vn`` table (e.g. from :func:`pdr_velocity`).
    waypoints
        ``t,lat,lon``, at least two rows.
    align_heading
        Rotate onto the first surveyed segment.

    Returns
    -------
    numpy.ndarray
        ``len(waypoints) - 1`` errors in metres.
    """
    frame = LocalFrame.around(float(waypoints["lon"].iat[0]), float(waypoints["lat"].iat[0]))
    x, y = frame.to_xy(waypoints["lon"].to_numpy(), waypoints["lat"].to_numpy())
    truth = np.column_stack([x - x[0], y - y[0]])
    track = integrate_velocity(velocity, float(waypoints["t"].iat[0]), waypoints["t"].to_numpy())
    if align_heading:
        angle = np.arctan2(truth[1, 1], truth[1, 0]) - np.arctan2(track[1, 1], track[1, 0])
        c, s = np.cos(angle), np.sin(angle)
        track = track @ np.array([[c, s], [-s, c]])
    return np.linalg.norm(track[1:] - truth[1:], axis=1)


def evaluate_ipin(path: str, trials: list[str] | None = None) -> tuple[pd.DataFrame, pd.DataFrame]:
    """PDR on IPIN trials, scored against the surveyed waypoints.

    Footsteps are counted and dead reckoning is scored between the first and last waypoint, starting
    from the first waypoint's position.

    Parameters
    ----------
    path
        The IPIN ``.h5``.
    trials
        Trial names (default: all).

    Returns
    -------
    trials : pandas.DataFrame
        One row per trial: ``trial, device, floors, steps, walk_s, surveyed_m, pdr_m, ratio``
        (PDR / surveyed path length) and ``err_median_m, err_p90_m`` (absolute heading) and
        ``aligned_median_m, aligned_p90_m`` (heading aligned on the first segment).
    waypoints : pandas.DataFrame
        One row per scored waypoint: ``trial, waypoint`` (index, from 1), ``err_m, aligned_err_m``.
    """
    rows, scored = [], []
    names = trials or ipin.list_trials(path)
    for name in tqdm(names, desc="PDR", unit="trial", disable=not sys.stderr.isatty()):
        session = ipin.read_trial(path, name)
        wp = session.waypoints
        t0, t1 = float(wp["t"].iat[0]), float(wp["t"].iat[-1])
        steps = detect_steps(session.imu)
        velocity = pdr_velocity(session.imu, steps)
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
    args = parser.parse_args(argv)
    table, scored = evaluate_ipin(args.h5)
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
