"""RoNIN inference speed: batched windows per second on 2 CPU threads for a 10-minute recording.

The baseline, measured in the same run, is the same model applied window by window (what a naive
streaming loop does). Target (issue 4): at least 2,000 windows/s batched, i.e. 100x real time at
stride 10. Also reports the end-to-end ``ronin_velocity`` time from an ``imu.csv`` table (quaternion
rotation, resampling to 200 Hz, windowing, inference).

Usage: ``python benchmarks/bench_ronin.py [--weights PT] [--minutes 10] [--baseline-windows 600]``
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import pandas as pd
import torch
from scipy.spatial.transform import Rotation

from curbside.localize.ronin.infer import (
    load_model,
    make_windows,
    predict_windows,
    ronin_velocity,
    window_starts,
)


def synthetic_imu_table(minutes: float, rate_hz: float = 50.0, seed: int = 0) -> pd.DataFrame:
    """A phone-like ``imu.csv`` table (walking bounce, slow turns) of the given length."""
    rng = np.random.default_rng(seed)
    t = np.arange(int(minutes * 60 * rate_hz)) / rate_hz
    rot = Rotation.from_euler("ZX", np.column_stack([0.05 * t, 0.1 + 0.05 * np.sin(t)]))
    acc = rot.inv().apply(np.column_stack([rng.normal(0, 0.3, (len(t), 2)), 9.81 + 1.5 * np.sin(12 * t)]))
    gyro = rng.normal(0, 0.2, (len(t), 3))
    table = pd.DataFrame(np.column_stack([t, acc, gyro]), columns=["t", "ax", "ay", "az", "gx", "gy", "gz"])
    table[["qx", "qy", "qz", "qw"]] = rot.as_quat()
    return table


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--weights", help="weights .pt (default: the bundled compact model)")
    parser.add_argument("--minutes", type=float, default=10.0)
    parser.add_argument("--baseline-windows", type=int, default=600,
                        help="windows timed one by one for the baseline rate")
    args = parser.parse_args()
    torch.set_num_threads(2)
    model = load_model(args.weights)
    cfg = model.config
    rng = np.random.default_rng(0)
    n_samples = int(args.minutes * 60 * cfg.rate_hz)
    feats = rng.normal(0, 1, (n_samples, 6)).astype(np.float32)
    feats[:, 5] += 9.81
    starts = window_starts(n_samples, cfg.window, cfg.stride)
    windows = make_windows(feats, starts, cfg.window)
    predict_windows(model, windows[:512])  # warm-up

    tic = time.perf_counter()
    predict_windows(model, windows)
    batched = len(windows) / (time.perf_counter() - tic)

    few = windows[: args.baseline_windows]
    with torch.inference_mode():
        tic = time.perf_counter()
        for w in few:
            model(torch.from_numpy(np.ascontiguousarray(w[None])))
        single = len(few) / (time.perf_counter() - tic)

    table = synthetic_imu_table(args.minutes)
    tic = time.perf_counter()
    vel = ronin_velocity(table, model)
    end_to_end = time.perf_counter() - tic

    print(f"model: {cfg.arch}, {args.minutes:g} min at {cfg.rate_hz:g} Hz -> {len(windows)} windows "
          f"(window {cfg.window}, stride {cfg.stride}), torch threads {torch.get_num_threads()}")
    print(f"batched (torch.inference_mode, batches of 4096): {batched:10.0f} windows/s")
    print(f"window by window (baseline, {len(few)} windows):   {single:10.0f} windows/s")
    print(f"ratio batched / window-by-window:              {batched / single:10.1f}x")
    print(f"real-time factor at stride {cfg.stride}:                 "
          f"{batched * cfg.stride / cfg.rate_hz:10.0f}x")
    print(f"target >= 2000 windows/s:                      {'met' if batched >= 2000 else 'NOT met'}")
    print(f"end to end ronin_velocity on a {args.minutes:g}-min 50 Hz imu.csv table: {end_to_end:.2f} s "
          f"({len(vel)} velocities)")


if __name__ == "__main__":
    main()
