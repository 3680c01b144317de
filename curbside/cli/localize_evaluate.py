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
previous curbside output unless ``--overwrite`` (see :mod:`curbside.io`). The options, help texts and
examples are in :mod:`curbside.cli.localize_evaluate_args`.
"""

from __future__ import annotations

import argparse
import logging
import os
from pathlib import Path

from curbside.cli.localize_evaluate_args import add_benchmark_parser, add_evaluate_parser, add_simulate_parser
from curbside.errors import CurbsideInputError

logger = logging.getLogger(__name__)


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
        tables, rows = ipin_table(args.ipin, args.ipin_trials, args.seed, methods=tuple(args.methods))
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


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add ``simulate``, ``evaluate`` and ``benchmark`` to ``subparsers``."""
    add_simulate_parser(subparsers).set_defaults(func=_simulate)
    add_evaluate_parser(subparsers).set_defaults(func=_evaluate)
    add_benchmark_parser(subparsers).set_defaults(func=_benchmark)
