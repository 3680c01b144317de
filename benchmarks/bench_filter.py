"""Particle-filter updates per second on one core, against a straightforward shapely implementation.

One update = predict (turn the step's displacement by each particle's heading offset, add noise), map
likelihood, GNSS likelihood (every other step), normalise, estimate, the sidewalk-segment mode,
systematic resampling: what :meth:`curbside.localize.filter.Tracker.step` does at each footstep, on the
one code path there is (each part with its compiled kernel inside it). Two implementations run the
same walk in the same process:

- ``tracker``: :class:`~curbside.localize.filter.Tracker` with its default parts, the map rasterised once;
- ``shapely baseline``: the natural first version, numpy motion and resampling but the map weights
  from ``shapely.contains_xy`` against the prepared union of each class, at every update.

It then reports where an update's time goes (each part's method timed inside the same walk), the cost
of a standard normal from the kernels' stream (:mod:`curbside.localize.filter.random`) against numpy's
``Generator.standard_normal``, and the memory per particle.

Usage::

    python benchmarks/bench_filter.py [--map MAP.geojson | --grid] [--steps 20000]

Without ``--map`` the map is built from the bundled downtown San Francisco extract (what ``osmseg
build`` writes by default); ``--grid`` uses a synthetic 20 x 20-block grid instead. Other processes
share the CPU, so each rate is the best of many short blocks of updates (``timeit``'s rule: the
fastest block is the one least disturbed) and the per-part table gives medians; the load average is
printed with them. Threads are pinned to one before numpy is imported. Targets (issue 8): N = 500 at
least 20,000 updates/s (aim: 50,000), N = 100,000 at least 120.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ[_var] = "1"

import argparse  # noqa: E402
import math  # noqa: E402
import time  # noqa: E402
import tracemalloc  # noqa: E402
from unittest import mock  # noqa: E402

import geopandas as gpd  # noqa: E402
import numpy as np  # noqa: E402
import shapely  # noqa: E402
from scipy.ndimage import distance_transform_edt  # noqa: E402

import curbside.localize.filter.tracker as tracker_module  # noqa: E402
from curbside.localize.filter import FilterConfig, GnssFix, Tracker, normalise_and_estimate  # noqa: E402
from curbside.localize.filter.random import Stream, fill_standard_normal  # noqa: E402
from curbside.localize.raster import BUILDING, MapRaster, rasterize_map  # noqa: E402
from curbside.osmseg.mapio import MapLayers, read_map  # noqa: E402

X0, Y0 = 551000.0, 4182000.0


def grid_city(
    blocks: int = 20, block_m: float = 100.0, street_m: float = 12.0, sidewalk_m: float = 3.0
) -> MapLayers:
    """A synthetic downtown: square blocks of four buildings ringed by sidewalks, streets between."""
    pitch = block_m + street_m
    i, j = np.meshgrid(np.arange(blocks), np.arange(blocks))
    bx, by = X0 + i.ravel() * pitch, Y0 + j.ravel() * pitch
    inner = sidewalk_m
    half = block_m / 2
    buildings = [
        shapely.box(bx + inner + dx, by + inner + dy, bx + dx + half - 1, by + dy + half - 1)
        for dx in (0, half - inner) for dy in (0, half - inner)
    ]
    outer = shapely.box(bx, by, bx + block_m, by + block_m)
    core = shapely.box(bx + inner, by + inner, bx + block_m - inner, by + block_m - inner)
    sidewalks = shapely.difference(outer, core)
    extent = blocks * pitch
    streets = [shapely.box(X0 - street_m, Y0 + k * pitch - street_m, X0 + extent, Y0 + k * pitch)
               for k in range(blocks + 1)]
    streets += [shapely.box(X0 + k * pitch - street_m, Y0 - street_m, X0 + k * pitch, Y0 + extent)
                for k in range(blocks + 1)]
    crosswalks = np.concatenate([shapely.box(bx + 2, by - street_m, bx + 6, by),
                                 shapely.box(bx - street_m, by + 2, bx, by + 6)])
    geoms = np.concatenate([np.concatenate(buildings), sidewalks, streets, crosswalks])
    classes = (["building"] * (4 * blocks * blocks) + ["sidewalk"] * (blocks * blocks)
               + ["street"] * len(streets) + ["crosswalk"] * len(crosswalks))
    segment_ids = [f"block{k}" if c == "sidewalk" else None for k, c in enumerate(classes)]
    gdf = gpd.GeoDataFrame({"class": classes, "segment_id": segment_ids}, geometry=geoms, crs=32610)
    return MapLayers(gdf)


def walk(start: tuple[float, float], steps: int) -> tuple[np.ndarray, list[GnssFix | None]]:
    """Circles of 5 m radius at 1.3 m/s, 0.55 s per step, a fix near the truth every other step."""
    rng = np.random.default_rng(0)
    heading = np.arange(steps) * (0.715 / 5.0)
    disp = 0.715 * np.column_stack([np.cos(heading), np.sin(heading)])
    truth = np.asarray(start) + np.cumsum(disp, axis=0)
    fixes = [GnssFix(truth[k, 0] + rng.normal(0, 5), truth[k, 1] + rng.normal(0, 5), 8.0) if k % 2 else None
             for k in range(steps)]
    return disp, fixes


def block_seconds(update, steps: int, block: int) -> np.ndarray:
    """Seconds taken by each block of ``block`` consecutive calls ``update(k)``, ``k = 0 .. steps - 1``."""
    blocks = np.zeros(max(steps // block, 1))
    for b in range(len(blocks)):
        t0 = time.perf_counter()
        for k in range(b * block, (b + 1) * block):
            update(k)
        blocks[b] = time.perf_counter() - t0
    return blocks


def best_rate(update, steps: int, block: int) -> float:
    """Updates per second of ``update(k)`` in its fastest block of ``block`` updates."""
    return block / float(block_seconds(update, steps, block).min())


def started_tracker(raster: MapRaster, n: int, start) -> Tracker:
    """A default tracker at ``start``, its kernels compiled (one update done)."""
    tracker = Tracker.from_config(raster, FilterConfig(n_particles=n), seed=1)
    tracker.start_at_pose(0.0, *start)
    tracker.step(0.0, displacement_en=(0.5, 0.0), gnss_fix=GnssFix(*start, 8.0))
    return tracker


def time_tracker(raster: MapRaster, n: int, steps: int, start, block: int) -> float:
    tracker = started_tracker(raster, n, start)
    disp, fixes = walk(start, steps)
    rate = best_rate(
        lambda k: tracker.step(0.55 * k, displacement_en=disp[k], gnss_fix=fixes[k]), steps, block
    )
    if tracker.recoveries:
        print(f"  ({tracker.recoveries} collapses during the timed walk)")
    return rate


def part_seconds(raster: MapRaster, n: int, steps: int, start, block: int = 10) -> dict[str, float]:
    """Seconds per update in each part, in the least disturbed fifth of the blocks of ``block`` updates.

    Each part's method (and the tracker's ``normalise_and_estimate``) is wrapped with a timer; the
    blocks whose whole time is in the fastest fifth are averaged, so the parts add up to the whole
    update. ``tracker (Python)`` is what is left: the tracker's own code and the timers (about 0.1 us
    per part called).
    """
    tracker = started_tracker(raster, n, start)
    disp, fixes = walk(start, steps)
    spent: dict[str, np.ndarray] = {}
    current = [0]

    def timed(name: str, method):
        per_block = spent.setdefault(name, np.zeros(steps // block))

        def wrapper(*args):
            t0 = time.perf_counter()
            result = method(*args)
            per_block[current[0] // block] += time.perf_counter() - t0
            return result

        return wrapper

    parts = {"predict": (tracker.predictor, "predict")}
    parts |= {f"{type(lik).__name__}.weigh": (lik, "weigh") for lik in tracker.likelihoods}
    if tracker.divergence is not None:
        parts["divergence.observe"] = (tracker.divergence, "observe")
    if tracker.segments is not None:
        parts["segments.mode"] = (tracker.segments, "mode")
    parts["resample"] = (tracker.resampler, "resample")
    for name, (part, method) in parts.items():
        setattr(part, method, timed(name, getattr(part, method)))

    def update(k: int) -> None:
        current[0] = k
        tracker.step(0.55 * k, displacement_en=disp[k], gnss_fix=fixes[k])

    with mock.patch.object(tracker_module, "normalise_and_estimate", timed("normalise + estimate",
                                                                           normalise_and_estimate)):
        whole = block_seconds(update, steps, block)
    calm = whole <= np.quantile(whole, 0.2)
    seconds = {name: float(v[calm].mean()) / block for name, v in spent.items()}
    seconds["tracker (Python)"] = float(whole[calm].mean()) / block - sum(seconds.values())
    seconds["whole update"] = float(whole[calm].mean()) / block
    return seconds


def normal_cost_ns(count: int = 1500, repeat: int = 2000) -> tuple[float, float]:
    """Nanoseconds per standard normal, ``count`` at a time: the kernels' stream and numpy's generator.

    The two alternate, so that both see the same load; each takes its fastest repeat.
    """
    out = np.empty(count)
    stream, rng = Stream(np.random.default_rng(0)), np.random.default_rng(0)
    fill_standard_normal(stream.state, out)
    fills = (lambda: fill_standard_normal(stream.state, out), lambda: rng.standard_normal(out=out))
    best = [math.inf, math.inf]
    for _ in range(repeat):
        for j, fill in enumerate(fills):
            t0 = time.perf_counter()
            fill()
            best[j] = min(best[j], time.perf_counter() - t0)
    return best[0] / count * 1e9, best[1] / count * 1e9


def time_shapely_baseline(
    layers: MapLayers, n: int, steps: int, start, block: int, jaywalk_weight: float = 0.4
) -> float:
    """The natural first version: the same update, the map weights by polygon tests."""
    unions = {cls: layers.union(cls) for cls in ("street", "crosswalk", "building")}
    for geom in unions.values():
        shapely.prepare(geom)
    rng = np.random.default_rng(1)
    state = {"x": start[0] + rng.normal(0, 1, n), "y": start[1] + rng.normal(0, 1, n),
             "theta": rng.normal(0, 0.1, n)}
    disp, fixes = walk(start, steps)

    def update(k: int) -> None:
        x, y, theta = state["x"], state["y"], state["theta"]
        dx, dy = disp[k]
        sigma = max(0.05, 0.15 * math.hypot(dx, dy))
        theta = theta + rng.normal(0, math.radians(0.5), n)
        c, s = np.cos(theta), np.sin(theta)
        x = x + c * dx - s * dy + rng.normal(0, sigma, n)
        y = y + s * dx + c * dy + rng.normal(0, sigma, n)
        w = np.ones(n)
        w[shapely.contains_xy(unions["street"], x, y)] = jaywalk_weight
        w[shapely.contains_xy(unions["crosswalk"], x, y)] = 1.0
        w[shapely.contains_xy(unions["building"], x, y)] = 0.0
        fix = fixes[k]
        if fix is not None:
            w *= np.exp(-((x - fix.x) ** 2 + (y - fix.y) ** 2) / (2 * fix.accuracy_m**2))
        if w.sum() == 0:
            w[:] = 1.0
        w /= w.sum()
        state["estimate"] = (w @ x, w @ y)
        positions = (rng.random() + np.arange(n)) / n
        idx = np.minimum(np.searchsorted(np.cumsum(w), positions, side="right"), n - 1)
        state["x"], state["y"], state["theta"] = x[idx], y[idx], theta[idx]

    return best_rate(update, steps, block)


def bytes_per_particle(raster: MapRaster) -> float:
    """Slope of the tracker's allocated memory between N=100,000 and N=200,000 (raster excluded)."""
    sizes = []
    for n in (100_000, 200_000):
        tracemalloc.start()
        before = tracemalloc.get_traced_memory()[0]
        tracker = Tracker.from_config(raster, FilterConfig(n_particles=n), seed=0)
        tracker.start_at_pose(0.0, raster.x0 + 1.0, raster.y0 + 1.0)
        sizes.append(tracemalloc.get_traced_memory()[0] - before)
        tracemalloc.stop()
        del tracker
    return (sizes[1] - sizes[0]) / 100_000


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--map", help="map GeoJSON (default: built from the bundled SF extract)")
    parser.add_argument("--grid", action="store_true", help="use a synthetic 20 x 20 block grid instead")
    parser.add_argument("--steps", type=int, default=20000, help="updates timed at N=500")
    args = parser.parse_args(argv)
    if args.grid:
        layers = grid_city()
    elif args.map:
        layers = read_map(args.map)
    else:
        from curbside.osmseg.build import build_map

        layers = build_map()
    t0 = time.perf_counter()
    raster = rasterize_map(layers)
    print(f"map: {len(layers.gdf)} polygons, raster {raster.shape[0]} x {raster.shape[1]} cells at "
          f"{raster.resolution_m} m, rasterised in {time.perf_counter() - t0:.2f} s")
    # Start near the middle, as far from buildings as the map allows (up to 25 m), so that the
    # circles stay walkable.
    coarse = raster.codes[::8, ::8]
    clearance_m = distance_transform_edt(coarse < BUILDING) * 8 * raster.resolution_m
    free = np.argwhere(clearance_m >= min(25.0, 0.8 * clearance_m.max()))
    mid = free[np.argmin(np.abs(free - np.array(coarse.shape) / 2).sum(axis=1))] * 8
    res = raster.resolution_m
    start = (raster.x0 + (mid[1] + 0.5) * res, raster.y0 + (mid[0] + 0.5) * res)

    print(f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores; one thread")
    sizes = ((500, args.steps, 50, 500, 10), (100_000, 250, 2, 6, 2))  # N, steps, block (tracker, baseline)
    print(f"{'N':>8} {'implementation':<18} {'updates/s':>11} {'ms/update':>10} {'vs shapely':>11}")
    for n, steps, block, base_steps, base_block in sizes:
        base = time_shapely_baseline(layers, n, base_steps, start, base_block)
        tracker = time_tracker(raster, n, steps, start, block)
        for name, rate in (("tracker", tracker), ("shapely baseline", base)):
            print(f"{n:>8} {name:<18} {rate:>11,.0f} {1e3 / rate:>10.3f} {rate / base:>10.1f}x")
    parts = {n: part_seconds(raster, n, steps, start, block=10 if n <= 1000 else 2)
             for n, steps in ((500, 4000), (100_000, 200))}
    print("\nwhere an update's time goes (microseconds per update in the calmest fifth of the blocks; GNSS "
          "and divergence run at every other update):")
    print(f"{'part':<26}" + "".join(f"{'N = ' + format(n, ','):>14}" for n in parts))
    for name in parts[500]:
        print(f"{name:<26}" + "".join(f"{parts[n][name] * 1e6:>14,.1f}" for n in parts))
    ours, numpys = normal_cost_ns()
    print(f"\nstandard normals, 1,500 at a time: {ours:.2f} ns each from the kernels' stream (xoshiro256++ "
          f"ziggurat), {numpys:.2f} ns from numpy's Generator.standard_normal ({numpys / ours:.1f}x)")
    print(f"memory: {bytes_per_particle(raster):.0f} bytes per particle (linear in N; the raster is "
          f"{raster.codes.nbytes / 1e6:.1f} MB, shared)")
    print(f"load average {os.getloadavg()[0]:.1f} at the end")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
