"""How wrong is a phone's inertial velocity? Error magnitudes measured on real recordings.

The ``phone`` simulation profile (:mod:`curbside.evaluate.simulate`) takes its magnitudes from here
where real data can give them, from the literature where it cannot (``docs/evaluate.md``). The
measurement uses the IPIN 2023 Track 3 trials (two Android phones held in front of the walker,
surveyed waypoints at every turn):

- **Heading error per leg.** Between two consecutive waypoints the walker went straight, so the
  direction of the displacement that the velocity integrates to over the leg, minus the direction
  of the surveyed leg, is the velocity's heading error on that leg (clockwise-positive, degrees).
  Legs shorter than ``min_leg_m`` are skipped (a 1 m waypoint error on a 4 m leg is 14 degrees).
- Per trial, from the legs: the **bias** (mean error), a **linear drift** (least-squares slope, deg
  per minute), and the **largest change between consecutive legs** (abrupt offsets).
- **Random walk.** Pooled over trials, the mean squared difference of the heading errors of two legs
  ``dt`` minutes apart grows as ``2 s^2 + q dt``: ``s`` is the per-leg noise (ground truth
  included), ``sqrt(q)`` the random-walk coefficient in deg/sqrt(min) (a least-squares line through
  all pairs up to ``max_lag_min``).
- **Speed scale.** The velocity's path length over the walk divided by the surveyed path length,
  and the spread of the same ratio leg by leg within a trial (short-term speed noise).
- **Speed noise over a window.** Inside each leg of ``window_s`` or more at walking pace, the path
  length the velocity integrates to over consecutive ``window_s`` windows divided by the surveyed
  one (:func:`window_speed_ratios`); the spread of that ratio around the walk's median is the
  along-track error the velocity adds in ``window_s``, with the per-walk scale taken out. The same
  function reads a simulated session (``velocity.csv`` and its exact ``waypoints.csv``), so the
  simulator's speed noise can be set beside a real model's (``benchmarks/speed_noise_check.py``).
- **Standing.** Each trial starts with about 30 s of vigorous handling (a calibration routine) and
  about 30 s of standing still before the first waypoint. Both are found from the accelerometer
  (1 s moving standard deviation of the magnitude below / above ``still_acc_sd``); the velocity's
  mean speed and its net drift over each give the phantom motion of a still and of a handled phone.

Run ``python -m curbside.evaluate.inertial_errors ../shared/data/ipin2023/ipin2023-t3.h5`` to print
the tables: RoNIN (bundled model) on the held-out ``repetition04`` trials, and the rotation vector's
forward-axis heading (what the orientation source alone does, untrained) on every trial.
"""

from __future__ import annotations

import argparse
import logging
from dataclasses import dataclass

import numpy as np
import pandas as pd
import pyproj

from curbside.errors import CurbsideInputError

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class MeasureConfig:
    """Thresholds of the measurement (see the module docstring)."""

    min_leg_m: float = 4.0
    max_lag_min: float = 2.0
    still_acc_sd: float = 0.5
    #: Margin (s) kept away from the first waypoint and from the handling/standing switch.
    margin_s: float = 2.0


def _plane(waypoints: pd.DataFrame) -> tuple[np.ndarray, np.ndarray]:
    """Waypoints on a true-north azimuthal-equidistant plane around the first one (metres)."""
    lon0, lat0 = float(waypoints["lon"].iat[0]), float(waypoints["lat"].iat[0])
    proj = pyproj.Proj(proj="aeqd", lon_0=lon0, lat_0=lat0, ellps="WGS84")
    x, y = proj(waypoints["lon"].to_numpy(), waypoints["lat"].to_numpy())
    return np.asarray(x), np.asarray(y)


def _displacement_at(velocity: pd.DataFrame, times: np.ndarray) -> np.ndarray:
    """East and north displacement (2, n) the velocity integrates to from its first row to ``times``."""
    t = velocity["t"].to_numpy(float)
    dt = np.diff(t, append=t[-1])
    return np.stack([
        np.interp(times, t, np.concatenate([[0.0], np.cumsum(velocity[c].to_numpy() * dt)[:-1]]))
        for c in ("ve", "vn")
    ])


