"""``localize simulate`` and ``localize evaluate``: the benchmark walks and the paper's report.

::

    localize simulate --route path1 [--seed S] [--map MAP] [--imu] [--no-velocity] -o SESSION [--overwrite]
    localize simulate --route custom --start LON LAT --length-m M [--crossings C] [--jaywalks J] -o SESSION
    localize simulate --benchmark sf6 [--seeds N] [--imu] -o DIR [--overwrite]
    localize simulate ... [--profile nominal|phone]
    localize evaluate SESSIONS... --maps A.geojson [B.geojson ...] [--map-names NAME ...]
                      [--metrics-map MAP] [--methods gnss inertial fused] [--jaywalk-weights 0 0.4 1]
                      [--particles 500 ...] [--gnss-sigma-factors F ...] [--seed S]
                      [--workers N | --scheduler ADDRESS] [--ipin H5 [--ipin-trials K]] -o REPORT_DIR
                      [--overwrite]
    localize benchmark [--profile phone|nominal] [--split test|tune] [--subsets paper6 downtown open]
                       [--seeds 3] [--map MAP] [--datasf-tiles T ...] [--ipin H5 [--ipin-ronin PT]]
                       [--workers 2] -o OUT

``SESSIONS`` are session folders or folders of them. Each list option with several values is a
parameter sweep (one at a time around the base values); all runs go to one report. ``benchmark``
simulates (or reuses) the benchmark's subsets, runs every method, checks issue 9's "done when" and
writes ``OUT/report/`` (:mod:`curbside.evaluate.suite`). Output folders must be new, empty or a
previous curbside output unless ``--overwrite`` (see :mod:`curbside.io`).
"""

from __future__ import annotations

import argparse
import logging
import os
import re
from pathlib import Path

from curbside.cli.common import (
    finite_float,
    non_negative_float,
    non_negative_int,
    positive_float,
    positive_int,
    seed,
    unit_interval,
)
from curbside.errors import CurbsideInputError
from curbside.evaluate.subset_names import DEFAULT_ROUTES, SPLITS, SUBSETS
from curbside.localize.runconstants import MODES, UNSEEN_VELOCITY_DEFAULTS, UNSEEN_VELOCITY_MODES

# The simulator's profile and GNSS model names, kept here so that ``localize --help`` need not import
# the simulator (a test checks them against curbside.evaluate.simulate and .gnss_model).
PROFILES = ("nominal", "phone")
GNSS_MODELS = ("canyon", "persistent")

logger = logging.getLogger(__name__)

_OVERWRITE_HELP = "write into a non-empty folder curbside did not write (its other files are kept)"


def _simulate(args: argparse.Namespace) -> int:
    from curbside.io import check_output_folder, output_folder

    command = "localize simulate --benchmark" if args.benchmark else "localize simulate"
    _check_simulate_options(args)
    check_output_folder(args.output, args.overwrite, command)  # before the slow imports and the OSM load
    from curbside.evaluate import routes as routes_mod
    from curbside.evaluate.gnss_model import GnssErrorModel
    from curbside.evaluate.simulate import SimulationConfig, sf6_routes, simulate_benchmark, simulate_session
    from curbside.localize.session import write_session

    config = SimulationConfig(profile=args.profile, gnss=GnssErrorModel.named(args.gnss),
                              write_velocity=not args.no_velocity, write_imu=args.imu)
    if args.benchmark:
        seeds = args.seeds or 3
        with output_folder(args.output, command, overwrite=args.overwrite) as tmp:
            written = simulate_benchmark(tmp, seeds, config, args.osm)
        print(
            f"{args.output}: {len(written)} sessions of the sf6 benchmark ({seeds} seed(s) per route, "
            f"profile {args.profile}, GNSS {args.gnss})"
        )
        return 0
    from curbside.evaluate.osmsource import load_osm
    from curbside.osmseg.mapio import read_map
    from curbside.projection import LocalFrame

    names = [s.name for s in routes_mod.SF6]
    if args.route != "custom" and args.route not in names:
        raise CurbsideInputError("--route", f"unknown route {args.route!r}; one of {names} or custom")
    if args.route == "custom" and (args.start is None or args.length_m is None):
        raise CurbsideInputError("--route custom", "needs --start LON LAT and --length-m")
    layers = read_map(args.map) if args.map else None  # a bad map fails now, not after the walk
    osm = load_osm(args.osm)
    seed = 1 if args.seed is None else args.seed
    if args.route == "custom":
        frame = LocalFrame(osm.crs)
        route = _custom_route(args, routes_mod.build_walk_graph(osm), frame, seed)
    else:
        route_list, frame, osm = sf6_routes(osm, args.osm, only=args.route)
        route = route_list[0]
    session = simulate_session(route, osm, frame, seed, config, name=Path(args.output).name)
    if layers is not None:
        _check_on_map(args.map, layers, route, frame)
    write_session(session, args.output, overwrite=args.overwrite, command="localize simulate")
    print(
        f"{args.output}: {route.spec.name}, {route.length_m:.0f} m, "
        f"{_count(route.crossings, 'crosswalk crossing')}, {_count(route.jaywalks, 'jaywalk')}, "
        f"{_count(len(session.gnss), 'GNSS fix', 'GNSS fixes')}"
    )
    return 0


