"""The argument parsers of ``localize simulate``, ``localize evaluate`` and ``localize benchmark``: their
options, help texts and examples (:mod:`curbside.cli.localize_evaluate` runs the commands).

Only argparse and a few constants are imported here, so that ``localize --help`` stays fast.
"""

from __future__ import annotations

import argparse
import re

from curbside.cli.common import (
    finite_float,
    non_negative_float,
    non_negative_int,
    positive_float,
    positive_int,
    seed,
    unit_interval,
)
from curbside.evaluate.subset_names import DEFAULT_ROUTES, SPLITS, SUBSETS
from curbside.localize.runconstants import MODES, UNSEEN_VELOCITY_DEFAULTS, UNSEEN_VELOCITY_MODES

# The simulator's profile and GNSS model names, kept here so that ``localize --help`` need not import
# the simulator (a test checks them against curbside.evaluate.simulate and .gnss_model).
PROFILES = ("nominal", "phone")
GNSS_MODELS = ("canyon", "persistent")

_OVERWRITE_HELP = "write into a non-empty folder curbside did not write (its other files are kept)"


class _HelpFormatter(argparse.HelpFormatter):
    """Wraps the description; keeps the examples' lines (a text with line breaks) as written."""

    def _fill_text(self, text: str, width: int, indent: str) -> str:
        if "\n" in text:
            return "".join(indent + line for line in text.splitlines(keepends=True))
        return super()._fill_text(text, width, indent)


def _scheduler_address(text: str) -> str:
    """argparse ``type``: a dask scheduler address, ``[PROTOCOL://]HOST:PORT`` (an IPv6 HOST in brackets)."""
    if not re.fullmatch(r"([a-z]+://)?(\[[0-9A-Fa-f:.]+\]|[^\s:/\[\]]+):\d{1,5}", text):
        raise argparse.ArgumentTypeError(f"expected HOST:PORT or tcp://HOST:PORT, got {text!r}")
    return text


_SIMULATE_EXAMPLES = """examples:
  localize simulate --route path3 --seed 1 -o walks/path3-s1     # one walk, in a few seconds
  localize simulate --route path1 --seed 7 --profile phone --imu -o walk/   # + imu.csv
  localize simulate --route custom --start -122.4025 37.7930 --length-m 600 --crossings 2 -o walk-c/
  localize simulate --benchmark sf6 --seeds 1 -o sf6/            # six walks, one per route"""

_EVALUATE_EXAMPLES = """examples:
  localize evaluate walks/ --maps map.geojson -o report/     # map.geojson: osmseg build -o map.geojson
  localize evaluate walks/ --maps map.geojson --methods gnss fused --jaywalk-weights 0.4 -o quick/
  localize evaluate walks/ --maps auto.geojson hand.geojson --map-names auto hand -o maps/
  localize evaluate walks/ --maps map.geojson --particles 500 2000 --gnss-sigma-factors 0.66 1 -o sweep/
Put SESSIONS first: an option with several values (--maps, --methods...) takes every word after it."""

_BENCHMARK_EXAMPLES = """examples:
  localize benchmark -o bench/                              # all of it: about 6-8 min on 2 cores
  localize benchmark --subsets paper6 --seeds 1 -o quick/   # a quick look: six walks, about 3 min
  localize benchmark --map map.geojson --datasf-tiles ../shared/data/datasf/*.topojson \\
      --ipin ../shared/data/ipin2023/ipin2023-t3.h5 -o bench/  # + the DataSF map and real IPIN trials
OUT keeps its simulated sessions: a run stopped half-way (Ctrl-C) resumes from them."""



