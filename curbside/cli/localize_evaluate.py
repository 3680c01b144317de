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
from pathlib import Path

from curbside.cli.common import (
    non_negative_float,
    non_negative_int,
    positive_float,
    positive_int,
    seed,
    unit_interval,
)
from curbside.errors import CurbsideInputError
from curbside.evaluate.runner import METHODS
from curbside.io import check_output_folder, output_folder

# The choices of the simulator and benchmark options, kept here so that ``localize --help`` need not
# import the simulator (tests check them against curbside.evaluate.simulate / .subsets).
PROFILES = ("nominal", "phone")
GNSS_MODELS = ("canyon", "persistent")
SUBSETS = ("paper6", "downtown", "open")
SPLITS = ("test", "tune")
DEFAULT_ROUTES = {"downtown": 8, "open": 6}

logger = logging.getLogger(__name__)

_OVERWRITE_HELP = "write into a non-empty folder curbside did not write (its other files are kept)"


def _simulate(args: argparse.Namespace) -> int:
    command = "localize simulate --benchmark" if args.benchmark else "localize simulate"
    check_output_folder(args.output, args.overwrite, command)  # before the slow imports and the OSM load
    from curbside.evaluate import routes as routes_mod
    from curbside.evaluate.gnss_model import GnssErrorModel
    from curbside.evaluate.simulate import SimulationConfig, sf6_routes, simulate_benchmark, simulate_session
    from curbside.localize.session import write_session

    config = SimulationConfig(profile=args.profile, gnss=GnssErrorModel.named(args.gnss),
                              write_velocity=not args.no_velocity, write_imu=args.imu)
    if args.benchmark:
        with output_folder(args.output, command, overwrite=args.overwrite) as tmp:
            written = simulate_benchmark(tmp, args.seeds, config, args.osm)
        print(
            f"{args.output}: {len(written)} sessions of the sf6 benchmark ({args.seeds} seed(s) per route, "
            f"profile {args.profile}, GNSS {args.gnss})"
        )
        return 0
    from curbside.evaluate.osmsource import load_osm
    from curbside.projection import LocalFrame

    names = [s.name for s in routes_mod.SF6]
    _check_custom_options(args)
    if args.route == "custom":
        if args.start is None or args.length_m is None:
            raise CurbsideInputError("--route custom", "needs --start LON LAT and --length-m")
        osm = load_osm(args.osm)
        frame = LocalFrame(osm.crs)
        spec = routes_mod.RouteSpec(
            "custom", tuple(args.start), args.length_m, args.crossings or 0, args.jaywalks or 0, "custom"
        )
        route = routes_mod.generate_route(routes_mod.build_walk_graph(osm), spec, frame, args.seed,
                                         progress=True)
    elif args.route in names:
        route_list, frame, osm = sf6_routes(load_osm(args.osm))
        route = route_list[names.index(args.route)]
    else:
        raise CurbsideInputError("--route", f"unknown route {args.route!r}; one of {names} or custom")
    session = simulate_session(route, osm, frame, args.seed, config, name=Path(args.output).name)
    if args.map:
        _check_on_map(args.map, route, frame)
    write_session(session, args.output, overwrite=args.overwrite, command="localize simulate")
    print(
        f"{args.output}: {route.spec.name}, {route.length_m:.0f} m, {route.crossings} crosswalk crossings, "
        f"{route.jaywalks} jaywalks, {len(session.gnss)} GNSS fixes"
    )
    return 0


def _check_custom_options(args: argparse.Namespace) -> None:
    """Refuse the custom route's options with a named route: they would be silently ignored."""
    given = [option for option, value in (("--start", args.start), ("--length-m", args.length_m),
                                          ("--crossings", args.crossings), ("--jaywalks", args.jaywalks))
             if value is not None]
    if given and args.route != "custom":
        raise CurbsideInputError(
            f"--route {args.route}", f"{', '.join(given)} only shape a custom route (--route custom)"
        )


