"""The replay viewer on a 10-minute walk at N = 500: page size and time to open in headless Chromium.

The walk: a simulated 850 m custom route in the Financial District (``localize simulate``), tracked by
``localize run --save-particles`` in the gnss, inertial and fused modes at N = 500 on the default OSM
map. Measured: the size of ``localize view``'s page over the three runs and, in headless Chromium
(Debian's, via Selenium), the time from navigation start to the first render (``curbside:first-render``
mark: map, tracks and fixes drawn) and to a usable slider (``curbside:slider-ready``: particle clouds
decoded and drawn), best of ``--repeat`` fresh loads. Baseline, loaded the same way: ``osmseg show``'s
HTML page of the same map (its load event). Targets (issue 11): under 2 s and under 20 MB.

Usage::

    python benchmarks/bench_view.py [--work DIR] [--repeat 3]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

from curbside.cli.localize import main as localize_main
from curbside.cli.osmseg import main as osmseg_main

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from browser import chromium, console_errors, wait_for_mark  # noqa: E402

TARGET_S = 2.0
TARGET_MB = 20.0
#: The walk: start (lon, lat), length, crosswalk crossings, jaywalks, seed.
WALK = ("-122.4025", "37.7930", "850", "4", "2", "3")


def prepare(work: Path) -> tuple[Path, Path]:
    """Build the map, simulate and track the walk, write the viewer and the baseline map page."""
    map_path = work / "map.geojson"
    if not map_path.is_file():
        assert osmseg_main(["build", "-o", str(map_path)]) == 0
    session = work / "walk10"
    if not session.is_dir():
        lon, lat, length, crossings, jaywalks, seed = WALK
        assert localize_main(["simulate", "--route", "custom", "--start", lon, lat, "--length-m", length,
                              "--crossings", crossings, "--jaywalks", jaywalks, "--seed", seed,
                              "--map", str(map_path), "-o", str(session)]) == 0
    runs = []
    for mode in ("gnss", "inertial", "fused"):
        out = work / f"run-{mode}"
        if not out.is_dir():
            assert localize_main(["run", str(session), "--map", str(map_path), "--mode", mode,
                                  "--particles", "500", "--save-particles", "-o", str(out)]) == 0
        runs.append(str(out))
    view = work / "view.html"
    assert localize_main(["view", *runs, "-o", str(view)]) == 0
    baseline = work / "map.html"
    assert osmseg_main(["show", str(map_path), "-o", str(baseline)]) == 0
    return view, baseline


def open_times(page: Path, repeat: int, marks: tuple[str, ...]) -> dict[str, float]:
    """Best time (ms since navigation start) of each mark over ``repeat`` fresh loads."""
    best: dict[str, float] = {}
    for _ in range(repeat):
        with chromium(1400, 900) as driver:
            driver.get(page.as_uri())
            for mark in marks:
                if mark == "load":
                    value = driver.execute_script(
                        "const n = performance.getEntriesByType('navigation')[0]; return n.loadEventEnd;"
                    )
                else:
                    value = wait_for_mark(driver, mark)
                best[mark] = min(best.get(mark, float("inf")), float(value))
            errors = console_errors(driver)
            if errors:
                raise RuntimeError(f"{page.name}: console errors {errors}")
    return best


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--work", type=Path,
                        help="working folder, reused between runs (default: a new temporary one)")
    parser.add_argument("--repeat", type=int, default=3, help="fresh loads per page (default: %(default)s)")
    args = parser.parse_args()
    work = args.work or Path(tempfile.mkdtemp(prefix="bench-view-"))
    work.mkdir(parents=True, exist_ok=True)
    started = time.perf_counter()
    view, baseline = prepare(work)
    print(f"prepared in {time.perf_counter() - started:.0f} s under {work}")
    viewer = open_times(view, args.repeat, ("curbside:first-render", "curbside:slider-ready"))
    plain = open_times(baseline, args.repeat, ("load",))
    size_mb = view.stat().st_size / 1e6
    ready_s = viewer["curbside:slider-ready"] / 1000
    print(f"viewer page: {size_mb:.1f} MB (target < {TARGET_MB:g} MB)")
    print(f"first render: {viewer['curbside:first-render'] / 1000:.2f} s, slider ready: {ready_s:.2f} s "
          f"(target < {TARGET_S:g} s)")
    print(f"baseline, the plain map page of the whole map ({baseline.stat().st_size / 1e6:.1f} MB): "
          f"loaded in {plain['load'] / 1000:.2f} s; viewer/baseline = {ready_s * 1000 / plain['load']:.2f}")
    return 0 if ready_s < TARGET_S and size_mb < TARGET_MB else 1


if __name__ == "__main__":
    raise SystemExit(main())