def add_simulate_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Add the ``simulate`` parser (options, help, examples) to ``localize``'s ``subparsers`` and return
    it; the caller sets the command it runs (``func``)."""
    sim = subparsers.add_parser(
        "simulate",
        help="simulate walks on real SF sidewalks (sessions)",
        description="Simulate a walk on the real sidewalks and crosswalks of downtown San Francisco (the "
        "bundled OpenStreetMap extract) and write it as a session folder: waypoints.csv (the ground "
        "truth), gnss.csv (an urban-canyon error model driven by OSM building heights), steps.csv, "
        "velocity.csv (RoNIN-like) and, with --imu, imu.csv. One of the six benchmark routes shaped like "
        "the paper's Table 1, a custom route, or the whole sf6 benchmark.",
        epilog=_SIMULATE_EXAMPLES,
        formatter_class=_HelpFormatter,
    )
    what = sim.add_mutually_exclusive_group(required=True)
    what.add_argument("--route", help="one benchmark route (path1 .. path6, shaped like the paper's six), "
                      "or 'custom' (with --start and --length-m)")
    what.add_argument("--benchmark", choices=["sf6"],
                      help="sf6: all six routes, --seeds walks each, into one folder of sessions")
    sim.add_argument("--seed", type=seed, default=None,
                     help="session seed, an integer >= 0: which walk is simulated (default: 1; not with "
                     "--benchmark, whose walks take seeds 1..N)")
    sim.add_argument("--start", nargs=2, type=finite_float, metavar=("LON", "LAT"),
                     help="custom route: where it starts, longitude then latitude in degrees (WGS84), near a "
                     "footway of the extract (downtown SF, e.g. -122.4025 37.7930)")
    sim.add_argument("--length-m", type=positive_float,
                     help="custom route: length in metres (it stays within 320 m of its start and uses no "
                     "street twice: about 2 km at most)")
    sim.add_argument("--crossings", type=non_negative_int, default=None,
                     help="custom route: how many crosswalks it crosses (default: 0)")
    sim.add_argument("--jaywalks", type=non_negative_int, default=None,
                     help="custom route: how many times it crosses a street off a crosswalk (default: 0)")
    sim.add_argument("--seeds", type=positive_int, default=None,
                     help="--benchmark: walks per route, with session seeds 1..N (default: 3)")
    sim.add_argument("--map", help="a map GeoJSON (osmseg build): refuse a route outside its extent and warn "
                     "about waypoints inside its buildings")
    sim.add_argument("--osm", help="OSM extract (.osm or .osm.bz2) for heights and footways (default: the "
                     "bundled one)")
    sim.add_argument("--imu", action="store_true",
                     help="also write imu.csv (100 Hz phone IMU, made for the footstep detector and PDR; "
                     "RoNIN cannot read it)")
    sim.add_argument("--no-velocity", action="store_true", help="do not write velocity.csv")
    sim.add_argument(
        "--profile",
        choices=PROFILES,
        default="nominal",
        help="inertial error model: nominal (RoNIN's published levels) or phone (a phone in a hand: "
        "heading jumps, drift, speed scale, stops at kerbs); default nominal",
    )
    sim.add_argument(
        "--gnss",
        choices=GNSS_MODELS,
        default="canyon",
        help="GNSS error model: canyon (the benchmark's, calibrated to the paper's GNSS column) or "
        "persistent (the same error sizes, with errors that last as long as real phones' do); default canyon",
    )
    sim.add_argument("-o", "--output", required=True,
                     help="the session folder to write (with --benchmark: the folder of sessions): new, "
                     "empty or a previous curbside output")
    sim.add_argument("--overwrite", action="store_true", help=_OVERWRITE_HELP)
    return sim


def add_evaluate_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Add the ``evaluate`` parser (options, help, examples) to ``localize``'s ``subparsers`` and return
    it; the caller sets the command it runs (``func``)."""
    ev = subparsers.add_parser(
        "evaluate",
        help="the paper's metrics, tables and figures over sessions",
        description="Track every session with each method, map and parameter, score every footstep "
        "against the ground truth (waypoints.csv) and write a report folder: metrics.json (SPEC metric "
        "names), report.md and report.html (the paper's tables and figures), and view/SESSION.html, a "
        "replay page per session. Each list option with several values is a sweep, one parameter at a "
        "time around the base values (the first map, w = 0.4 when given, the first of the others). "
        "Compare an automatic and a hand-corrected map (osmseg edit) with --maps auto.geojson hand.geojson.",
        epilog=_EVALUATE_EXAMPLES,
        formatter_class=_HelpFormatter,
    )
    ev.add_argument("sessions", nargs="+", help="session folders (each with waypoints.csv, the ground "
                    "truth), or folders of them (localize simulate's output)")
    ev.add_argument("--maps", nargs="+", required=True,
                    help="map GeoJSONs (osmseg build, osmseg edit); several are map sources to compare")
    ev.add_argument("--map-names", nargs="+", help="labels of the maps, one each (default: file stems)")
    ev.add_argument("--metrics-map", help="map whose sidewalk segments score every run (default: the first)")
    ev.add_argument("--methods", nargs="+", default=list(MODES), choices=MODES,
                    help="methods to run, on the sessions and on the --ipin trials: gnss (GNSS only), "
                    "inertial (RoNIN+PF), paper (the paper's plain GNSS+RoNIN+PF), fused (curbside's filter) "
                    "(default: all)")
    ev.add_argument("--jaywalk-weights", nargs="+", type=unit_interval, default=[0.0, 0.4, 1.0], metavar="W",
                    help="weight, in [0, 1], of a particle on the street surface off a crosswalk (0: never "
                    "there, 1: as likely as on a sidewalk); the paper's sweep (default: 0 0.4 1)")
    ev.add_argument("--particles", nargs="+", type=positive_int, default=[500],
                    metavar="N", help="particle counts, the same for every method, curbside fused included "
                    "(default: 500, the paper's; localize run gives fused 2000)")
    ev.add_argument(
        "--gnss-sigma-factors",
        nargs="+",
        type=positive_float,
        metavar="F",
        help="the GNSS likelihood's standard deviation (m) = F x each fix's reported accuracy_m (default: "
        "each method's own, 0.66 for curbside fused, 1 for the paper's method)",
    )
    ev.add_argument("--velocity-source", default="auto", choices=["auto", "file", "ronin", "pdr"],
                    help="auto: velocity.csv, else RoNIN on imu.csv (PDR on a simulated one), else PDR "
                         "(default: %(default)s)")
    ev.add_argument("--seed", type=seed, default=0,
                    help="filter seed, an integer >= 0 (default: %(default)s)")
    ev.add_argument("--workers", type=positive_int,
                    help="dask LocalCluster worker processes; 1 runs serially (default: one per CPU, "
                    "at most one per run)")
    ev.add_argument("--scheduler", type=_scheduler_address,
                    help="address of a running dask scheduler, e.g. tcp://host:8786 (instead of --workers)")
    ev.add_argument("--ipin", metavar="H5", help="IPIN 2023 HDF5 (ipin2023-t3.h5): add a table of the "
                    "--methods over its trials (real phones, tracked without a map)")
    ev.add_argument("--ipin-trials", type=positive_int, metavar="K",
                    help="only the first K IPIN trials (default: all)")
    ev.add_argument("-o", "--output", required=True,
                    help="report folder: new, empty or a previous curbside output")
    ev.add_argument("--overwrite", action="store_true", help=_OVERWRITE_HELP)
    return ev