def _check_on_map(map_path: str, route, frame) -> None:
    import numpy as np
    import pyproj
    import shapely

    from curbside.osmseg.mapio import read_map

    layers = read_map(map_path)
    lon, lat = frame.to_lonlat(route.xy[:, 0], route.xy[:, 1])
    from curbside.projection import LocalFrame

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


def _check_sessions(sessions: list[Path], maps: dict, methods: list[str]) -> None:
    """Refuse, before any run, a session without ground truth or off one of the maps.

    Parameters
    ----------
    sessions
        Session folders.
    maps
        The maps' layers by path (every method scores on them, the GNSS baseline too).
    methods
        The methods to run (their configurations decide whether the start pose is checked).

    Raises
    ------
    CurbsideInputError
        Naming the session's file (and the map): ``waypoints.csv`` missing or with fewer than two
        waypoints, a session outside a map's extent.
    """
    from curbside.localize.pipeline import check_on_map, resolve_config
    from curbside.localize.session import read_session

    configs = [resolve_config(None, method) for method in methods]
    for folder in sessions:
        session = read_session(folder, kinds=("gnss", "waypoints"))
        waypoints = folder / "waypoints.csv"
        if session.waypoints is None:
            raise CurbsideInputError(waypoints, "missing: no ground truth to score the session against")
        if len(session.waypoints) < 2:
            raise CurbsideInputError(
                waypoints, f"ground truth needs at least two waypoints; it holds {len(session.waypoints)}"
            )
        for path, layers in maps.items():
            for config in configs:
                check_on_map(session, layers, config, map_name=path)


def _evaluate(args: argparse.Namespace) -> int:
    from curbside.evaluate.benchmark import expand_sessions, ipin_table, plan, route_table
    from curbside.evaluate.report import write_report
    from curbside.evaluate.runner import run_all
    from curbside.osmseg.mapio import read_map

    check_output_folder(args.output, args.overwrite, "localize evaluate")  # before minutes of runs
    sessions = expand_sessions(args.sessions)
    for m in args.maps:
        if not Path(m).is_file():
            raise CurbsideInputError(m, "no such map file")
    names = args.map_names or [Path(m).stem for m in args.maps]
    if len(names) != len(args.maps) or len(set(names)) != len(names):
        raise CurbsideInputError("--map-names", "give one distinct name per map")
    maps = dict(zip(names, [str(m) for m in args.maps], strict=True))
    metrics_map = args.metrics_map or args.maps[0]
    reference = read_map(metrics_map)
    if len(reference.layer("sidewalk")) == 0:
        raise CurbsideInputError(metrics_map, "no sidewalk segments to score against: pass --metrics-map")
    _check_sessions(sessions, {path: read_map(path) for path in maps.values()}, args.methods)
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
    print(f"{args.output}: report over {len(sessions)} sessions, {len(specs)} runs")
    return 0


