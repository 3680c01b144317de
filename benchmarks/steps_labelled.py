"""Footstep counts against counts established on real recordings, per carrying mode.

Scores :func:`curbside.localize.steps.detect_steps` on

- the labelled windows of ``tests/data/steps`` (Oxford Step Counter validation set: hand, trouser
  pocket, bag; footsteps from the authors' ground-truth device; see the README there), counted
  between the midpoints of the first two and of the last two true footsteps;
- the three IPIN 2023 windows counted by eye (hand held in front; ``tests/test_steps.py``);
- with ``--ipin FILE.h5`` also the IPIN trials' first minute, before the first surveyed point: the
  walker waves the phone to calibrate its compass, then stands still, so every footstep found there is
  a false one (it reports the figures for the waving and the standing part).

Usage::

    python benchmarks/steps_labelled.py [--ipin ../shared/data/ipin2023/ipin2023-t3.h5]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import pandas as pd

from curbside.localize.readers.ipin import list_trials, read_trial
from curbside.localize.steps import detect_steps

TESTS = Path(__file__).resolve().parents[1] / "tests" / "data"
MODES = {"hand": "hand", "frontpocket": "pocket", "backpocket": "pocket", "bag": "bag", "purse": "bag"}
IPIN_WINDOWS = [
    ("TrainingTrial01_repetition01", 61.5, 76.0, 20),
    ("TrainingTrial01_repetition01", 77.0, 81.3, 7),
    ("TrainingTrial23_repetition03", 61.0, 76.0, 24),
]


def labelled_rows() -> list[dict]:
    """One row per labelled window: recording, mode, how counted, true and detected footsteps."""
    rows = []
    for path in sorted((TESTS / "steps").glob("*.csv")):
        table = pd.read_csv(path)
        t = table["t_us"].to_numpy(float) / 1e6
        truth = t[1:][np.diff(table["gt_steps"].to_numpy()) > 0]
        imu = pd.DataFrame({"t": t, "ax": table["ax"], "ay": table["ay"], "az": table["az"]})
        found = detect_steps(imu)
        lo, hi = 0.5 * (truth[0] + truth[1]), 0.5 * (truth[-2] + truth[-1])
        rows.append({
            "recording": path.stem, "mode": MODES[path.stem.split("_")[1]], "counted_by": "device (Oxford)",
            "window_s": f"{lo - t[0]:.2f}-{hi - t[0]:.2f}",
            "true": int(((truth > lo) & (truth < hi)).sum()),
            "detected": int(((found > lo) & (found < hi)).sum()),
        })
    h5 = TESTS / "sessions" / "ipin2023-cut.h5"
    for trial, lo, hi, count in IPIN_WINDOWS:
        found = detect_steps(read_trial(h5, trial).imu)
        rows.append({
            "recording": f"IPIN {trial}", "mode": "hand", "counted_by": "eye (|a| plots)",
            "window_s": f"{lo}-{hi}", "true": count, "detected": int(((found >= lo) & (found < hi)).sum()),
        })
    return rows


def ipin_false_steps(path: Path) -> dict[str, int]:
    """Footsteps found before each trial's first surveyed point: while waving the phone, while standing."""
    waving = standing = trials = 0
    for name in list_trials(path):
        session = read_trial(path, name)
        start = float(session.waypoints["t"].iat[0])
        found = detect_steps(session.imu)
        # Waving ends 20-30 s before the walk; the last 2 s may hold the first footstep of the walk.
        waving += int((found < start - 22.0).sum())
        standing += int(((found >= start - 22.0) & (found < start - 2.0)).sum())
        trials += 1
    return {"trials": trials, "false_steps_waving": waving, "false_steps_standing": standing}


def main(argv: list[str] | None = None) -> int:
    """Print the per-window table, the per-mode totals and (with --ipin) the false footsteps."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--ipin", type=Path, help="IPIN 2023 .h5 for the false-footstep count")
    args = parser.parse_args(argv)
    table = pd.DataFrame(labelled_rows())
    table["error_%"] = (100 * (table["detected"] - table["true"]) / table["true"]).round(1)
    print(table.to_string(index=False))
    totals = table.groupby("mode")[["true", "detected"]].sum()
    totals["error_%"] = (100 * (totals["detected"] - totals["true"]) / totals["true"]).round(1)
    print()
    print(totals.to_string())
    if args.ipin:
        print()
        print(ipin_false_steps(args.ipin))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
