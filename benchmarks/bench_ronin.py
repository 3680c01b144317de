"""RoNIN cost for a live service: inference in fixed-shape batches, streaming preprocessing, rotations.

Every figure is a ratio or a rate measured in this run, on this machine, with CPU time (process time,
all threads) beside the wall time so that a loaded machine distorts less:

1. **Inference**: windows per second in fixed-shape padded batches of each ``--batch-sizes`` value
   (what :func:`infer_windows` does), against the same model applied window by window (what a naive
   streaming loop does): the ratio is the speed-up of batching.
2. **Streaming preprocessing**: a synthetic 50 Hz phone session pushed through :class:`RoninStream` in
   0.5 s chunks (what the navigation app sends), as CPU seconds per second of IMU, against the same
   session pushed in one piece.
3. **Service budget**: CPU share of ``--walkers`` sessions at each stride (windows per second needed /
   windows per CPU-second measured in 1, plus the streaming cost of 2), for the 2-core target machine.
4. **Rotations (issue 8)**: the hand-written quaternion product of the gyroscope scan and the
   hand-written vector rotation against ``scipy.spatial.transform.Rotation``.

Usage: ``python benchmarks/bench_ronin.py [--weights PT] [--threads 1] [--walkers 200]``
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable

import numpy as np
import pandas as pd
import torch
from scipy.spatial.transform import Rotation

from curbside.localize.gyro import quat_mul, rotate_vectors
from curbside.localize.ronin.infer import infer_windows, load_model
from curbside.localize.ronin.stream import RoninStream, RoninStreamConfig


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


def timed(fn: Callable[[], object], repeat: int = 1) -> tuple[float, float]:
    """Best wall time and its CPU (process) time of ``repeat`` calls, seconds per call."""
    best = (np.inf, np.inf)
    for _ in range(repeat):
        wall, cpu = time.perf_counter(), time.process_time()
        fn()
        best = min(best, (time.perf_counter() - wall, time.process_time() - cpu))
    return best


def bench_inference(model, windows: np.ndarray, batch_sizes: list[int], n_single: int) -> dict[int, float]:
    """Print windows/s per batch size and against window by window; return windows per CPU-second."""
    few = windows[:n_single]

    def one_by_one() -> None:
        with torch.inference_mode():
            for w in few:
                model(torch.from_numpy(np.ascontiguousarray(w[None])))

    single_wall, single_cpu = timed(one_by_one)
    print(f"window by window (baseline, {n_single} windows): {n_single / single_wall:8.0f} windows/s wall, "
          f"{n_single / single_cpu:8.0f} per CPU-second")
    per_cpu = {}
    for batch in batch_sizes:
        infer_windows(model, windows[: 2 * batch], batch)  # warm-up
        wall, cpu = timed(lambda b=batch: infer_windows(model, windows, b), repeat=2)
        per_cpu[batch] = len(windows) / cpu
        print(f"fixed-shape batches of {batch:4d}:              {len(windows) / wall:8.0f} windows/s wall, "
              f"{per_cpu[batch]:8.0f} per CPU-second, {single_wall / wall * len(windows) / n_single:5.1f}x "
              f"window by window")
    return per_cpu


def bench_streaming(table: pd.DataFrame, chunk_s: float) -> float:
    """Print and return the CPU seconds per second of IMU of streaming ``table`` in ``chunk_s`` chunks."""
    duration = float(table["t"].iat[-1] - table["t"].iat[0])
    rows = max(1, int(round(chunk_s / np.median(np.diff(table["t"])))))

    def streamed() -> None:
        stream = RoninStream()
        for lo in range(0, len(table), rows):
            stream.push(table.iloc[lo : lo + rows])
            stream.take_windows()
        stream.finish()

    def whole() -> None:
        stream = RoninStream()
        stream.push(table)
        stream.finish()
        stream.take_windows()

    chunk_wall, chunk_cpu = timed(streamed)
    whole_wall, whole_cpu = timed(whole)
    print(f"streaming preprocessing, {chunk_s:g} s chunks ({rows} rows): "
          f"{1e3 * chunk_cpu / duration:6.2f} ms CPU per second of IMU ({1e3 * chunk_wall / duration:.2f} ms "
          f"wall); in one piece: {1e3 * whole_cpu / duration:.2f} ms ({chunk_cpu / whole_cpu:.1f}x less)")
    return chunk_cpu / duration


def bench_rotations(n: int = 100_000) -> None:
    """Issue 8: hand-written quaternion code against scipy's Rotation, same inputs, same run."""
    p, q = Rotation.random(n, rng=1).as_quat(), Rotation.random(n, rng=2).as_quat()
    v = np.random.default_rng(0).normal(size=(n, 3))
    rot = Rotation.from_quat(q)
    for name, ours, theirs in [
        ("quaternion product", lambda: quat_mul(p, q), lambda: (Rotation.from_quat(p) * rot).as_quat()),
        ("rotate vectors", lambda: rotate_vectors(q, v), lambda: rot.apply(v)),
    ]:
        mine, scipys = timed(ours, repeat=5)[1], timed(theirs, repeat=5)[1]
        print(f"{name:<20s} ({n} rows): hand-written {1e3 * mine:6.2f} ms, "
              f"scipy Rotation {1e3 * scipys:6.2f} ms ({scipys / mine:.1f}x)")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--weights", help="weights .pt (default: the bundled compact model)")
    parser.add_argument("--threads", type=int, default=1, help="torch CPU threads (one per worker process)")
    parser.add_argument("--minutes", type=float, default=5.0, help="length of the synthetic session")
    parser.add_argument("--batch-sizes", type=int, nargs="+", default=[16, 32, 64, 128, 256])
    parser.add_argument("--baseline-windows", type=int, default=300,
                        help="windows timed one by one for the baseline rate")
    parser.add_argument("--walkers", type=int, default=200, help="sessions of the service budget")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    model = load_model(args.weights)
    table = synthetic_imu_table(args.minutes)
    stream = RoninStream(RoninStreamConfig(stride=10))
    stream.push(table)
    stream.finish()
    _, windows = stream.take_windows()
    print(f"model {model.config.arch}, torch {torch.__version__}, {args.threads} thread(s); "
          f"{len(windows)} windows from a {args.minutes:g}-min 50 Hz session")
    per_cpu = bench_inference(model, windows, args.batch_sizes, args.baseline_windows)
    streaming = bench_streaming(table, chunk_s=0.5)
    best = max(per_cpu, key=per_cpu.get)
    print(f"service budget, {args.walkers} walkers, batches of {best} (CPU share of one core):")
    for stride in (10, 20, 40):
        needed = args.walkers * model.config.rate_hz / stride
        share = needed / per_cpu[best] + args.walkers * streaming
        print(f"  stride {stride:2d}: {needed:6.0f} windows/s -> {share:5.2f} cores "
              f"({100 * share / 2:.0f} % of a 2-core machine)")
    bench_rotations()


if __name__ == "__main__":
    main()