def _benchmark(args: argparse.Namespace) -> int:
    from curbside.evaluate.suite import SuiteConfig, check_suite_folder, run_suite, suite_summary

    check_suite_folder(args.output, args.overwrite)  # before any map, model or walk
    for path in [*(args.datasf_tiles or []), *([args.ipin] if args.ipin else [])]:
        if not Path(path).is_file():
            raise CurbsideInputError(path, "no such file")
    if args.ipin_ronin:
        if not args.ipin:
            raise CurbsideInputError("--ipin-ronin", "needs --ipin (the trials to score)")
        from curbside.localize.ronin.infer import load_model

        load_model(args.ipin_ronin)  # a missing or unreadable model fails now, not after the walks
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
    )
    what = sim.add_mutually_exclusive_group(required=True)
    what.add_argument("--route", help="one benchmark route (path1 .. path6), or 'custom'")
    what.add_argument("--benchmark", choices=["sf6"], help="all six routes, --seeds recordings each")
    sim.add_argument("--seed", type=seed, default=1,
                     help="session seed: which walk is simulated (default: %(default)s)")
    sim.add_argument("--start", nargs=2, type=float, metavar=("LON", "LAT"), help="custom route: start")
    sim.add_argument("--length-m", type=positive_float,
                     help="custom route: length in metres (it stays within 320 m of its start and uses no "
                     "street twice: about 2 km at most)")
    sim.add_argument("--crossings", type=non_negative_int, default=None,
                     help="custom route: crosswalk crossings (default: 0)")
    sim.add_argument("--jaywalks", type=non_negative_int, default=None,
                     help="custom route: crossings off crosswalks (default: 0)")
    sim.add_argument("--seeds", type=positive_int, default=3,
                     help="sessions (simulated recordings) per route for --benchmark (default: %(default)s)")
    sim.add_argument("--map", help="check the route against this map (extent, buildings)")
    sim.add_argument("--osm", help="OSM extract for heights and footways (default: the bundled one)")
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
    sim.add_argument("-o", "--output", required=True, help="session folder (or folder of sessions)")
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
        "time around the first values. Compare an automatic and a hand-corrected map (osmseg edit) with "
        "--maps auto.geojson hand.geojson.",
    )
    ev.add_argument("sessions", nargs="+", help="session folders or folders of them")
    ev.add_argument("--maps", nargs="+", required=True, help="map GeoJSONs (map sources to compare)")
    ev.add_argument("--map-names", nargs="+", help="labels of the maps (default: file stems)")
    ev.add_argument("--metrics-map", help="map whose sidewalk segments score every run (default: the first)")
    ev.add_argument("--methods", nargs="+", default=list(METHODS), choices=METHODS,
                    help="methods to run: gnss (GNSS only), inertial (RoNIN+PF), paper (the paper's plain "
                    "GNSS+RoNIN+PF), fused (curbside's filter) (default: all)")
    ev.add_argument("--jaywalk-weights", nargs="+", type=unit_interval, default=[0.0, 0.4, 1.0], metavar="W",
                    help="particle weight on the street surface, in [0, 1]; the paper's sweep "
                    "(default: 0 0.4 1)")
    ev.add_argument("--particles", nargs="+", type=positive_int, default=[500],
                    metavar="N", help="particle counts, the same for every method, curbside fused included "
                    "(default: 500, the paper's; localize run gives fused 2000)")
    ev.add_argument(
        "--gnss-sigma-factors",
        nargs="+",
        type=positive_float,
        metavar="F",
        help="GNSS sigma = factor x accuracy (default: each method's own, 0.66 for curbside fused, 1 for "
        "the paper's method)",
    )
    ev.add_argument("--velocity-source", default="auto", choices=["auto", "file", "ronin", "pdr"],
                    help="auto: velocity.csv, else RoNIN on imu.csv, else PDR (default: %(default)s)")
    ev.add_argument("--seed", type=seed, default=0, help="filter seed (default: %(default)s)")
    ev.add_argument("--workers", type=positive_int,
                    help="dask LocalCluster worker processes; 1 runs serially (default: one per CPU, "
                    "at most one per run)")
    ev.add_argument("--scheduler", help="address of an existing dask scheduler (instead of --workers)")
    ev.add_argument("--ipin", help="IPIN 2023 HDF5: add the real-data table (no map)")
    ev.add_argument("--ipin-trials", type=positive_int, help="only the first K IPIN trials")
    ev.add_argument("-o", "--output", required=True,
                    help="report folder: new, empty or a previous curbside output")
    ev.add_argument("--overwrite", action="store_true", help=_OVERWRITE_HELP)
    ev.set_defaults(func=_evaluate)