def leg_errors(velocity: pd.DataFrame, waypoints: pd.DataFrame, config: MeasureConfig) -> pd.DataFrame:
    """Heading error and speed ratio of a velocity table on each surveyed leg.

    Parameters
    ----------
    velocity
        ``t, ve, vn`` (m/s, true-north frame).
    waypoints
        ``t, lat, lon`` surveyed taps.
    config
        ``min_leg_m``.

    Returns
    -------
    pandas.DataFrame
        ``t_mid_s, length_m, heading_err_deg, speed_ratio`` per leg long enough.
    """
    x, y = _plane(waypoints)
    wt = waypoints["t"].to_numpy(float)
    t = velocity["t"].to_numpy(float)
    de, dn = np.diff(_displacement_at(velocity, wt), axis=1)
    tx, ty = np.diff(x), np.diff(y)
    length = np.hypot(tx, ty)
    err = np.degrees(np.arctan2(de, dn) - np.arctan2(tx, ty))
    err = (err + 180.0) % 360.0 - 180.0
    keep = (length >= config.min_leg_m) & (wt[1:] <= t[-1]) & (wt[:-1] >= t[0])
    return pd.DataFrame(
        {
            "t_mid_s": ((wt[1:] + wt[:-1]) / 2)[keep],
            "length_m": length[keep],
            "heading_err_deg": err[keep],
            "speed_ratio": (np.hypot(de, dn) / np.maximum(length, 1e-9))[keep],
        }
    )


