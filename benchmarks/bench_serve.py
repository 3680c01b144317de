"""Load test of ``localize serve``: how many walkers streaming in real time one machine holds.

Loopback only, bounded in walkers and in time. The service runs as its own process (``localize
serve`` on a free 127.0.0.1 port, the San Francisco map, fused mode); the walkers run in another
process, one asyncio task and one WebSocket each. Every walker replays the same simulated downtown
walk (``curbside.evaluate.simulate``: 50 Hz IMU with the orientation quaternion, 1 Hz GNSS, a start
pose) at the real-time rate: a batch of half a second of rows every half second, sent when its last
row is due, one batch in flight (a late reply delays the next batch, as on a phone). Walkers start at
staggered times; one whose walk ends starts a new session.

The number of walkers steps up (``--walkers``); after a warm-up, each step measures for ``--step-s``:

- the round trip of a batch (send -> the estimate back: rows validated, pushed, RoNIN, filter): p50,
  p99, max;
- how late batches were sent (a walker is *behind* when its replies come slower than its rows);
- the round trip of ``GET /health`` sent alongside every 100 ms: the HTTP floor of the same machine at
  the same moment, what the service's own work adds to;
- the service process's CPU (cores used) and resident memory.

A step *holds* when p99 < 100 ms, the p99 send lateness < one batch, and no request failed. The run
stops at the first step that does not hold. Memory per session is the slope of resident memory against
open sessions over the steps.

The same run also measures the **compute baseline**: CPU seconds per walker-second of data when the
same walk is pushed through :class:`~curbside.localize.live.LiveSession` in process (no HTTP, no JSON,
RoNIN in whole batches), and reports the service's CPU per walker-second against it.

Usage::

    python benchmarks/bench_serve.py [--map MAP] [--walkers 10,25,50,100,150,200,300]
                                     [--step-s 30] [--warmup-s 8] [--batch-s 0.5] [--max-minutes 15]

Without ``--map`` the map is built from the bundled extract (cached under ``cache/bench_serve``). The
machine may be shared: the load average before the run is printed; compare steps of one run, not
runs on different days.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

CACHE = Path("cache") / "bench_serve"
REPO = Path(__file__).resolve().parent.parent


def prepare(map_path: str | None) -> tuple[Path, Path]:
    """The map file and a simulated SF walk written as a SPEC session folder (cached)."""
    from curbside.evaluate.simulate import ImuModel, SimulationConfig, sf6_routes, simulate_session
    from curbside.localize.session import write_session
    from curbside.osmseg.build import build_map
    from curbside.osmseg.mapio import write_map

    CACHE.mkdir(parents=True, exist_ok=True)
    map_file = Path(map_path) if map_path else CACHE / "sf.geojson"
    if not map_file.exists():
        print("building the San Francisco map ...", flush=True)
        write_map(build_map(), map_file)
    walk = CACHE / "walk"
    if not (walk / "imu.csv").exists():
        print("simulating a walk ...", flush=True)
        routes, frame, osm = sf6_routes()
        config = SimulationConfig(
            imu=ImuModel(rate_hz=50.0), write_velocity=False, write_imu=True, write_steps=False
        )
        write_session(simulate_session(routes[0], osm, frame, seed=0, config=config), walk, overwrite=True)
    return map_file, walk


def messages(walk: Path, batch_s: float) -> tuple[dict, list[bytes]]:
    """The start pose and the walk as WebSocket messages of ``batch_s`` seconds each (JSON bytes)."""
    from curbside.localize.session import read_session

    session = read_session(walk)
    imu, gnss = session.imu, session.gnss
    t0, t1 = session.time_span()
    out = []
    edges = np.arange(t0, t1, batch_s)
    # each batch ends where the next begins: lo + batch_s rounds past the next edge (0.1 + 0.02 >
    # 0.12), which sent the row at 0.12 twice and had 17 % of 0.02 s batches refused
    for lo, hi in zip(edges, [*edges[1:], np.inf], strict=True):
        pick_i = imu[(imu["t"] >= lo) & (imu["t"] < hi)]
        pick_g = gnss[(gnss["t"] >= lo) & (gnss["t"] < hi)]
        body = {"imu": pick_i.to_dict("records"), "gnss": pick_g.to_dict("records")}
        out.append(json.dumps(body).encode())
    return session.meta["start"], out


def compute_baseline(map_file: Path, walk: Path, walkers: int = 8, seconds: float = 60.0) -> float:
    """CPU seconds per walker-second of data, in process (see the module docstring)."""
    import torch

    from curbside.localize.engine import StartPose
    from curbside.localize.live import IMU_QUAT_COLUMNS, InferenceQueue, LiveSession
    from curbside.localize.raster import load_or_build_raster
    from curbside.localize.ronin.infer import load_model
    from curbside.localize.runconfig import RunConfig
    from curbside.localize.session import read_session
    from curbside.osmseg.mapio import read_map

    torch.set_num_threads(1)
    session = read_session(walk)
    layers = read_map(map_file)
    config = RunConfig.for_mode("fused")
    raster = load_or_build_raster(
        layers, config.filter.map.raster_resolution_m, config.filter.map.segment_reach_m
    )
    start = StartPose(**session.meta["start"])
    queue = InferenceQueue(load_model())
    lives = [LiveSession(config, layers, raster, start=start) for _ in range(walkers)]
    imu = session.imu[list(IMU_QUAT_COLUMNS)].to_numpy()
    gnss = session.gnss.to_numpy()
    cpu0 = time.process_time()
    for lo in np.arange(0.0, seconds, 0.5):
        pick_i = imu[(imu[:, 0] >= lo) & (imu[:, 0] < lo + 0.5)]
        pick_g = gnss[(gnss[:, 0] >= lo) & (gnss[:, 0] < lo + 0.5)]
        for live in lives:
            live.push(pick_i, pick_g, IMU_QUAT_COLUMNS)
            queue.collect(live)
        queue.run(whole_batches_only=True)
        for live in lives:
            live.advance()
    return (time.process_time() - cpu0) / (walkers * seconds)


# -- the walkers' process ------------------------------------------------------------------------------


class Stats:
    def __init__(self) -> None:
        self.reset()

    def reset(self) -> None:
        self.latency: list[float] = []
        self.late: list[float] = []
        self.health: list[float] = []
        self.errors = 0
        self.sessions_done = 0


async def _walker(index: int, url: str, start: dict, msgs: list[bytes], batch_s: float, stats: Stats, stop):
    import httpx
    import websockets

    loop = asyncio.get_running_loop()
    # Each walker's clock has its own phase (golden-ratio spread over a batch period), kept from the
    # first batch on whatever its connection took: phones do not send in step.
    phase = (index * 0.618034) % 1.0 * batch_s
    async with httpx.AsyncClient(base_url=url, timeout=30.0) as http:
        while not stop.is_set():
            reply = await http.post("/sessions", json={"start": start})
            if reply.status_code != 201:
                stats.errors += 1
                await asyncio.sleep(1.0)
                continue
            sid = reply.json()["id"]
            async with websockets.connect(
                f"{url.replace('http', 'ws')}/sessions/{sid}/stream", max_size=2**24
            ) as ws:
                now = loop.time()
                t0 = now - (now % batch_s) + phase  # the walk starts at the walker's next phase
                for k, msg in enumerate(msgs):
                    due = t0 + (k + 1) * batch_s
                    if due > loop.time():
                        await asyncio.sleep(due - loop.time())
                    sent = loop.time()
                    await ws.send(msg.decode())
                    answer = await ws.recv()
                    stats.latency.append(loop.time() - sent)
                    stats.late.append(sent - due)
                    if '"detail"' in answer:
                        stats.errors += 1
                    if stop.is_set():
                        break
                await ws.send('{"end": true}')
                await ws.recv()
            stats.sessions_done += 1


async def _prober(url: str, stats: Stats, stop) -> None:
    import httpx

    loop = asyncio.get_running_loop()
    async with httpx.AsyncClient(base_url=url, timeout=30.0) as http:
        while not stop.is_set():
            sent = loop.time()
            await http.get("/health")
            stats.health.append(loop.time() - sent)
            await asyncio.sleep(0.1)


def _summary(values: list[float]) -> dict[str, float]:
    if not values:
        return {"p50_ms": float("nan"), "p99_ms": float("nan"), "max_ms": float("nan")}
    a = np.asarray(values) * 1000.0
    return {
        "p50_ms": float(np.percentile(a, 50)),
        "p99_ms": float(np.percentile(a, 99)),
        "max_ms": float(a.max()),
    }


async def _ramp(args: argparse.Namespace) -> None:
    import psutil

    server = psutil.Process(args.server_pid)
    start, msgs = messages(Path(args.walk), args.batch_s)
    stats, stop = Stats(), asyncio.Event()
    tasks = [asyncio.create_task(_prober(args.url, stats, stop))]
    deadline = time.monotonic() + args.max_minutes * 60.0
    for n in [int(x) for x in args.walkers.split(",")]:
        while len(tasks) - 1 < n:
            tasks.append(
                asyncio.create_task(_walker(len(tasks) - 1, args.url, start, msgs, args.batch_s, stats, stop))
            )
        await asyncio.sleep(args.warmup_s)
        stats.reset()
        cpu0, wall0 = sum(server.cpu_times()[:2]), time.monotonic()
        await asyncio.sleep(args.step_s)
        cpu = (sum(server.cpu_times()[:2]) - cpu0) / (time.monotonic() - wall0)
        late = np.asarray(stats.late) if stats.late else np.zeros(1)
        row = {
            "walkers": n,
            "batches": len(stats.latency),
            "estimate": _summary(stats.latency),
            "health": _summary(stats.health),
            "late_p99_s": float(np.percentile(late, 99)),
            "errors": stats.errors,
            "server_cores": cpu,
            "server_rss_mb": server.memory_info().rss / 1e6,
            "load_avg": os.getloadavg()[0],
        }
        row["holds"] = bool(
            row["estimate"]["p99_ms"] < 100.0 and row["late_p99_s"] < args.batch_s and not stats.errors
        )
        print(json.dumps(row), flush=True)
        if not row["holds"] or time.monotonic() > deadline:
            break
    stop.set()
    await asyncio.wait(tasks, timeout=30.0)


# -- the orchestra -------------------------------------------------------------------------------------------


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _wait_up(url: str, proc: subprocess.Popen) -> None:
    import httpx

    deadline = time.monotonic() + 120.0
    while time.monotonic() < deadline and proc.poll() is None:
        try:
            if httpx.get(f"{url}/health", timeout=1.0).status_code == 200:
                return
        except httpx.TransportError:
            time.sleep(0.3)
    raise RuntimeError("the service did not start")


def _table(rows: list[dict], baseline: float) -> str:
    lines = [
        "walkers | batch round trip p50 / p99 / max (ms) | /health p50 / p99 (ms) | late p99 (s) | errors | "
        "server cores | RSS (MB) | CPU s per walker-s (vs in-process) | load avg | holds",
        "---|---|---|---|---|---|---|---|---|---",
    ]
    for r in rows:
        e, h = r["estimate"], r["health"]
        per = r["server_cores"] / r["walkers"]
        lines.append(
            f"{r['walkers']} | {e['p50_ms']:.1f} / {e['p99_ms']:.1f} / {e['max_ms']:.0f} | "
            f"{h['p50_ms']:.1f} / {h['p99_ms']:.1f} | {r['late_p99_s']:.2f} | {r['errors']} | "
            f"{r['server_cores']:.2f} | {r['server_rss_mb']:.0f} | "
            f"{per * 1000:.1f} ms ({per / baseline:.1f}x) | "
            f"{r['load_avg']:.1f} | {'yes' if r['holds'] else 'no'}"
        )
    return "\n".join(lines)


def _serve_and_ramp(
    map_file: Path, walk: Path, args: argparse.Namespace
) -> tuple[subprocess.CompletedProcess, float]:
    """Start ``localize serve`` on a free loopback port, ramp the walkers against it from a client
    process; the client's output and the server's idle memory (MB)."""
    port = _free_port()
    url = f"http://127.0.0.1:{port}"
    env = os.environ | {"PYTHONPATH": str(REPO)}
    with tempfile.TemporaryDirectory() as data_dir:
        server = subprocess.Popen(
            [sys.executable, "-m", "curbside.cli.localize", "serve", "--map", str(map_file), "--port",
             str(port), "--data-dir", data_dir, "--max-sessions", "5000", "--idle-timeout", "120"],
            env=env,
            stdout=subprocess.DEVNULL,
        )
        try:
            _wait_up(url, server)
            import psutil

            idle_rss = psutil.Process(server.pid).memory_info().rss / 1e6
            client = subprocess.run(
                [sys.executable, __file__, "--client", "--url", url, "--walk", str(walk), "--server-pid",
                 str(server.pid), "--walkers", args.walkers, "--step-s", str(args.step_s), "--warmup-s",
                 str(args.warmup_s), "--batch-s", str(args.batch_s), "--max-minutes", str(args.max_minutes)],
                env=env,
                capture_output=True,
                text=True,
                timeout=args.max_minutes * 60 + 300,
            )
        finally:
            server.terminate()
            server.wait(timeout=120)
    return client, idle_rss


def _summarise(rows: list[dict], baseline: float, idle_rss: float, out: str | None) -> None:
    """Print the ramp's table, the most walkers held and the memory per session; write JSON to ``out``."""
    print(_table(rows, baseline))
    held = [r["walkers"] for r in rows if r["holds"]]
    sizes = np.array([r["walkers"] for r in rows], float)
    rss = np.array([r["server_rss_mb"] for r in rows])
    per_session = np.polyfit(sizes, rss, 1)[0] if len(rows) > 1 else (rss[0] - idle_rss) / sizes[0]
    print(f"\nmost walkers held (p99 < 100 ms, keeping up): {max(held) if held else 'none of the steps'}")
    print(
        f"memory: {idle_rss:.0f} MB with no session, {per_session:.2f} MB per session (slope over the steps)"
    )
    print(f"load average after the run: {os.getloadavg()}")
    if out:
        summary = {"rows": rows, "baseline_cpu_s_per_walker_s": baseline, "idle_rss_mb": idle_rss,
                   "mb_per_session": per_session}
        Path(out).write_text(json.dumps(summary, indent=2))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--map")
    parser.add_argument("--walkers", default="10,25,50,100,150,200,300")
    parser.add_argument("--step-s", type=float, default=30.0)
    parser.add_argument("--warmup-s", type=float, default=8.0)
    parser.add_argument("--batch-s", type=float, default=1.0)
    parser.add_argument("--max-minutes", type=float, default=15.0)
    parser.add_argument("--out", help="also write the results as JSON here")
    parser.add_argument("--client", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--url", help=argparse.SUPPRESS)
    parser.add_argument("--walk", help=argparse.SUPPRESS)
    parser.add_argument("--server-pid", type=int, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.client:
        asyncio.run(_ramp(args))
        return 0
    print(f"load average before the run: {os.getloadavg()}; {os.cpu_count()} CPUs", flush=True)
    map_file, walk = prepare(args.map)
    baseline = compute_baseline(map_file, walk)
    print(f"in-process compute: {baseline * 1000:.1f} ms CPU per walker-second", flush=True)
    client, idle_rss = _serve_and_ramp(map_file, walk, args)
    rows = [json.loads(line) for line in client.stdout.splitlines() if line.startswith("{")]
    if not rows:
        sys.stderr.write(client.stderr)
        return 1
    _summarise(rows, baseline, idle_rss, args.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