def _custom_route(args: argparse.Namespace, graph, frame, seed: int):
    """``--route custom``: the walk from ``--start``, refused when no footway of the extract is near it."""
    from curbside.evaluate import routes as routes_mod

    lon, lat = args.start
    if not (-180 <= lon <= 180 and -90 <= lat <= 90):
        raise CurbsideInputError("--start", f"({lon:g}, {lat:g}) is not a longitude and a latitude in "
                                 "degrees; give LON then LAT, e.g. -122.4025 37.7930")
    spec = routes_mod.RouteSpec(
        "custom", (lon, lat), args.length_m, args.crossings or 0, args.jaywalks or 0, "custom"
    )
    far = routes_mod.far_from_footways(graph, spec, frame)
    if far:
        raise CurbsideInputError("--start", far)
    return routes_mod.generate_route(graph, spec, frame, seed, progress=True)


def _check_simulate_options(args: argparse.Namespace) -> None:
    """Refuse the options that the walks asked for would silently ignore."""

    def given(*options: str) -> list[str]:
        return [o for o in options if getattr(args, o[2:].replace("-", "_")) is not None]

    def listed(options: list[str], one: str, many: str) -> str:
        names = options[0] if len(options) == 1 else f"{', '.join(options[:-1])} and {options[-1]}"
        return f"{names} {one if len(options) == 1 else many}"

    custom = given("--start", "--length-m", "--crossings", "--jaywalks")
    if args.benchmark and (unused := given("--seed", "--map") + custom):
        unused_here = listed(unused, "does", "do")
        raise CurbsideInputError("--benchmark sf6", f"{unused_here} not apply to the benchmark (six fixed "
                                 "routes, session seeds 1..N from --seeds N, no map check)")
    if args.route and args.seeds is not None:
        raise CurbsideInputError(f"--route {args.route}",
                                 "--seeds only applies to --benchmark (one walk: --seed S)")
    if args.route and args.route != "custom" and custom:
        shape = listed(custom, "only shapes", "only shape")
        raise CurbsideInputError(f"--route {args.route}", f"{shape} a custom route (--route custom)")


def _check_on_map(map_path: str, layers, route, frame) -> None:
    """Refuse a route outside the map's extent; warn about waypoints inside its buildings."""
    import numpy as np
    import pyproj
    import shapely

    from curbside.projection import LocalFrame

    lon, lat = frame.to_lonlat(route.xy[:, 0], route.xy[:, 1])
    x, y = LocalFrame(pyproj.CRS(layers.crs)).to_xy(lon, lat)
    if not shapely.box(*layers.gdf.total_bounds).contains(shapely.multipoints(np.column_stack([x, y]))):
        raise CurbsideInputError(map_path, f"route {route.spec.name} lies outside the map's extent")
    inside = shapely.contains_xy(layers.union("building"), x, y)
    if inside.any():
        logger.warning(
            "%d of %d waypoints of %s lie in a building of %s",
            inside.sum(),
            len(x),
            route.spec.name,
            map_path,
        )


def _check_is_file(path: str, what: str) -> None:
    """Refuse a missing ``what`` file, or a folder given for one; a path with ``*`` or ``?`` in it is a
    shell pattern that matched nothing."""
    p = Path(path)
    if p.is_dir():
        raise CurbsideInputError(path, f"is a folder, not a {what} file")
    if not p.is_file():
        pattern = " (a pattern that matched no file)" if any(c in path for c in "*?[") else ""
        raise CurbsideInputError(path, f"no such {what} file{pattern}")