def window_speed_ratios(
    velocity: pd.DataFrame, waypoints: pd.DataFrame, window_s: float, min_speed_mps: float = 0.8
) -> np.ndarray:
    """Integrated over surveyed speed, window by window, inside the straight legs of a walk.

    Parameters
    ----------
    velocity
        ``t, ve, vn`` (m/s, true-north frame).
    waypoints
        ``t, lat, lon`` taps; between two the walker went straight at a steady pace.
    window_s
        Window length (s); each leg of at least ``window_s`` at ``min_speed_mps`` or faster gives
        ``floor(duration / window_s)`` windows from its start.
    min_speed_mps
        Legs slower than this (standing, waiting) give none.

    Returns
    -------
    numpy.ndarray
        The velocity's path length over each window divided by the leg's pace times ``window_s``.
    """
    x, y = _plane(waypoints)
    wt = waypoints["t"].to_numpy(float)
    t = velocity["t"].to_numpy(float)
    pace = np.hypot(np.diff(x), np.diff(y)) / np.maximum(np.diff(wt), 1e-9)
    count = (np.diff(wt) // window_s).astype(int)
    keep = (pace >= min_speed_mps) & (count > 0) & (wt[:-1] >= t[0]) & (wt[1:] <= t[-1])
    leg = np.repeat(np.flatnonzero(keep), count[keep])
    if not len(leg):
        return np.empty(0)
    k = np.concatenate([np.arange(c) for c in count[keep]])
    start = wt[leg] + k * window_s
    end = start + window_s
    de, dn = _displacement_at(velocity, end) - _displacement_at(velocity, start)
    return np.hypot(de, dn) / (pace[leg] * window_s)


def trial_summary(legs: pd.DataFrame) -> dict[str, float]:
    """Bias, linear drift, residual spread, largest leg-to-leg change and speed figures of one trial."""
    e = legs["heading_err_deg"].to_numpy()
    tm = legs["t_mid_s"].to_numpy() / 60.0
    slope = float(np.polyfit(tm, e, 1)[0]) if len(e) >= 3 else float("nan")
    w = legs["length_m"].to_numpy()
    return {
        "legs": len(e),
        "bias_deg": float(np.average(e, weights=w)),
        "drift_deg_per_min": slope,
        "max_leg_change_deg": float(np.max(np.abs(np.diff(e)))) if len(e) >= 2 else float("nan"),
        "distance_ratio": float(np.sum(legs["speed_ratio"] * w) / np.sum(w)),
        "leg_speed_ratio_sd": float(np.std(legs["speed_ratio"])),
    }


def random_walk_fit(per_trial_legs: list[pd.DataFrame], max_lag_min: float) -> tuple[float, float]:
    """``(sqrt(q) deg/sqrt(min), s deg)`` from the pooled heading-error variogram (module docstring)."""
    lags, sq = [], []
    for legs in per_trial_legs:
        tm = legs["t_mid_s"].to_numpy() / 60.0
        e = legs["heading_err_deg"].to_numpy()
        i, j = np.triu_indices(len(e), k=1)
        lag = tm[j] - tm[i]
        ok = lag <= max_lag_min
        lags.append(lag[ok])
        sq.append((e[j] - e[i])[ok] ** 2)
    lag, d2 = np.concatenate(lags), np.concatenate(sq)
    if len(lag) < 3:
        return float("nan"), float("nan")
    q, c = np.polyfit(lag, d2, 1)
    return float(np.sqrt(max(q, 0.0))), float(np.sqrt(max(c, 0.0) / 2.0))


def standing_spans(
    imu: pd.DataFrame, t_first_s: float, config: MeasureConfig
) -> dict[str, tuple[float, float]]:
    """The still span right before the first waypoint and the handling span before it (app times).

    The still span runs back from the first waypoint while the 1 s moving standard deviation of
    the accelerometer magnitude stays below ``still_acc_sd``; the handling span is everything
    before it.
    """
    t = imu["t"].to_numpy(float)
    mag = np.sqrt(imu["ax"] ** 2 + imu["ay"] ** 2 + imu["az"] ** 2).to_numpy()
    rate = 1.0 / np.median(np.diff(t))
    sd = pd.Series(mag).rolling(max(3, int(round(rate))), center=True, min_periods=1).std().to_numpy()
    before = t < t_first_s - config.margin_s
    moving = np.flatnonzero(before & (sd > config.still_acc_sd))
    if len(moving) == 0:
        return {"still": (float(t[0]), t_first_s - config.margin_s)}
    switch = float(t[moving[-1]])
    return {
        "handling": (float(t[0]), switch - config.margin_s),
        "still": (switch + config.margin_s, t_first_s - config.margin_s),
    }


def phantom_motion(velocity: pd.DataFrame, span: tuple[float, float]) -> dict[str, float]:
    """Mean speed and net drift speed (net displacement / duration) of a velocity over a span."""
    t = velocity["t"].to_numpy(float)
    m = (t >= span[0]) & (t <= span[1])
    if m.sum() < 2:
        return {"duration_s": 0.0, "mean_speed_mps": float("nan"), "net_speed_mps": float("nan")}
    dt = np.gradient(t[m])
    ve, vn = velocity["ve"].to_numpy()[m], velocity["vn"].to_numpy()[m]
    duration = float(t[m][-1] - t[m][0])
    return {
        "duration_s": duration,
        "mean_speed_mps": float(np.mean(np.hypot(ve, vn))),
        "net_speed_mps": float(np.hypot(np.sum(ve * dt), np.sum(vn * dt)) / max(duration, 1e-9)),
    }


def forward_velocity(imu: pd.DataFrame, walking_speed_mps: float = 1.0) -> pd.DataFrame:
    """A unit-speed velocity along the phone's forward axis (the orientation source's heading only)."""
    from curbside.localize.pdr import forward_heading_vectors

    v = forward_heading_vectors(imu) * walking_speed_mps
    return pd.DataFrame({"t": imu["t"].to_numpy(float), "ve": v[:, 0], "vn": v[:, 1]})


def measure_ipin(
    h5: str, source: str = "ronin", held_out_only: bool = True, config: MeasureConfig | None = None
) -> tuple[pd.DataFrame, dict[str, float]]:
    """Per-trial error figures and their pooled summary on IPIN 2023 trials.

    Parameters
    ----------
    h5
        ``ipin2023-t3.h5``.
    source
        ``ronin`` (the bundled model's velocity) or ``rotvec`` (the rotation vector's forward axis:
        heading only, speed figures meaningless).
    held_out_only
        Only the ``repetition04`` trials RoNIN never saw (required for ``ronin``).
    config
        Thresholds.

    Returns
    -------
    (pandas.DataFrame, dict)
        One row per trial (:func:`trial_summary` plus phantom motion); pooled figures: the spread
        (standard deviation) of the bias across trials, the median absolute drift, the random-walk
        coefficient, the per-leg noise, the spread of the distance ratio and the phantom speeds.
    """
    from curbside.localize.readers.ipin import list_trials, read_trial

    config = config or MeasureConfig()
    if source not in ("ronin", "rotvec"):
        raise CurbsideInputError("source", f"unknown source {source!r}; ronin or rotvec")
    if source == "ronin" and not held_out_only:
        raise CurbsideInputError("held_out_only", "RoNIN trained on the other trials: use held-out ones")
    model = None
    if source == "ronin":
        from curbside.localize.ronin.infer import load_model

        model = load_model()
    names = [n for n in list_trials(h5) if not held_out_only or "repetition04" in n]
    rows, all_legs = [], []
    for name in names:
        session = read_trial(h5, name)
        if session.waypoints is None:
            log.warning("%s: no surveyed waypoints to measure against; skipped", name)
            continue
        if source == "ronin":
            from curbside.localize.ronin.infer import ronin_velocity

            velocity = ronin_velocity(session.imu, model)
        else:
            velocity = forward_velocity(session.imu)
        legs = leg_errors(velocity, session.waypoints, config)
        if len(legs) < 2:
            log.warning("%s: fewer than two legs of %.0f m or more; skipped", name, config.min_leg_m)
            continue
        all_legs.append(legs)
        row = {"trial": session.name, **trial_summary(legs)}
        spans = standing_spans(session.imu, float(session.waypoints["t"].iat[0]), config)
        for kind, span in spans.items():
            row.update({f"{kind}_{k}": v for k, v in phantom_motion(velocity, span).items()})
        rows.append(row)
    table = pd.DataFrame(rows)
    walk, noise = random_walk_fit(all_legs, config.max_lag_min)
    pooled = {
        "trials": len(table),
        "legs": int(table["legs"].sum()),
        "bias_sd_deg": float(table["bias_deg"].std()),
        "bias_abs_max_deg": float(table["bias_deg"].abs().max()),
        "drift_abs_median_deg_per_min": float(table["drift_deg_per_min"].abs().median()),
        "random_walk_deg_per_sqrt_min": walk,
        "leg_noise_deg": noise,
        "max_leg_change_median_deg": float(table["max_leg_change_deg"].median()),
        "distance_ratio_sd": float(table["distance_ratio"].std()),
        "leg_speed_ratio_sd_median": float(table["leg_speed_ratio_sd"].median()),
    }
    for kind in ("still", "handling"):
        if f"{kind}_mean_speed_mps" in table:
            pooled[f"{kind}_mean_speed_mps"] = float(table[f"{kind}_mean_speed_mps"].median())
            pooled[f"{kind}_net_speed_mps"] = float(table[f"{kind}_net_speed_mps"].median())
    return table, pooled


def main(argv: list[str] | None = None) -> int:
    """``python -m curbside.evaluate.inertial_errors FILE.h5``: the tables behind the phone profile."""
    parser = argparse.ArgumentParser(
        prog="python -m curbside.evaluate.inertial_errors", description=main.__doc__
    )
    parser.add_argument("h5", help="IPIN 2023 .h5 (../shared/data/ipin2023/ipin2023-t3.h5)")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.WARNING)
    for source, held_out in (("ronin", True), ("rotvec", False)):
        table, pooled = measure_ipin(args.h5, source, held_out)
        title = (
            "RoNIN (bundled), held-out trials"
            if source == "ronin"
            else "rotation vector forward axis, all trials"
        )
        print(f"\n## {title}\n")
        with pd.option_context("display.width", 220, "display.max_columns", 30, "display.precision", 2):
            print(table.to_string(index=False))
        print()
        for key, value in pooled.items():
            print(f"- {key}: {value:.3g}" if isinstance(value, float) else f"- {key}: {value}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
