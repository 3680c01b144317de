"""Figures for inertial odometry on held-out recordings: RoNIN against the PDR baseline.

Each method is turned into a trajectory sampled at the RoNIN window centres (every ``stride`` grid
samples: 100 ms by default) over the ground-truth span, started at the ground-truth position of the
first centre:

- RoNIN: its window velocities integrated with the trapezoidal rule;
- PDR (:func:`curbside.localize.pdr.pdr_velocity`): step displacements accumulated at the step
  times and linearly interpolated in time.

Metrics per recording
---------------------
``distance_ratio``
    Length of the estimated trajectory / length of the ground-truth (waypoint) path over the span.
``speed_error_mps``
    Mean absolute difference of speeds over one-second windows (ground truth: the waypoint path's
    mean velocity over the window; PDR: its trajectory's displacement over the window).
``ate_m``
    Absolute trajectory error (RoNIN's definition): RMSE of positions after the best 2-D rotation
    about the common start point (the MS floor-plan frame is not north-up).
``rte_m``
    Relative trajectory error: RMSE over every 60 s interval of the difference between estimated
    and true displacement, with the same rotation; recordings shorter than 60 s use the end error
    scaled by 60 s / duration (RoNIN's rule).
``ate_raw_m``
    As ``ate_m`` without the rotation: what a user gets in the orientation source's frame (true
    north for IPIN, whose ground truth is surveyed).
``waypoint_errors_m``
    Distances between the (unrotated) trajectory and each ground-truth waypoint inside the span.
``yaw_spread_mps``, ``early_yaw_spread_mps``, ``familiar`` (RoNIN only)
    The model's yaw-equivariance spread, median over the recording and over its first 30 s, and whether
    the model knows the recording by it (:mod:`curbside.localize.ronin.familiarity`; no ground truth
    needed).
"""

from __future__ import annotations

import logging
from dataclasses import asdict
from pathlib import Path

import numpy as np
from tqdm.auto import tqdm

from curbside.localize.imu import WorldSamples
from curbside.localize.ronin.data import Recording
from curbside.localize.ronin.familiarity import familiarity
from curbside.localize.ronin.infer import check_compatible, infer_windows
from curbside.localize.ronin.model import RoninResNet
from curbside.localize.ronin.stream import RoninStreamConfig, WindowCutter

logger = logging.getLogger(__name__)

#: RTE interval (s), as in RoNIN.
RTE_INTERVAL_S = 60.0


def best_rotation(estimate: np.ndarray, truth: np.ndarray) -> float:
    """Angle (rad) of the rotation about the origin that best maps ``estimate`` onto ``truth`` (N, 2)."""
    cross = np.sum(estimate[:, 0] * truth[:, 1] - estimate[:, 1] * truth[:, 0])
    dot = np.sum(estimate[:, 0] * truth[:, 0] + estimate[:, 1] * truth[:, 1])
    return float(np.arctan2(cross, dot))