def _check_ipin(path: str, held_out: bool) -> None:
    """Refuse, before any run, an ``--ipin`` file that is not an IPIN 2023 HDF5 with trials (with
    ``held_out``: with held-out ``repetition04`` trials, the ones the benchmark scores)."""
    from curbside.localize.readers.ipin import list_trials
    from curbside.localize.ronin.data import IPIN_TEST_MARK

    _check_is_file(path, "IPIN HDF5")
    trials = list_trials(path)  # a file that is not HDF5, or holds no trial, is refused here
    if held_out and not any(IPIN_TEST_MARK in name for name in trials):
        raise CurbsideInputError(
            path, f"none of its {len(trials)} trials is a held-out one ({IPIN_TEST_MARK}), which the "
            "benchmark scores; give the full ipin2023-t3.h5",
        )


def _check_ronin_weights(path: str) -> None:
    """Refuse, before any walk, ``--ipin-ronin`` weights that are missing, lack their config or do not
    load."""
    from curbside.localize.paths import config_path_for
    from curbside.localize.ronin.infer import load_model

    _check_is_file(path, "RoNIN weights")
    config = config_path_for(path)
    if Path(path) != config and not config.is_file():
        raise CurbsideInputError(
            path, f"its config {config.name} is not beside it (a RoNIN model is a .pt with its .json, as "
            "localize train-ronin writes them)",
        )
    load_model(path)


def _count(n: int, one: str, many: str | None = None) -> str:
    """``1 jaywalk``, ``2 jaywalks``."""
    return f"{n} {one if n == 1 else (many or one + 's')}"


def _check_given_once(paths: list, what: str) -> None:
    """Refuse a file or folder given twice (as the same path, or as two that resolve to it, a folder of
    sessions and one of its sessions among them): its runs would count twice in every pooled figure."""
    seen: dict[Path, str] = {}
    for path in map(str, paths):
        resolved = Path(path).resolve()
        if resolved in seen:
            also = "" if seen[resolved] == path else f" (also as {seen[resolved]})"
            raise CurbsideInputError(path, f"the same {what} is given twice{also}: give each once")
        seen[resolved] = path


def _map_names(maps: list[str], map_names: list[str] | None) -> list[str]:
    """The maps' labels: ``--map-names``, one distinct name per map (the same file under two names is a
    check that both give the same figures), or else the file stems; without ``--map-names``, a map given
    twice is refused as such, and two files of one name as needing names."""
    if map_names is not None:
        if len(map_names) != len(maps) or len(set(map_names)) != len(map_names):
            raise CurbsideInputError("--map-names", "give one distinct name per map")
        return map_names
    _check_given_once(maps, "map")
    names = [Path(m).stem for m in maps]
    for i, name in enumerate(names):
        if name in names[:i]:
            other = maps[names.index(name)]
            raise CurbsideInputError(
                maps[i], f"has the file name of {other} ('{name}'): name the maps with --map-names")
    return names


def _evaluate(args: argparse.Namespace) -> int:
    from curbside.evaluate.dask_cluster import check_scheduler
    from curbside.io import check_output_folder, output_folder
    from curbside.localize.paths import expand_sessions

    check_output_folder(args.output, args.overwrite, "localize evaluate")  # before minutes of runs
    if args.scheduler:
        check_scheduler(args.scheduler)  # in seconds, before the maps and sessions are read
    sessions = expand_sessions(args.sessions)
    _check_given_once(sessions, "session folder")
    for m in [*args.maps, *([args.metrics_map] if args.metrics_map else [])]:
        _check_is_file(m, "map")
    names = _map_names(args.maps, args.map_names)
    if args.ipin:
        _check_ipin(args.ipin, held_out=False)  # before the runs, not after them
    elif args.ipin_trials is not None:
        raise CurbsideInputError("--ipin-trials", "chooses trials of --ipin H5, which is not given")
    # the heavy imports, once the cheap checks passed
    from curbside.evaluate.benchmark import ipin_table, plan, route_table
    from curbside.evaluate.report import write_report
    from curbside.evaluate.runner import check_sessions, run_all
    from curbside.osmseg.mapio import read_map

    maps = dict(zip(names, [str(m) for m in args.maps], strict=True))
    metrics_map = args.metrics_map or args.maps[0]
    reference = read_map(metrics_map)
    if len(reference.layer("sidewalk")) == 0:
        raise CurbsideInputError(metrics_map, "no sidewalk segments to score against: pass --metrics-map")
    check_sessions(sessions, {path: read_map(path) for path in maps.values()}, tuple(args.methods))
    sigmas = tuple(args.gnss_sigma_factors) if args.gnss_sigma_factors else (None,)
    specs, base = plan(
        sessions,
        maps,
        tuple(args.methods),
        tuple(args.jaywalk_weights),
        tuple(args.particles),
        sigmas,
        args.seed,
        str(metrics_map),
        velocity_source=args.velocity_source,
    )
    workers = args.workers if args.workers is not None else min(len(specs), os.cpu_count() or 1)
    results = run_all(specs, workers=workers, scheduler=args.scheduler)
    extra, extra_json = [], {}
    table1 = route_table(sessions)
    if args.ipin:
        tables, rows = ipin_table(args.ipin, args.ipin_trials, args.seed)
        extra += tables
        extra_json["ipin"] = rows
    with output_folder(args.output, "localize evaluate", overwrite=args.overwrite) as tmp:
        write_report(
            results,
            tmp,
            base,
            reference,
            extra,
            [table1] if table1 else [],
            extra_json,
            intro=f"{len(sessions)} session(s), {len(maps)} map(s), {len(specs)} runs.",
        )
    print(f"{args.output}: report over {_count(len(sessions), 'session')}, {_count(len(specs), 'run')}")
    return 0


