"""Fused (GNSS + PDR/RoNIN + particle filter, no map) vs raw GNSS on the 43 IPIN 2023 trials.

Error = horizontal distance between a method's position, linearly interpolated at each surveyed
waypoint's time (POSI), and the waypoint. Both methods are scored on the same waypoints: those inside
the span of the trial's valid fixes (the same rule as the dataset README's GNSS statistics), except
the first, where the filter is placed. The filter starts from the first waypoint and the heading
towards the second (``meta.json``'s start pose, the paper's setting); ``--no-start-pose`` starts it
from the first usable fix instead.

Usage::

    python benchmarks/ipin_fused_vs_gnss.py ../shared/data/ipin2023/ipin2023-t3.h5 [--seed 0]
        [--particles 500] [--modes gnss fused inertial] [--velocity-source auto|pdr|ronin]
        [--trials N] [--match TEXT] [--no-start-pose] [--csv out.csv]

The bundled RoNIN model was trained on every IPIN trial except the ``repetition04`` ones: score
RoNIN on those only (``--match repetition04``); PDR has no training data.
"""

from __future__ import annotations

import argparse
import logging
import sys

import numpy as np
import pandas as pd
from tqdm import tqdm

from curbside.evaluate import metrics
from curbside.localize.pipeline import track_session, valid_fixes
from curbside.localize.readers.ipin import list_trials, read_trial
from curbside.projection import LocalFrame


def waypoint_errors(track: pd.DataFrame, waypoints: pd.DataFrame) -> np.ndarray:
    """Error (m) at every waypoint, NaN where not scored (by ``metrics.waypoint_errors``)."""
    out = np.full(len(waypoints), np.nan)
    if len(track) < 2:
        return out
    scored = metrics.waypoint_errors(track, waypoints, exclude_first=False)
    out[np.searchsorted(waypoints["t"].to_numpy(float), scored["t"].to_numpy(float))] = scored["error_m"]
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("h5", help="ipin2023-t3.h5")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--particles", type=int, default=500)
    parser.add_argument("--modes", nargs="+", default=["gnss", "fused", "inertial"])
    parser.add_argument("--velocity-source", default="auto")
    parser.add_argument("--trials", type=int, default=None, help="only the first N trials")
    parser.add_argument("--match", default="", help="only trials whose name contains this text, e.g. "
                        "repetition04 (the trials the bundled RoNIN model did not train on)")
    parser.add_argument("--no-start-pose", action="store_true")
    parser.add_argument("--csv", help="write per-waypoint errors here")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.ERROR)

    rows = []
    trials = [t for t in list_trials(args.h5) if args.match in t][: args.trials]
    sources: set[str] = set()
    for trial in tqdm(trials, unit="trial", file=sys.stderr):
        session = read_trial(args.h5, trial)
        start = session.meta["start"]
        frame = LocalFrame.around(start["lon"], start["lat"])
        tf = valid_fixes(session.gnss, frame)[0]
        errors = {}
        for mode in args.modes:
            try:
                result = track_session(
                    session, None, mode, particles=args.particles, seed=args.seed,
                    velocity_source=args.velocity_source, use_start_pose=not args.no_start_pose,
                )
                track = result.track
                sources.add(result.velocity_source or "-")
            except Exception as exc:  # noqa: BLE001 - report and go on with the other trials
                print(f"{trial} {mode}: {exc}", file=sys.stderr)
                continue
            errors[mode] = waypoint_errors(track, session.waypoints)
        tw = session.waypoints["t"].to_numpy()
        scored = (tw >= tf[0]) & (tw <= tf[-1]) if len(tf) else np.zeros(len(tw), bool)
        scored[0] = False  # the start pose: the filters are placed there
        for mode, err in errors.items():
            for k in np.flatnonzero(scored):
                rows.append({"trial": session.name, "group": session.name[:15], "mode": mode,
                             "waypoint": int(k), "error_m": err[k]})
    df = pd.DataFrame(rows)
    if args.csv:
        df.to_csv(args.csv, index=False)
    df["set"] = np.select(
        [df["trial"].str.match(r"TrainingTrial0"), df["trial"].str.match(r"TrainingTrial2")],
        ["floor 0 (01-05)", "floor -2 (21-27)"], "floor changes (51-53)",
    )
    summary = []
    for name, part in [("all trials", df), *df.groupby("set")]:
        for mode, g in part.groupby("mode"):
            e = g["error_m"].dropna()
            summary.append({"set": name, "mode": mode, "waypoints": len(e),
                            "median_m": e.median(), "p90_m": e.quantile(0.9), "mean_m": e.mean()})
    table = pd.DataFrame(summary).pivot(index="set", columns="mode", values=["median_m", "p90_m"])
    print(f"IPIN 2023: error at surveyed waypoints (m), seed {args.seed}, N={args.particles}, "
          f"{len(trials)} trials, {df['waypoint'].groupby(df['mode']).size().max()} waypoints per mode, "
          f"velocity from {', '.join(sorted(sources - {'-'}))}")
    print(table.round(1).to_string())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
