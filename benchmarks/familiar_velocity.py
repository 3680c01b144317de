"""What the velocity and the fixes of real phones look like next to the simulator's (docs/filter.md, "A
velocity model fitted to the walker"; docs/evaluate.md, "Known limits").

For each source it prints, per walk, the median relative change of the inertial speed from one
half-second window to the next while walking (the familiar-velocity test's statistic,
:class:`curbside.localize.velocity_checks.SpeedJitterCheck`), over the first 20 s of walking and over
the whole walk; and, where there is ground truth, how far the fixes move against the true track (the
ratio of their displacement over 30 s to the truth's), how far they trail the walker along the
direction of walking, and which exponential smoothing of the true track they fit best.

Usage::

    python benchmarks/familiar_velocity.py ../shared/data/ipin2023/ipin2023-t3.h5 \\
        [--ronin benchmarks/weights/ronin_ms_only.pt] [--sessions TUNE_DIR/tune/paper6 ...]

The IPIN trials are tracked with the bundled RoNIN (and with ``--ronin``'s model); ``--sessions`` adds
simulated session folders (e.g. those ``benchmarks/tune_fusion.py`` writes).
"""

from __future__ import annotations

import argparse
import dataclasses
import math
from pathlib import Path

import numpy as np
from scipy.signal import lfilter

from curbside.evaluate.groundtruth import waypoints_xy
from curbside.localize.runconfig import FamiliarVelocityConfig
from curbside.localize.session import Session, read_session
from curbside.localize.streams import DisplacementIntegrator
from curbside.localize.velocity_checks import SpeedJitterCheck
from curbside.projection import LocalFrame


def speed_changes(session: Session, t0: float) -> np.ndarray:
    """The test's samples over the whole walk from ``t0`` (no verdict: every sample kept)."""
    v = session.velocity
    d = DisplacementIntegrator(1.0)
    d.push(v["t"].to_numpy(), v[["ve", "vn"]].to_numpy())
    check = SpeedJitterCheck(FamiliarVelocityConfig(final_samples=0), t0, d.at(t0))
    check.observe(d.at, float(v["t"].iat[-1]))
    return np.array(check.samples)


def fix_motion(
    session: Session, window_s: float = 30.0
) -> tuple[list[float], list[float], dict[float, float]]:
    """Displacement ratios of the fixes over ``window_s`` (walks of 15 m or more), their error along the
    walking direction (m), and their median error against the true track smoothed with each time
    constant (s)."""
    wp = session.waypoints
    frame = LocalFrame.around(float(wp["lon"].iat[0]), float(wp["lat"].iat[0]))
    wt, wx, wy = waypoints_xy(wp, frame)
    g = session.gnss[session.gnss["accuracy_m"] > 0]
    gt = g["t"].to_numpy()
    gx, gy = frame.to_xy(g["lon"].to_numpy(), g["lat"].to_numpy())
    inside = (gt > wt[0]) & (gt < wt[-1])
    gt, gx, gy = gt[inside], gx[inside], gy[inside]
    ratios, along = [], []
    for a in np.arange(wt[0], wt[-1] - window_s, 5.0):
        first, last = (gt >= a) & (gt < a + 3), (gt > a + window_s - 3) & (gt <= a + window_s)
        true = np.hypot(*np.diff(np.interp([a + 1.5, a + window_s - 1.5], wt, wx)),
                        *np.diff(np.interp([a + 1.5, a + window_s - 1.5], wt, wy)))
        if first.any() and last.any() and true >= 15.0:
            fixes = math.hypot(gx[last].mean() - gx[first].mean(), gy[last].mean() - gy[first].mean())
            ratios.append(fixes / true)
    tx, ty = np.interp(gt, wt, wx), np.interp(gt, wt, wy)
    if len(gt) > 2:
        vx, vy = np.gradient(tx, gt), np.gradient(ty, gt)
        moving = np.hypot(vx, vy) > 0.5
        along = list(((gx - tx) * vx + (gy - ty) * vy)[moving] / np.hypot(vx, vy)[moving])
    grid = np.arange(wt[0], wt[-1], 0.1)
    px, py = np.interp(grid, wt, wx), np.interp(grid, wt, wy)
    smoothed = {}
    for tau in (0.0, 2.0, 4.0, 6.0, 8.0):
        sx, sy = px, py
        if tau > 0:  # s[k] = s[k-1] + a (p[k] - s[k-1]), started at p[0]
            a = 0.1 / tau
            sx, sy = (lfilter([a], [1.0, a - 1.0], p - p[0]) + p[0] for p in (px, py))
        late = gt > wt[0] + 20.0
        err = np.hypot(gx[late] - np.interp(gt[late], grid, sx), gy[late] - np.interp(gt[late], grid, sy))
        smoothed[tau] = float(np.median(err)) if len(err) else math.nan
    return ratios, along, smoothed