def _benchmark(args: argparse.Namespace) -> int:
    from curbside.evaluate.dask_cluster import check_scheduler
    from curbside.evaluate.suite_output import check_suite_folder
    from curbside.osmseg.inputs import check_map_file

    check_suite_folder(args.output, args.overwrite)  # before any map, model or walk
    if args.scheduler:
        check_scheduler(args.scheduler)  # in seconds, not after minutes of simulated walks
    if args.ipin_ronin and not args.ipin:
        raise CurbsideInputError("--ipin-ronin", "needs --ipin (the trials to score)")
    for path in args.datasf_tiles or []:
        _check_is_file(path, "DataSF tile")
    if args.map:
        check_map_file(args.map)
    # the heavy imports, once the cheap checks passed
    from curbside.evaluate.suite import SuiteConfig, run_suite, suite_summary

    if args.ipin_ronin:  # IPIN is scored after every walk: a bad model or file fails now, not then
        _check_ronin_weights(args.ipin_ronin)
    if args.ipin:
        _check_ipin(args.ipin, held_out=True)
    config = SuiteConfig(
        profile=args.profile,
        split=args.split,
        subsets=tuple(args.subsets),
        seeds=args.seeds,
        downtown_routes=args.downtown_routes,
        open_routes=args.open_routes,
        particles=args.particles,
        filter_seed=args.seed,
        filter_seeds=args.filter_seeds,
        smoothing_lag_s=args.lag_s,
        unseen_velocity=args.unseen_velocity,
        gnss=args.gnss,
    )
    paths = run_suite(
        args.output,
        config,
        map_path=args.map,
        datasf_tiles=args.datasf_tiles,
        workers=args.workers,
        scheduler=args.scheduler,
        ipin=args.ipin,
        ipin_ronin=args.ipin_ronin,
        overwrite=args.overwrite,
    )
    print(suite_summary(paths["report"]), end="")
    print(f"{paths['report.html']}")
    return 0


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


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add ``simulate``, ``evaluate`` and ``benchmark`` to ``subparsers``."""
    _register_simulate(subparsers)
    _register_evaluate(subparsers)
    _register_benchmark(subparsers)


def _register_simulate(subparsers: argparse._SubParsersAction) -> None:
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
    sim.set_defaults(func=_simulate)


def _register_evaluate(subparsers: argparse._SubParsersAction) -> None:
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
                    help="methods to run: gnss (GNSS only), inertial (RoNIN+PF), paper (the paper's plain "
                    "GNSS+RoNIN+PF), fused (curbside's filter) (default: all)")
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
    ev.add_argument("--ipin", metavar="H5", help="IPIN 2023 HDF5 (ipin2023-t3.h5): add a table over its "
                    "trials (real phones, tracked without a map)")
    ev.add_argument("--ipin-trials", type=positive_int, metavar="K",
                    help="only the first K IPIN trials (default: all)")
    ev.add_argument("-o", "--output", required=True,
                    help="report folder: new, empty or a previous curbside output")
    ev.add_argument("--overwrite", action="store_true", help=_OVERWRITE_HELP)
    ev.set_defaults(func=_evaluate)


def _register_benchmark(subparsers: argparse._SubParsersAction) -> None:
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
    bench.set_defaults(func=_benchmark)
