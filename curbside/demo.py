"""The end-to-end demo run by ``make demo``: ``python -m curbside.demo --out out``.

The demo is a list of stages (:data:`STAGES`) run in order on a shared :class:`DemoContext`; each stage
returns the files it wrote, by name. The first stages build the default map from the bundled
OpenStreetMap extract, write ``map.geojson``, ``map.png``, ``map.html`` and the map editor ``edit.html``
and print the per-class summary; then the six San Francisco walks are simulated and tracked (GNSS,
RoNIN+PF, GNSS+RoNIN+PF) into the benchmark report under ``benchmark/report/`` (a short summary is
printed), and the first walk is tracked once more with its particle clouds kept, for the replay viewer
``view.html``: as the report scores it (its particle count, jaywalk weight and filter seed), so the page
shows the report's figures for that walk.

Each stage logs when it starts and ends; when stderr is not a terminal (no progress bars), a stage that
runs long also logs that it is still running every :data:`HEARTBEAT_S` seconds.
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from curbside.cli.common import make_parser, run_cli
from curbside.osmseg.build import build_map
from curbside.osmseg.edit import file_features, write_editor
from curbside.osmseg.mapio import write_map
from curbside.osmseg.plot import save_html, save_png
from curbside.osmseg.summary import class_summary, format_summary

log = logging.getLogger(__name__)

#: Seconds between "still running" log lines of a long stage when stderr is not a terminal.
HEARTBEAT_S = 20.0


@dataclass
class DemoContext:
    """What the stages share.

    Attributes
    ----------
    out_dir
        Folder every stage writes into.
    results
        In-memory results handed from stage to stage (``"map"``: the :class:`MapLayers`...).
    """

    out_dir: Path
    results: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class Stage:
    """One step of the demo: a name and a function of the context returning ``{name: path written}``."""

    name: str
    run: Callable[[DemoContext], dict[str, Path]]


def build_default_map(ctx: DemoContext) -> dict[str, Path]:
    """Build the default area from the bundled extract and write ``map.geojson``."""
    ctx.results["map"] = build_map()
    return {"map_geojson": write_map(ctx.results["map"], ctx.out_dir / "map.geojson")}


def render_map_files(ctx: DemoContext) -> dict[str, Path]:
    """Render the map to ``map.png`` and ``map.html``, and write the map editor ``edit.html``."""
    layers = ctx.results["map"]
    map_geojson = ctx.out_dir / "map.geojson"
    features = file_features(map_geojson) if map_geojson.is_file() else None
    return {
        "map_png": save_png(layers, ctx.out_dir / "map.png"),
        "map_html": save_html(layers, ctx.out_dir / "map.html"),
        "map_editor": write_editor(layers, map_geojson.name, ctx.out_dir / "edit.html", features),
    }


def print_map_summary(ctx: DemoContext) -> dict[str, Path]:
    """Print the per-class counts and areas of the map."""
    summary = class_summary(ctx.results["map"])
    ctx.results["map_summary"] = summary
    print(f"Map layers ({ctx.results['map'].meta.get('source', 'unknown source')}):")
    print(format_summary(summary))
    return {}


def benchmark_stage(ctx: DemoContext) -> dict[str, Path]:
    """The sf6 benchmark on the demo's map: simulate, track, score; print a short summary."""
    from curbside.evaluate.benchmark import run_benchmark

    map_path = ctx.out_dir / "map.geojson"
    existing = map_path if map_path.is_file() else None
    paths = run_benchmark(ctx.out_dir / "benchmark", seeds=2, fast=True, workers=2, map_path=existing)
    ctx.results["benchmark"] = paths
    print(benchmark_headline(paths["report"]))
    return {"benchmark_report": paths["report"] / "report.html", "benchmark_sessions": paths["sessions"]}