def _rotate(xy: np.ndarray, angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return xy @ np.array([[c, s], [-s, c]])


def _one_second_velocity(t: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """Mean velocity over the second centred on each time of ``t`` (those a second from either end)."""
    centre = t[(t - 0.5 >= t[0]) & (t + 0.5 <= t[-1])]
    return np.column_stack([np.interp(centre + 0.5, t, xy[:, k]) - np.interp(centre - 0.5, t, xy[:, k])
                            for k in (0, 1)])


def trajectory_metrics(t: np.ndarray, estimate: np.ndarray, truth: np.ndarray,
                       waypoints: np.ndarray | None = None) -> dict[str, float | list[float]]:
    """All per-recording metrics of one estimated trajectory (see the module docstring).

    Parameters
    ----------
    t
        ``(N,)`` times (s), uniform.
    estimate, truth
        ``(N, 2)`` positions (m); both start at the same point.
    waypoints
        ``(M, 3)`` ``t, x, y`` ground-truth points for ``waypoint_errors_m``.

    Returns
    -------
    dict
    """
    rel_est, rel_true = estimate - estimate[0], truth - truth[0]
    angle = best_rotation(rel_est, rel_true)
    aligned = _rotate(rel_est, angle)
    dt = float(np.median(np.diff(t)))
    v_est, v_true = (_one_second_velocity(t, xy) for xy in (aligned, rel_true))
    true_len = float(np.sum(np.linalg.norm(np.diff(truth, axis=0), axis=1)))
    est_len = float(np.sum(np.linalg.norm(np.diff(estimate, axis=0), axis=1)))
    duration = t[-1] - t[0]
    lag = int(round(RTE_INTERVAL_S / dt))
    if len(t) > lag:
        d_err = (aligned[lag:] - aligned[:-lag]) - (rel_true[lag:] - rel_true[:-lag])
        rte = float(np.sqrt(np.mean(np.sum(d_err**2, axis=1))))
    else:
        rte = float(np.linalg.norm(aligned[-1] - rel_true[-1]) * RTE_INTERVAL_S / max(duration, 1e-9))
    out: dict[str, float | list[float]] = {
        "duration_s": float(duration),
        "path_length_m": true_len,
        "distance_ratio": est_len / true_len if true_len > 0 else float("nan"),
        "speed_error_mps": float(np.mean(np.abs(np.linalg.norm(v_est, axis=1)
                                                - np.linalg.norm(v_true, axis=1)))),
        "ate_m": float(np.sqrt(np.mean(np.sum((aligned - rel_true) ** 2, axis=1)))),
        "ate_raw_m": float(np.sqrt(np.mean(np.sum((rel_est - rel_true) ** 2, axis=1)))),
        "rte_m": rte,
        "rotation_deg": float(np.degrees(angle)),
    }
    if waypoints is not None:
        inside = (waypoints[:, 0] >= t[0]) & (waypoints[:, 0] <= t[-1])
        wp = waypoints[inside]
        ex = np.interp(wp[:, 0], t, estimate[:, 0])
        ey = np.interp(wp[:, 0], t, estimate[:, 1])
        out["waypoint_errors_m"] = np.hypot(ex - wp[:, 1], ey - wp[:, 2]).tolist()
    return out


def truth_windows(recording: Recording, config: RoninStreamConfig) -> tuple[np.ndarray, np.ndarray]:
    """Window-centre times and windows of ``recording`` lying wholly inside its ground-truth span.

    The recording's world-frame samples go through the streaming path's
    :class:`~curbside.localize.ronin.stream.WindowCutter` (grid anchored at the recording's first
    sample, a window every ``config.stride`` samples).
    """
    cutter = WindowCutter(config, recording.name)
    cutter.add(WorldSamples(recording.t, recording.features.astype(float), np.zeros(len(recording.t), int)))
    cutter.finish()
    t_c, windows = cutter.take()
    gt_t = recording.positions[:, 0]
    inside = (t_c - config.half_window_s >= gt_t[0]) & (t_c + config.half_window_s <= gt_t[-1])
    return t_c[inside], windows[inside]


def ronin_trajectory(model: RoninResNet, recording: Recording, config: RoninStreamConfig | None = None,
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Window-centre times, RoNIN trajectory and ground-truth positions over the ground-truth span:
    the windows of :func:`truth_windows` through :func:`infer_windows`."""
    config = config or RoninStreamConfig()
    check_compatible(model, config)
    t_c, windows = truth_windows(recording, config)
    gt_t = recording.positions[:, 0]
    if len(t_c) < 2:
        return np.zeros(0), np.zeros((0, 2)), np.zeros((0, 2))
    vel = infer_windows(model, windows, config.batch_size)
    truth = np.column_stack([np.interp(t_c, gt_t, recording.positions[:, k]) for k in (1, 2)])
    steps = 0.5 * (vel[1:] + vel[:-1]) * np.diff(t_c)[:, None]
    estimate = truth[0] + np.vstack([np.zeros((1, 2)), np.cumsum(steps, axis=0)])
    return t_c, estimate, truth


def pdr_trajectory(recording: Recording, t_c: np.ndarray, start: np.ndarray) -> np.ndarray | None:
    """PDR positions at ``t_c`` from the recording's raw IMU, started at ``start`` (None: no steps)."""
    from curbside.localize.pdr import pdr_velocity

    if recording.imu is None:
        return None
    vel = pdr_velocity(recording.imu)
    if len(vel) < 2:
        return None
    t_s = vel["t"].to_numpy()
    disp = vel[["ve", "vn"]].to_numpy()[1:] * np.diff(t_s)[:, None]
    pos = np.vstack([np.zeros((1, 2)), np.cumsum(disp, axis=0)])
    est = np.column_stack([np.interp(t_c, t_s, pos[:, 0]), np.interp(t_c, t_s, pos[:, 1])])
    return est - est[0] + start


def evaluate_recordings(recordings: list[Recording], model: RoninResNet, with_pdr: bool = True,
                        config: RoninStreamConfig | None = None, progress: bool = False) -> dict:
    """Per-recording and summary figures for RoNIN (and PDR) on ``recordings``.

    Parameters
    ----------
    recordings
        Held-out recordings (with ``imu`` kept when ``with_pdr``).
    model
        The RoNIN model.
    with_pdr
        Also evaluate the PDR baseline.
    config
        Stream parameters (stride, batch size); default :class:`RoninStreamConfig`.
    progress
        A progress bar over the recordings on a terminal.

    Returns
    -------
    dict
        ``{"model": config, "recordings": {name: {method: metrics}}, "summary": {source: {method: ...}}}``.
    """
    per: dict[str, dict] = {}
    for rec in tqdm(recordings, desc="ronin-eval", unit="recording", disable=None if progress else True):
        t_c, est, truth = ronin_trajectory(model, rec, config)
        if len(t_c) < 2:
            logger.info("%s: shorter than a window over its ground-truth span, skipped", rec.name)
            continue
        wp = rec.positions
        per[rec.name] = {"source": rec.source, "ronin": trajectory_metrics(t_c, est, truth, wp)}
        per[rec.name]["ronin"].update(_familiarity_metrics(model, rec, config or RoninStreamConfig()))
        if with_pdr:
            pdr = pdr_trajectory(rec, t_c, truth[0])
            if pdr is not None:
                per[rec.name]["pdr"] = trajectory_metrics(t_c, pdr, truth, wp)
    return {"model": {"arch": model.config.arch, "extra_best_epoch": model.config.extra.get("best_epoch")},
            "stream": asdict(config or RoninStreamConfig()), "recordings": per, "summary": summarise(per)}


def _familiarity_metrics(model: RoninResNet, recording: Recording, config: RoninStreamConfig) -> dict:
    """The model's yaw-equivariance spread on the recording (:mod:`curbside.localize.ronin.familiarity`)."""
    record = familiarity(model, *truth_windows(recording, config)).to_dict()
    return {"yaw_spread_mps": record["spread_mps"], "early_yaw_spread_mps": record["early_spread_mps"],
            "walking_windows": record["walking_windows"], "familiar": record["familiar"]}


def summarise(per: dict[str, dict]) -> dict:
    """Median / IQR / mean of each metric per source and method (waypoint errors pooled)."""
    summary: dict[str, dict] = {}
    for source in sorted({v["source"] for v in per.values()}):
        summary[source] = {}
        for method in ("ronin", "pdr"):
            rows = [v[method] for v in per.values() if v["source"] == source and method in v]
            if not rows:
                continue
            entry: dict[str, float | int] = {"n_recordings": len(rows)}
            for key in ("distance_ratio", "speed_error_mps", "ate_m", "ate_raw_m", "rte_m", "yaw_spread_mps"):
                vals = np.array([r.get(key) for r in rows], float)
                if key == "yaw_spread_mps" and not np.isfinite(vals).any():  # no walking, or PDR
                    continue
                q1, med, q3 = np.nanpercentile(vals, [25, 50, 75])
                entry[f"{key}_median"] = float(med)
                entry[f"{key}_iqr"] = [float(q1), float(q3)]
                entry[f"{key}_mean"] = float(np.nanmean(vals))
            wps = np.concatenate([r.get("waypoint_errors_m", []) for r in rows])
            if "yaw_spread_mps_median" in entry:
                entry["familiar"] = sum(r["familiar"] is True for r in rows)
            if len(wps):
                entry["waypoint_error_median_m"] = float(np.median(wps))
                entry["waypoint_error_p90_m"] = float(np.percentile(wps, 90))
            summary[source][method] = entry
    return summary


def format_summary(report: dict) -> str:
    """A plain-text table of the summary (printed by ``localize ronin-eval``).

    When the report names them (``weights``, ``split``, as ``localize ronin-eval`` writes it), a title
    says which weights were scored on which recordings, and whether those recordings are held out from
    the weights' training data. Every figure is a median over recordings, except the waypoint error,
    pooled over all waypoints.
    """
    lines = []
    weights, split = report.get("weights"), report.get("split")
    if weights is not None and split is not None:
        stride, rate = report["stream"]["stride"], report["stream"]["rate_hz"]
        scored = {v["source"] for v in report["recordings"].values()}
        seen = scored & set(weights.get("trained_on") or ())
        note = (f"; {split} recordings of {'/'.join(sorted(seen))} are not held out from these weights' "
                "training" if split != "test" and seen else "")
        lines.append(f"RoNIN weights {Path(weights['path']).name} (sha256 {weights['sha256'][:12]}) on the "
                     f"{split} split, a velocity every {1000 * stride / rate:g} ms{note}")
    lines.append("medians over recordings (waypoint errors: over all waypoints); distances in m, "
                 "speeds in m/s")
    lines.append(f"{'source':<6} {'method':<6} {'n':>4} {'dist ratio [IQR]':>22} {'speed err':>9} "
                 f"{'ATE':>8} {'RTE':>8} {'raw ATE':>8} {'wp err':>8} {'wp p90':>8} {'yaw spread':>10} "
                 f"{'familiar':>8}")
    for source, methods in report["summary"].items():
        for method, e in methods.items():
            iqr = e["distance_ratio_iqr"]
            lines.append(
                f"{source:<6} {method:<6} {e['n_recordings']:>4} "
                f"{e['distance_ratio_median']:>8.3f} [{iqr[0]:.2f},{iqr[1]:.2f}] "
                f"{e['speed_error_mps_median']:>9.3f} {e['ate_m_median']:>8.2f} {e['rte_m_median']:>8.2f} "
                f"{e['ate_raw_m_median']:>8.2f} {e.get('waypoint_error_median_m', float('nan')):>8.2f} "
                f"{e.get('waypoint_error_p90_m', float('nan')):>8.2f} {_spread_cells(e)}".rstrip()
            )
    return "\n".join(lines) + "\n"


def _spread_cells(entry: dict) -> str:
    """The yaw spread and familiar-count cells of a summary row (blank for PDR)."""
    if "yaw_spread_mps_median" not in entry:
        return f"{'':>10} {'':>8}"
    return f"{entry['yaw_spread_mps_median']:>10.3f} {entry['familiar']:>3}/{entry['n_recordings']:<4}"


def calibrate_output_scale(model: RoninResNet, recordings: list[Recording]) -> float:
    """Set ``model.config.output_scale`` so that the median distance ratio on ``recordings`` is 1.

    Use validation recordings (never the test split). Returns the new scale: 1.0 when no recording has
    a finite, positive ratio (each needs a window inside its ground truth, and some ground-truth
    distance and estimated motion).
    """
    model.config.output_scale = 1.0
    ratios = []
    for rec in recordings:
        t_c, est, truth = ronin_trajectory(model, rec)
        if len(t_c) >= 2:
            ratios.append(trajectory_metrics(t_c, est, truth)["distance_ratio"])
    ratios = [r for r in ratios if np.isfinite(r) and r > 0]
    if not ratios:
        return 1.0
    model.config.output_scale = float(1.0 / np.median(ratios))
    logger.info("output scale %.4f from %d validation recordings", model.config.output_scale, len(ratios))
    return model.config.output_scale