def add_benchmark_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Add the ``benchmark`` parser (options, help, examples) to ``localize``'s ``subparsers`` and return
    it; the caller sets the command it runs (``func``)."""
    bench = subparsers.add_parser(
        "benchmark",
        help="the benchmark: simulated subsets x every method, done-when checks, report",
        description="Simulate (or reuse) the benchmark's sessions (paper6, downtown, open), track them with "
        "GNSS, RoNIN+PF, the paper's method and curbside fused, and write OUT/report/ with the tables, "
        "figures and issue 9's done-when checks (PASS/FAIL).",
        epilog=_BENCHMARK_EXAMPLES,
        formatter_class=_HelpFormatter,
    )
    bench.add_argument("--profile", choices=PROFILES, default="phone",
                       help="inertial error profile of the simulated walks (default: phone)")
    bench.add_argument("--gnss", choices=GNSS_MODELS, default="canyon",
                       help="GNSS error model of the simulated walks: canyon (the default, the scored "
                       "one) or persistent (errors that last as long as a phone's)")
    bench.add_argument("--split", choices=SPLITS, default="test",
                       help="which routes and walks: test (the scored ones) or tune (others of the same "
                       "kind, to choose parameters on); default test")
    bench.add_argument("--subsets", nargs="+", choices=SUBSETS, default=list(SUBSETS),
                       help="which subsets to run (default: all three)")
    bench.add_argument("--seeds", type=positive_int, default=3,
                       help="simulated walks (sessions) per route (default 3)")
    bench.add_argument("--downtown-routes", type=positive_int, default=DEFAULT_ROUTES["downtown"],
                       help=f"random downtown routes (default {DEFAULT_ROUTES['downtown']})")
    bench.add_argument("--open-routes", type=positive_int, default=DEFAULT_ROUTES["open"],
                       help=f"routes under open sky (default {DEFAULT_ROUTES['open']})")
    bench.add_argument("--map", help="the OSM map of downtown SF to track on (default: build it into "
                       "OUT/map.geojson, about 20 s)")
    bench.add_argument("--datasf-tiles", nargs="+", metavar="TOPOJSON",
                       help="DataSF 2013 building tiles (.topojson): also track on a map with their "
                       "buildings and OSM's streets")
    bench.add_argument("--ipin", metavar="H5",
                       help="IPIN 2023 HDF5 (ipin2023-t3.h5): also score its held-out trials (real phones, "
                       "no map)")
    bench.add_argument("--ipin-ronin", metavar="PT",
                       help="RoNIN weights (.pt with its .json) never trained on IPIN (e.g. "
                       "benchmarks/weights/ronin_ms_only.pt): also score every IPIN trial with them, as for "
                       "a phone and place the model has not seen (reported, not a done-when check)")
    bench.add_argument("--particles", type=positive_int, default=500,
                       help="particles of the paper's method and RoNIN+PF (default 500, the paper's); "
                       "curbside fused runs with its own default (2000)")
    bench.add_argument("--seed", type=seed, default=0,
                       help="filter seed, an integer >= 0 (the sessions' seeds are fixed by --split; "
                       "default 0)")
    bench.add_argument("--filter-seeds", type=positive_int, default=1, metavar="N",
                       help="run every filter with N seeds from --seed on and pool them (less noisy "
                       "figures and checks, N times the tracking time; default 1)")
    bench.add_argument("--lag-s", type=non_negative_float, default=0.0, metavar="SECONDS",
                       help="also score curbside fused's fixed-lag smoothed positions with this lag, as "
                       "'fused, smoothed' (offline; default 0: off)")
    bench.add_argument("--unseen-velocity", nargs="?", const="on", default=UNSEEN_VELOCITY_DEFAULTS.mode,
                       choices=UNSEEN_VELOCITY_MODES,
                       help="run curbside fused everywhere with this --unseen-velocity mode, as localize run "
                       "takes it ('on' for the flag alone; default "
                       f"{UNSEEN_VELOCITY_DEFAULTS.mode}, its own); "
                       "the checks judge it, version 0.1's fused filter stays the IPIN baseline")
    bench.add_argument("--workers", type=positive_int, default=2,
                       help="dask worker processes; 1 runs serially (default 2)")
    bench.add_argument("--scheduler", type=_scheduler_address,
                       help="address of a running dask scheduler, e.g. tcp://host:8786 (instead of "
                       "--workers)")
    bench.add_argument("-o", "--output", required=True,
                       help="output folder: new, empty or a previous benchmark output (its sessions are "
                       "reused when they match)")
    bench.add_argument("--overwrite", action="store_true", help=_OVERWRITE_HELP)
    return bench
