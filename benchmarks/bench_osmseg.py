"""``osmseg build`` of the default area, against osmnx merely reading the same file.

Baseline: ``osmnx.features_from_xml(bundled extract)``, which parses the file into a feature table
and derives nothing. Measured: the whole ``osmseg build`` (read with pyosmium + buildings, streets,
crosswalks, sidewalks + atomic GeoJSON write). Both run in this process, alternately, ``--repeat``
times each; the best time of each is compared. Target: ratio <= 2.0.

Usage::

    python benchmarks/bench_osmseg.py [--repeat 3]
"""

from __future__ import annotations

import argparse
import tempfile
import time
import warnings
from pathlib import Path

import osmnx as ox

from curbside import settings
from curbside.osmseg.build import build_map
from curbside.osmseg.mapio import write_map

TARGET_RATIO = 2.0


def time_osmnx_read() -> float:
    """Seconds osmnx takes to read the bundled extract into features."""
    start = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ox.features_from_xml(settings.default_osm_file)
    return time.perf_counter() - start


def time_osmseg_build(out: Path) -> tuple[float, dict[str, int]]:
    """Seconds for read + derive + write of the default area, and the polygon count per class."""
    start = time.perf_counter()
    layers = build_map()
    write_map(layers, out)
    elapsed = time.perf_counter() - start
    return elapsed, layers.gdf["class"].value_counts().to_dict()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=3, help="runs of each (best is kept)")
    args = parser.parse_args()
    baseline, build = [], []
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "map.geojson"
        for _ in range(args.repeat):
            baseline.append(time_osmnx_read())
            seconds, counts = time_osmseg_build(out)
            build.append(seconds)
        size_mb = out.stat().st_size / 1e6
    ratio = min(build) / min(baseline)
    print(f"osmnx.features_from_xml (baseline): {min(baseline):6.2f} s  (runs: {_fmt(baseline)})")
    print(f"osmseg build, read+derive+write:    {min(build):6.2f} s  (runs: {_fmt(build)})")
    print(f"ratio build / baseline:             {ratio:6.2f}   target <= {TARGET_RATIO}")
    print(f"map: {size_mb:.1f} MB, " + ", ".join(f"{k} {v}" for k, v in sorted(counts.items())))


def _fmt(times: list[float]) -> str:
    return ", ".join(f"{t:.2f}" for t in times)


if __name__ == "__main__":
    main()
