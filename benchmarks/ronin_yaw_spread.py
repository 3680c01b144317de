"""Does a RoNIN model know a recording? Its yaw-equivariance spread against its velocity error, on real
recordings (docs/ronin.md, "Does the model know this recording?").

For each recording and model it prints the median yaw-equivariance spread
(:func:`curbside.localize.ronin.familiarity.familiarity`: every 5th window run under six yaw turns)
over the first 30 s and over the whole recording, and the median error of the model's one-second
velocity against the ground-truth path's; then the medians and ranges per group (source, split, model)
and the correlation of spread and error across recordings.

Usage::

    python benchmarks/ronin_yaw_spread.py --ipin ../shared/data/ipin2023/ipin2023-t3.h5 \\
        --ms-indoor ../shared/data/imu/ms-indoor-2020.h5 --ronin benchmarks/weights/ronin_ms_only.pt \\
        [--ms-paths 12] [--csv rows.csv]

The bundled model and ``--ronin``'s run on the same recordings: every IPIN trial (the bundled model was
trained on the training trials, not on ``repetition04``) and the first ``--ms-paths`` held-out
MS-indoor paths (held out from both models).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import pandas as pd

from curbside.localize.ronin.data import Recording, read_ipin, read_ms_indoor
from curbside.localize.ronin.evaluate import truth_windows
from curbside.localize.ronin.familiarity import TEST_EVERY, familiarity
from curbside.localize.ronin.infer import infer_windows, load_model
from curbside.localize.ronin.stream import RoninStreamConfig


def velocity_error_mps(model, recording: Recording, t_c: np.ndarray, windows: np.ndarray) -> float:
    """Median distance between the model's velocity and the ground-truth path's over each window's second."""
    t_c, windows = t_c[::TEST_EVERY], windows[::TEST_EVERY]
    gt = recording.positions
    xy = [np.column_stack([np.interp(t, gt[:, 0], gt[:, k]) for k in (1, 2)]) for t in (t_c + 0.5, t_c - 0.5)]
    return float(np.median(np.linalg.norm(infer_windows(model, windows) - (xy[0] - xy[1]), axis=1)))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--ipin", required=True, metavar="H5", help="ipin2023-t3.h5")
    parser.add_argument("--ms-indoor", required=True, metavar="H5", help="ms-indoor-2020.h5")
    parser.add_argument("--ronin", required=True, metavar="PT",
                        help="a second model, e.g. one that never saw IPIN")
    parser.add_argument("--ms-paths", type=int, default=12, help="held-out MS-indoor paths (default 12)")
    parser.add_argument("--csv", help="also write the per-recording rows here")
    args = parser.parse_args(argv)
    config = RoninStreamConfig()
    models = {"bundled": load_model(None), Path(args.ronin).stem: load_model(args.ronin)}
    recordings = read_ipin(args.ipin, progress=False)
    held_out_ms = [r for r in read_ms_indoor(args.ms_indoor, progress=False) if r.split == "test"]
    recordings += held_out_ms[: args.ms_paths]
    rows = []
    for rec in recordings:
        t_c, windows = truth_windows(rec, config)
        if len(t_c) < 2 * TEST_EVERY:
            continue
        for name, model in models.items():
            verdict = familiarity(model, t_c, windows)
            rows.append({"recording": rec.name, "group": f"{rec.source}/{rec.split}", "model": name,
                         "early_spread_mps": verdict.early_spread_mps, "spread_mps": verdict.spread_mps,
                         "familiar": verdict.familiar,
                         "velocity_error_mps": velocity_error_mps(model, rec, t_c, windows)})
    table = pd.DataFrame(rows)
    if args.csv:
        table.to_csv(args.csv, index=False)
    summary = table.groupby(["group", "model"]).agg(
        recordings=("recording", "size"), familiar=("familiar", "sum"),
        early_median=("early_spread_mps", "median"), early_min=("early_spread_mps", "min"),
        early_max=("early_spread_mps", "max"), whole_median=("spread_mps", "median"),
        error_median=("velocity_error_mps", "median"))
    print(summary.round(3).to_string())
    corr = np.corrcoef(table["spread_mps"], table["velocity_error_mps"])[0, 1]
    print(f"correlation of the whole-recording spread and the velocity error across recordings: {corr:.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