def benchmark_headline(report_dir: Path) -> str:
    """A few lines from a report's ``metrics.json``: each method's CSA and error at the base parameters,
    curbside fused minus each baseline with its 95 % interval, how often a side named at
    ``segment_prob`` 0.9 or more was right, and how often ``accuracy_m`` held the walker."""
    from curbside.evaluate.runner import METHOD_LABELS

    doc = json.loads((report_dir / "metrics.json").read_text(encoding="utf-8"))
    base = doc["base"]
    lines = [
        f"sf6 benchmark, map {base['map']}, jaywalk weight {base['jaywalk_weight']}, "
        f"{base['particles']} particles (pooled over all footsteps):"
    ]
    for row in doc["pooled"]:
        at_base = row["map"] == base["map"] and (
            row["method"] == "gnss"
            or (row["jaywalk_weight"] == base["jaywalk_weight"] and row["particles"] == base["particles"])
        )
        if at_base:
            label = METHOD_LABELS.get(row["method"], row["method"])
            lines.append(
                f"  {label:<14} CSA {row['csa']:.2f}   error median {row['euclid_median_m']:.1f} m, "
                f"p90 {row['euclid_p90_m']:.1f} m"
            )
    differences = {}
    for row in doc.get("intervals_95") or []:
        if " - " in row["method"] and row["metric"] in ("csa", "euclid_p90_m"):
            differences.setdefault(row["method"], {})[row["metric"]] = row
    for method, rows in differences.items():
        label = " - ".join(METHOD_LABELS.get(m, m) for m in method.split(" - "))
        csa, p90 = rows["csa"], rows["euclid_p90_m"]
        lines.append(
            f"  {label}: CSA {csa['value']:+.2f} [{csa['lo']:+.2f}, {csa['hi']:+.2f}], "
            f"p90 {p90['value']:+.1f} m [{p90['lo']:+.1f}, {p90['hi']:+.1f}] (95 % session bootstrap)"
        )
    trust = {r["method"]: r for r in doc.get("segment_prob_reliability") or [] if r["csa_0.9"] is not None}
    named = [f"{METHOD_LABELS[m]} on {100 * trust[m]['coverage_0.9']:.0f} % of footsteps, right "
             f"{100 * trust[m]['csa_0.9']:.0f} % of the time" for m in ("fused", "paper") if m in trust]
    if named:
        lines.append("  a side named at segment_prob >= 0.9: " + "; ".join(named))
    held = [f"{METHOD_LABELS[m]} {100 * trust[m]['accuracy_coverage']:.0f} %" for m in ("fused", "paper")
            if m in trust and trust[m].get("accuracy_coverage") is not None]
    if held:
        lines.append("  accuracy_m (68 % claimed) held the walker: " + ", ".join(held) + " of footsteps")
    lines.append(f"  full report: {report_dir / 'report.html'} (one replay page per session in view/)")
    return "\n".join(lines)


def report_run_options(report_dir: Path) -> list[str]:
    """The ``localize run`` options that track a walk as the report in ``report_dir`` scored it: its base
    particle count, jaywalk weight and GNSS sigma factor (``metrics.json``'s ``base``) and filter seed 0
    (:func:`curbside.evaluate.benchmark.run_benchmark`'s).

    Parameters
    ----------
    report_dir
        The report folder (holds ``metrics.json``).

    Returns
    -------
    list[str]
        Options for ``localize run`` (``localize run``'s own defaults differ: N = 2000 for curbside fused).
    """
    base = json.loads((report_dir / "metrics.json").read_text(encoding="utf-8"))["base"]
    options = ["--particles", str(base["particles"]), "--jaywalk-weight", str(base["jaywalk_weight"]),
               "--seed", "0"]
    if base.get("gnss_sigma_factor") is not None:
        options += ["--set", f"filter.gnss.sigma_factor={base['gnss_sigma_factor']}"]
    return options


