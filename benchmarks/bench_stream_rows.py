"""CPU cost of a live session per second of walk when the client sends one row (or a few) per request.

A real walk (an IPIN 2023 trial: 50 Hz IMU with the orientation quaternion, 1 Hz GNSS, a start pose)
goes through the objects the service runs for each request (:mod:`curbside.localize.serve.service`):
:meth:`LiveSession.push <curbside.localize.live.LiveSession.push>` (validation, RoNIN windows,
footsteps), :meth:`InferenceQueue.collect <curbside.localize.live.InferenceQueue.collect>`,
:meth:`LiveSession.advance <curbside.localize.live.LiveSession.advance>` (the filter) and
:func:`~curbside.localize.serve.answers.estimate_of` (the reply), in batches of ``--rows`` IMU rows,
each fix in the batch that carries the IMU rows of its time. RoNIN inference runs as the service's
thread runs it at real time: whole batches at once, a partial (padded) batch once its first window
has waited ``--inference-wait-s`` seconds of walk. No HTTP, no JSON, one process.

Every figure is CPU time (process time, all threads) per second of walk, measured in this run beside
the **whole-walk batch run** (the same session pushed in one piece, as ``localize run`` computes it):
the ratio to it is the per-request overhead. Inference is reported apart (its cost depends on the
service's ``inference_wait_s``, not on the batch size). Each streamed track is checked equal to the
whole-walk one.

Usage::

    python benchmarks/bench_stream_rows.py [--walk H5::TRIAL] [--rows 1 10 50] [--repeat 1]
                                           [--profile ROWS] [--threads 1]

``--profile ROWS`` prints the cProfile of the run in batches of ``ROWS`` (by own time). The machine
may be shared: compare figures of one run.
"""

from __future__ import annotations

import argparse
import cProfile
import logging
import pstats
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd
import torch

from curbside.localize.engine import StartPose
from curbside.localize.live import (
    GNSS_COLUMNS,
    IMU_QUAT_COLUMNS,
    InferenceQueue,
    LiveSession,
    stream_session,
)
from curbside.localize.readers import read_any
from curbside.localize.runconfig import RunConfig
from curbside.localize.serve.answers import estimate_of
from curbside.localize.session import Session

REPO = Path(__file__).resolve().parent.parent
SHARED_WALK = REPO.parent / "shared" / "data" / "ipin2023" / "ipin2023-t3.h5"
BUNDLED_WALK = REPO / "tests" / "data" / "sessions" / "ipin2023-cut.h5"
TRIAL = "TrainingTrial01_repetition01"


@dataclass
class Run:
    """One streamed run: CPU seconds in all and in inference, and the track."""

    cpu_s: float
    inference_cpu_s: float
    requests: int
    track: pd.DataFrame


def default_walk() -> str:
    """The shared 232 s IPIN trial, or the bundled 32 s cut of it when the shared data is absent."""
    return f"{SHARED_WALK if SHARED_WALK.exists() else BUNDLED_WALK}::{TRIAL}"


def stream_rows(walk: Session, config: RunConfig, model, rows: int, inference_wait_s: float) -> Run:
    """Feed ``walk`` ``rows`` IMU rows per request through the service's per-request path."""
    imu = walk.imu[list(IMU_QUAT_COLUMNS)].to_numpy(float)
    gnss = walk.gnss[list(GNSS_COLUMNS)].to_numpy(float)
    live = LiveSession(config, start=StartPose(**walk.meta["start"]), name="bench")
    queue = InferenceQueue(model)
    n_requests = -(-len(imu) // rows)
    inference_cpu = 0.0
    pending_since = None
    fix_lo = 0
    cpu0 = time.process_time()
    for k in range(n_requests):
        batch = imu[k * rows : (k + 1) * rows]
        last = k == n_requests - 1
        fix_hi = len(gnss) if last else int(np.searchsorted(gnss[:, 0], batch[-1, 0], side="right"))
        warnings = live.push(batch, gnss[fix_lo:fix_hi], IMU_QUAT_COLUMNS)
        fix_lo = fix_hi
        queue.collect(live)
        now = batch[-1, 0]
        if queue.pending:
            pending_since = now if pending_since is None else pending_since
            stale = now - pending_since >= inference_wait_s
            taken = queue.take(whole_batches_only=not stale)
            if taken:
                cpu = time.process_time()
                queue.deliver(taken, queue.infer(taken))
                inference_cpu += time.process_time() - cpu
                pending_since = now if queue.pending else None
        live.advance()
        estimate_of(live, {}, warnings)
    live.finish_streams()
    queue.collect(live)
    cpu = time.process_time()
    queue.run()
    inference_cpu += time.process_time() - cpu
    live.advance()
    cpu_s = time.process_time() - cpu0
    return Run(cpu_s, inference_cpu, n_requests, live.result().track)


def whole_walk(walk: Session, config: RunConfig, model) -> tuple[float, pd.DataFrame]:
    """CPU seconds and track of the same session pushed in one piece (``localize run``'s result)."""
    cpu0 = time.process_time()
    track = stream_session(walk, None, config, model).track
    return time.process_time() - cpu0, track


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--walk", default=default_walk(), help="a session readers.read_any reads")
    parser.add_argument("--rows", type=int, nargs="+", default=[1, 10, 50], help="IMU rows per request")
    parser.add_argument("--mode", default="fused")
    parser.add_argument("--inference-wait-s", type=float, default=0.25,
                        help="longest a partial RoNIN batch waits (s of walk; the service's default)")
    parser.add_argument("--threads", type=int, default=1, help="torch threads (the service's default)")
    parser.add_argument("--repeat", type=int, default=1, help="runs per batch size; the fastest counts")
    parser.add_argument("--profile", type=int, metavar="ROWS", help="cProfile the run in batches of ROWS")
    args = parser.parse_args()
    logging.basicConfig(level=logging.WARNING)
    from curbside.localize.ronin.infer import load_model

    torch.set_num_threads(args.threads)
    model = load_model()
    walk = read_any(args.walk)
    config = RunConfig.for_mode(args.mode, seed=3)
    t0, t1 = walk.time_span()
    walk_s = t1 - t0
    print(f"{args.walk}: {walk_s:.0f} s of walk, {len(walk.imu)} IMU rows, {len(walk.gnss)} fixes; "
          f"mode {args.mode}, {config.filter.n_particles} particles, torch {args.threads} thread(s)")
    whole_walk(walk, config, model)  # warm-up: compiled kernels, caches
    whole_cpu, whole_track = min((whole_walk(walk, config, model) for _ in range(args.repeat)),
                                 key=lambda run: run[0])
    print(f"whole walk in one piece: {1e3 * whole_cpu / walk_s:7.2f} ms CPU per s of walk")
    print(" rows/request  requests  ms CPU/s walk  of it inference  x whole walk  track = whole walk")
    for rows in args.rows:
        run = min((stream_rows(walk, config, model, rows, args.inference_wait_s) for _ in range(args.repeat)),
                  key=lambda r: r.cpu_s)
        same = run.track.equals(whole_track)
        print(f"{rows:13d} {run.requests:9d} {1e3 * run.cpu_s / walk_s:14.2f} "
              f"{1e3 * run.inference_cpu_s / walk_s:16.2f} {run.cpu_s / whole_cpu:13.1f}  {same}")
    if args.profile:
        profiler = cProfile.Profile()
        profiler.runcall(stream_rows, walk, config, model, args.profile, args.inference_wait_s)
        print(f"\ncProfile, {args.profile} row(s) per request, by own time:")
        pstats.Stats(profiler).sort_stats("tottime").print_stats(30)


if __name__ == "__main__":
    main()