def first_smooth(samples: np.ndarray, threshold: float, min_samples: int = 40) -> int | None:
    """The number of samples at which their running median first falls under ``threshold``."""
    for k in range(min_samples, len(samples) + 1):
        if np.median(samples[:k]) < threshold:
            return k
    return None


def report(name: str, sessions: list[Session], truth: bool) -> None:
    first, whole, ratios, along, smoothed = [], [], [], [], []
    smooth_at: dict[float, list[int | None]] = {0.045: [], 0.05: [], 0.06: []}
    for s in sessions:
        t0 = float(s.waypoints["t"].iat[0]) if s.waypoints is not None else float(s.velocity["t"].iat[0])
        samples = speed_changes(s, t0)
        if len(samples) >= 40:
            first.append(np.median(samples[:40]))
            whole.append(np.median(samples))
        for threshold, found in smooth_at.items():
            found.append(first_smooth(samples, threshold))
        if truth and s.gnss is not None:
            r, a, sm = fix_motion(s)
            ratios += r
            along += a
            smoothed.append(sm)
    print(f"{name}: {len(sessions)} walks")
    if whole:
        print("  speed change per half second, median per walk: first 20 s of walking p0/p5/p50/p95 "
              f"{np.round(np.percentile(first, [0, 5, 50, 95]), 3)}; whole walk p0/p5/p50/p95 "
              f"{np.round(np.percentile(whole, [0, 5, 50, 95]), 3)}")
        for threshold, found in smooth_at.items():
            at = [k / 2 for k in found if k is not None]  # two samples per second of walking
            when = f", after {np.median(at):.0f} s of walking at the median" if at else ""
            print(f"  running median ever under {100 * threshold:g} %: {len(at)} of {len(found)} walks{when}")
    if ratios:
        print(f"  fixes' displacement over 30 s / the truth's: p10/p25/p50/p75/p90 "
              f"{np.round(np.percentile(ratios, [10, 25, 50, 75, 90]), 2)} ({len(ratios)} windows)")
        print(f"  fixes' error along the walking direction: median {np.median(along):+.2f} m")
        taus = smoothed[0].keys()
        fits = {tau: np.nanmedian([sm[tau] for sm in smoothed]) for tau in taus}
        print("  median error against the true track smoothed over tau: "
              + ", ".join(f"{tau:g} s {err:.2f} m" for tau, err in fits.items()))


def ipin_sessions(h5: str, weights: str | None) -> list[Session]:
    from curbside.localize.readers.ipin import list_trials, read_trial
    from curbside.localize.ronin.infer import load_model, ronin_velocity

    model = load_model(weights)
    out = []
    for name in list_trials(h5):
        s = read_trial(h5, name)
        if s.waypoints is None or len(s.waypoints) < 2 or s.imu is None:
            continue
        velocity = ronin_velocity(s.imu, model, source=f"{name}/imu.csv")
        out.append(dataclasses.replace(s, velocity=velocity))
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("h5", help="ipin2023-t3.h5")
    parser.add_argument("--ronin", metavar="PT", help="also with this RoNIN (e.g. one that never saw IPIN)")
    parser.add_argument("--sessions", nargs="*", default=[], metavar="DIR",
                        help="folders of simulated session folders (each reported on its own)")
    args = parser.parse_args(argv)
    report("IPIN 2023, bundled RoNIN", ipin_sessions(args.h5, None), truth=True)
    if args.ronin:
        report(f"IPIN 2023, {Path(args.ronin).name}", ipin_sessions(args.h5, args.ronin), truth=False)
    for folder in args.sessions:
        sessions = [read_session(p) for p in sorted(Path(folder).iterdir()) if p.is_dir()]
        report(f"simulated, {folder}", sessions, truth=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
