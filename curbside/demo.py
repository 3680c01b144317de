"""The end-to-end demo run by ``make demo``: ``python -m curbside.demo --out out``.

The demo is a list of stages (:data:`STAGES`) run in order on a shared :class:`DemoContext`; each stage
returns the files it wrote, by name. The first stages build the default map from the bundled
OpenStreetMap extract, write ``map.geojson``, ``map.png`` and ``map.html`` and print the per-class
summary; the last simulates the six San Francisco walks, tracks them (GNSS, RoNIN+PF, GNSS+RoNIN+PF)
and writes the benchmark report under ``benchmark/report/``.
"""

from __future__ import annotations

import argparse
import logging
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from tqdm import tqdm

from curbside.cli.common import make_parser, run_cli
from curbside.evaluate.benchmark import demo_stage
from curbside.osmseg.build import build_map
from curbside.osmseg.mapio import write_map
from curbside.osmseg.plot import save_html, save_png
from curbside.osmseg.summary import class_summary, format_summary

log = logging.getLogger(__name__)


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
    """Render the map to ``map.png`` and ``map.html``."""
    layers = ctx.results["map"]
    return {
        "map_png": save_png(layers, ctx.out_dir / "map.png"),
        "map_html": save_html(layers, ctx.out_dir / "map.html"),
    }


def print_map_summary(ctx: DemoContext) -> dict[str, Path]:
    """Print the per-class counts and areas of the map."""
    summary = class_summary(ctx.results["map"])
    ctx.results["map_summary"] = summary
    print(f"Map layers ({ctx.results['map'].meta.get('source', 'unknown source')}):")
    print(format_summary(summary))
    return {}


#: The map stages: build, render and summarise the default area.
MAP_STAGES: list[Stage] = [
    Stage("build the default map", build_default_map),
    Stage("render the map", render_map_files),
    Stage("summarise the map", print_map_summary),
]

#: The demo's stages, in order: the map, then the six-walk benchmark on it.
STAGES: list[Stage] = [*MAP_STAGES, Stage("sf6 benchmark report", demo_stage)]


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
        Every file written, by name (``map_geojson``, ``map_png``, ``map_html``...).
    """
    ctx = DemoContext(Path(out_dir))
    ctx.out_dir.mkdir(parents=True, exist_ok=True)
    written: dict[str, Path] = {}
    for stage in tqdm(list(stages or STAGES), desc="demo", unit="stage", disable=None):
        started = time.perf_counter()
        paths = stage.run(ctx)
        written.update(paths)
        log.info("%s: %.1f s", stage.name, time.perf_counter() - started)
        for name, path in paths.items():
            log.info("  wrote %s: %s", name, path)
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
        print(f"  {name:12s} {path}")
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``python -m curbside.demo``."""
    parser = make_parser(
        "curbside.demo",
        "Build the default map, render and summarise it, then run the six-walk SF benchmark report.",
    )
    parser.add_argument("--out", default="out", help="output folder (default: out)")
    parser.add_argument("--map-only", action="store_true", help="stop after the map stages (no benchmark)")
    parser.set_defaults(func=_main, verbose=1)  # the demo logs its stages at INFO level
    return run_cli("curbside.demo", parser, argv)


if __name__ == "__main__":
    raise SystemExit(main())