def replay_stage(ctx: DemoContext) -> dict[str, Path]:
    """Track the first benchmark walk in each mode with its particle clouds, as the benchmark report
    scores it (:func:`report_run_options`), and write ``view.html``."""
    from curbside.cli.localize import main as localize_main

    sessions = sorted(p for p in Path(ctx.results["benchmark"]["sessions"]).iterdir() if p.is_dir())
    report_options = report_run_options(Path(ctx.results["benchmark"]["report"]))
    runs = []
    for mode in ("gnss", "inertial", "fused"):
        out = ctx.out_dir / "runs" / mode
        args = ["-v", "run", str(sessions[0]), "--map", str(ctx.out_dir / "map.geojson"), "--mode", mode,
                *report_options, "--save-particles", "-o", str(out)]
        if localize_main(args) != 0:
            raise RuntimeError(f"localize run failed on {sessions[0]} ({mode})")
        runs.append(str(out))
    # The demo's folder is its own: its page is replaced even when an older curbside wrote it unsigned.
    if localize_main(["-v", "view", *runs, "-o", str(ctx.out_dir / "view.html"), "--overwrite"]) != 0:
        raise RuntimeError("localize view failed")
    print(f"replay of {sessions[0].name} ({' '.join(report_options)}, as the report scores it): "
          f"{ctx.out_dir / 'view.html'}")
    return {"runs": ctx.out_dir / "runs", "replay_viewer": ctx.out_dir / "view.html"}


#: The map stages: build, render and summarise the default area.
MAP_STAGES: list[Stage] = [
    Stage("build the default map", build_default_map),
    Stage("render the map and write its editor", render_map_files),
    Stage("summarise the map", print_map_summary),
]

#: The demo's stages, in order: the map, the six-walk benchmark on it, a replay of one walk.
STAGES: list[Stage] = [
    *MAP_STAGES, Stage("sf6 benchmark report", benchmark_stage), Stage("replay viewer", replay_stage)
]


@contextmanager
def _heartbeat(name: str, every_s: float) -> Iterator[None]:
    """Log that stage ``name`` is still running every ``every_s`` seconds until the block ends."""
    done = threading.Event()
    started = time.perf_counter()

    def beat() -> None:
        while not done.wait(every_s):
            log.info("%s: still running (%.0f s)", name, time.perf_counter() - started)

    thread = threading.Thread(target=beat, name="demo-heartbeat", daemon=True)
    thread.start()
    try:
        yield
    finally:
        done.set()
        thread.join()


def run_demo(out_dir: str | Path, stages: Sequence[Stage] | None = None) -> dict[str, Path]:
    """Run the demo's stages in order.

    Parameters
    ----------
    out_dir
        Output folder (created if missing).
    stages
        The stages to run (default: :data:`STAGES`).

    Returns
    -------
    dict[str, pathlib.Path]
        Every file written, by name (``map_geojson``, ``map_png``, ``map_html``...), each path once.
    """
    ctx = DemoContext(Path(out_dir))
    ctx.out_dir.mkdir(parents=True, exist_ok=True)
    stages = list(stages or STAGES)
    written: dict[str, Path] = {}
    quiet_terminal = not sys.stderr.isatty()
    for i, stage in enumerate(stages, 1):
        log.info("stage %d/%d: %s", i, len(stages), stage.name)
        started = time.perf_counter()
        if quiet_terminal:
            with _heartbeat(stage.name, HEARTBEAT_S):
                paths = stage.run(ctx)
        else:
            paths = stage.run(ctx)
        for name, path in paths.items():
            if path not in written.values():
                written[name] = path
        log.info("stage %d/%d: %s done in %.1f s", i, len(stages), stage.name, time.perf_counter() - started)
    return written


def _curbside_info_only(record: logging.LogRecord) -> bool:
    return record.levelno >= logging.WARNING or record.name.startswith(("curbside", "__main__"))


def _main(args: argparse.Namespace) -> int:
    # The demo logs curbside's stages at INFO; other libraries (dask's scheduler) only at WARNING and up.
    for handler in logging.getLogger().handlers:
        handler.addFilter(_curbside_info_only)
    written = run_demo(args.out, MAP_STAGES if args.map_only else STAGES)
    print("Wrote:")
    for name, path in written.items():
        print(f"  {name:18s} {path}")
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``python -m curbside.demo``."""
    parser = make_parser(
        "curbside.demo",
        "Build the default map, render it, write its editor and summarise it, run the six-walk SF "
        "benchmark report, and replay one walk in the viewer.",
    )
    parser.add_argument("--out", default="out", help="output folder (default: out)")
    parser.add_argument("--map-only", action="store_true", help="stop after the map stages (no benchmark)")
    parser.set_defaults(func=_main, verbose=1)  # the demo logs its stages at INFO level
    return run_cli("curbside.demo", parser, argv)


if __name__ == "__main__":
    raise SystemExit(main())