def _register_benchmark(subparsers: argparse._SubParsersAction) -> None:
    from curbside.localize.runconfig import UNSEEN_VELOCITY_MODES, UnseenVelocityConfig

    bench = subparsers.add_parser(
        "benchmark",
        help="the benchmark: simulated subsets x every method, done-when checks, report",
        description="Simulate (or reuse) the benchmark's sessions (paper6, downtown, open), track them with "
        "GNSS, RoNIN+PF, the paper's method and curbside fused, and write OUT/report/ with the tables, "
        "figures and issue 9's done-when checks (PASS/FAIL).",
    )
    bench.add_argument("--profile", choices=PROFILES, default="phone",
                       help="inertial error profile of the simulated walks (default: phone)")
    bench.add_argument("--gnss", choices=GNSS_MODELS, default="canyon",
                       help="GNSS error model of the simulated walks: canyon (the default, the scored "
                       "one) or persistent (errors that last as long as a phone's)")
    bench.add_argument("--split", choices=SPLITS, default="test", help="test (scored) or tune (default test)")
    bench.add_argument("--subsets", nargs="+", choices=SUBSETS, default=list(SUBSETS),
                       help="which subsets to run (default: all three)")
    bench.add_argument("--seeds", type=positive_int, default=3, help="sessions per route (default 3)")
    bench.add_argument("--downtown-routes", type=positive_int, default=DEFAULT_ROUTES["downtown"],
                       help=f"random downtown routes (default {DEFAULT_ROUTES['downtown']})")
    bench.add_argument("--open-routes", type=positive_int, default=DEFAULT_ROUTES["open"],
                       help=f"routes under open sky (default {DEFAULT_ROUTES['open']})")
    bench.add_argument("--map", help="the OSM map to track on (default: build it into OUT/map.geojson)")
    bench.add_argument(
        "--datasf-tiles", nargs="+", help="DataSF 2013 building tiles: add the DataSF-buildings map"
    )
    bench.add_argument("--ipin", metavar="H5",
                       help="IPIN 2023 HDF5: also score the held-out trials (real phones, no map)")
    bench.add_argument("--ipin-ronin", metavar="PT",
                       help="RoNIN weights never trained on IPIN (e.g. benchmarks/weights/ronin_ms_only.pt): "
                       "also score every IPIN trial with them, as for a phone and place the model has not "
                       "seen (reported, not a done-when check)")
    bench.add_argument("--particles", type=positive_int, default=500,
                       help="particles of the paper's method and RoNIN+PF (default 500, the paper's); "
                       "curbside fused runs with its own default (2000)")
    bench.add_argument("--seed", type=seed, default=0,
                       help="filter seed (the sessions' seeds are fixed by --split; default 0)")
    bench.add_argument("--filter-seeds", type=positive_int, default=1, metavar="N",
                       help="run every filter with N seeds from --seed on and pool them (less noisy "
                       "figures and checks, N times the tracking time; default 1)")
    bench.add_argument("--lag-s", type=non_negative_float, default=0.0, metavar="SECONDS",
                       help="also score curbside fused's fixed-lag smoothed positions with this lag, as "
                       "'fused, smoothed' (offline; default 0: off)")
    bench.add_argument("--unseen-velocity", nargs="?", const="on", default=UnseenVelocityConfig().mode,
                       choices=UNSEEN_VELOCITY_MODES,
                       help="run curbside fused everywhere with this --unseen-velocity mode, as localize run "
                       f"takes it ('on' for the flag alone; default {UnseenVelocityConfig().mode}, its own); "
                       "the checks judge it, version 0.1's fused filter stays the IPIN baseline")
    bench.add_argument("--workers", type=positive_int, default=2,
                       help="dask worker processes; 1 runs serially (default 2)")
    bench.add_argument("--scheduler", help="address of an existing dask scheduler")
    bench.add_argument("-o", "--output", required=True,
                       help="output folder: new, empty or a previous benchmark output (its sessions are "
                       "reused when they match)")
    bench.add_argument("--overwrite", action="store_true", help=_OVERWRITE_HELP)
    bench.set_defaults(func=_benchmark)
