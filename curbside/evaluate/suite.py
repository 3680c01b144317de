"""The benchmark harness behind ``localize benchmark``: subsets x methods x maps, one seeded run.

:func:`run_suite` builds (or takes) the OSM map and, given the DataSF tiles, the DataSF-buildings map;
simulates (or reuses) every session of the requested subsets and split
(:mod:`curbside.evaluate.subsets`); tracks each with GNSS, RoNIN+PF, the paper's method and curbside
fused at the base jaywalk weight (and at every weight of the sweep on ``paper6``, the paper's
Table 2); scores every run against the OSM map's sidewalk segments; checks the issue's "done when"
(:mod:`curbside.evaluate.criteria`) and writes ``report.md``, ``report.html``, ``metrics.json`` and
``run.json`` (every parameter, the timings) under ``OUT/report/``. The IPIN trials scored beside the
walks (``--ipin``) are :mod:`curbside.evaluate.suite_ipin`'s.
"""

from __future__ import annotations

import json
import logging
import os
import platform
import subprocess
import time
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any

import pandas as pd

import curbside
from curbside.errors import CurbsideInputError
from curbside.evaluate import criteria
from curbside.evaluate.benchmark import IpinScores, snapshot_times
from curbside.evaluate.gnss_model import GnssErrorModel
from curbside.evaluate.runner import (
    SMOOTHED_METHOD,
    RunSpec,
    check_sessions,
    pool,
    run_all,
    smoothed_results,
    subset_of,
)
from curbside.evaluate.simulate import PROFILES, SimulationConfig
from curbside.evaluate.subsets import DEFAULT_ROUTES, SPLITS, SUBSETS, benchmark_sessions, load_world
from curbside.evaluate.suite_ipin import ipin_info, ipin_scorings
from curbside.evaluate.suite_output import (
    DATASF_MAP,
    OSM_MAP,
    benchmark_maps,
    check_map_area,
    check_suite_folder,
    folder_for_run,
)
from curbside.localize.filter import FilterConfig
from curbside.localize.runconfig import UNSEEN_VELOCITY_MODES, UnseenVelocityConfig
from curbside.localize.session import read_session
from curbside.osmseg.mapio import read_map

log = logging.getLogger(__name__)

#: The methods every benchmark table shows, in order.
SUITE_METHODS: tuple[str, ...] = ("gnss", "inertial", "paper", "fused")


@dataclass(frozen=True)
class SuiteConfig:
    """Every parameter of a benchmark run (recorded in ``run.json``).

    Attributes
    ----------
    profile
        Simulation profile: ``phone`` (default) or ``nominal``.
    split
        ``test`` (scored) or ``tune`` (for choosing parameters).
    subsets
        Among ``paper6``, ``downtown``, ``open``.
    seeds
        Sessions per route.
    downtown_routes, open_routes
        Routes of the random subsets.
    jaywalk_weight
        The base weight w (the criteria are judged here).
    sweep_weights, sweep_subsets
        Table 2: every weight on these subsets, for the particle-filter methods.
    particles, filter_seed, velocity_source
        Filter settings passed to ``track_session``; ``particles`` is the paper's N, for its method and
        RoNIN+PF.
    fused_particles
        Curbside fused's N (its own default).
    filter_seeds
        Run every filter (not GNSS alone, and the IPIN runs too) with this many seeds from
        ``filter_seed`` on; the tables, checks and intervals pool them per session, the report's
        figures draw the first seed's runs.
    datasf_methods
        Methods also run on the DataSF-buildings map (when its tiles are given).
    write_imu
        Sessions also get ``imu.csv`` (slower; the runs still read ``velocity.csv``).
    smoothing_lag_s
        Curbside fused on the OSM map also keeps fixed-lag smoothed positions with this lag, scored
        as the method ``fused_smoothed`` (an offline figure; 0: off). The filter's own track is the same.
    unseen_velocity
        Curbside fused's ``unseen_velocity.mode`` everywhere (:class:`~curbside.localize.runconfig.
        UnseenVelocityConfig`; default ``auto``, its own), the checks judging it; version 0.1's fused
        filter, the IPIN baseline, stays as it was.
    gnss
        The simulated walks' GNSS error model (:data:`~curbside.evaluate.gnss_model.GNSS_MODELS`):
        ``canyon`` (the default, the one issue 9 is scored on) or ``persistent`` (the same error sizes,
        errors that last as long as a phone's; the same walks and velocities).
    """

    profile: str = "phone"
    split: str = "test"
    subsets: tuple[str, ...] = SUBSETS
    seeds: int = 3
    downtown_routes: int = DEFAULT_ROUTES["downtown"]
    open_routes: int = DEFAULT_ROUTES["open"]
    jaywalk_weight: float = 0.4
    sweep_weights: tuple[float, ...] = (0.0, 0.4, 1.0)
    sweep_subsets: tuple[str, ...] = ("paper6",)
    particles: int = 500
    fused_particles: int = FilterConfig().n_particles
    filter_seed: int = 0
    filter_seeds: int = 1
    velocity_source: str = "auto"
    datasf_methods: tuple[str, ...] = ("paper", "fused")
    write_imu: bool = False
    smoothing_lag_s: float = 0.0
    unseen_velocity: str = UnseenVelocityConfig().mode
    gnss: str = "canyon"

    def __post_init__(self) -> None:
        GnssErrorModel.named(self.gnss)  # an unknown name is a one-line input error
        if self.profile not in PROFILES:
            raise CurbsideInputError(
                "--profile", f"unknown profile {self.profile!r}; one of {list(PROFILES)}"
            )
        if self.split not in SPLITS:
            raise CurbsideInputError("--split", f"unknown split {self.split!r}; one of {list(SPLITS)}")
        if not self.subsets:
            raise CurbsideInputError("--subsets", "need at least one subset")
        if self.filter_seeds < 1:
            raise CurbsideInputError("--filter-seeds", f"need at least 1, got {self.filter_seeds}")
        if self.unseen_velocity not in UNSEEN_VELOCITY_MODES:
            mode, known = self.unseen_velocity, list(UNSEEN_VELOCITY_MODES)
            raise CurbsideInputError("--unseen-velocity", f"unknown mode {mode!r}; one of {known}")
        for subset in self.subsets:
            if subset not in SUBSETS:
                raise CurbsideInputError("--subsets", f"unknown subset {subset!r}; one of {list(SUBSETS)}")

    def overrides_of(self, method: str, smooth: bool = False) -> tuple[tuple[str, object], ...]:
        """``method``'s run-configuration overrides: the ``--unseen-velocity`` mode for curbside fused
        when it is not its default, and the smoother's lag (``smooth``)."""
        overrides: dict[str, object] = {}
        if self.unseen_velocity != UnseenVelocityConfig().mode and method == "fused":
            overrides["unseen_velocity.mode"] = self.unseen_velocity
        if smooth:
            overrides["filter.smoother.lag_s"] = self.smoothing_lag_s
        return tuple(sorted(overrides.items()))

    def simulation(self) -> SimulationConfig:
        """The simulator's configuration of the suite's walks."""
        return SimulationConfig(profile=self.profile, gnss=GnssErrorModel.named(self.gnss),
                                write_imu=self.write_imu)

    def particles_of(self, method: str) -> int:
        """``method``'s particle count."""
        return self.fused_particles if method == "fused" else self.particles

    def routes_of(self, subset: str) -> int | None:
        """Route count of a random subset (``None`` for ``paper6``)."""
        return {"downtown": self.downtown_routes, "open": self.open_routes}.get(subset)


def plan_suite(sessions: dict[str, list[Path]], maps: dict[str, str], config: SuiteConfig) -> list[RunSpec]:
    """The runs of a benchmark (see the module docstring); the first ``paper6`` session keeps
    particle snapshots (Fig. 3)."""
    w0 = config.jaywalk_weight
    metrics_map = maps[OSM_MAP]
    specs: list[RunSpec] = []
    snap_done = False
    for subset, paths in sessions.items():
        weights = sorted(set(config.sweep_weights) | {w0}) if subset in config.sweep_subsets else [w0]
        for path in paths:
            session = str(path)
            snaps: tuple[float, ...] = ()
            if not snap_done and subset == config.subsets[0]:
                snaps, snap_done = snapshot_times(read_session(path)), True
            specs.append(
                RunSpec(
                    session,
                    "gnss",
                    None,
                    OSM_MAP,
                    metrics_map,
                    w0,
                    config.particles,
                    None,
                    config.filter_seed,
                )
            )
            for method in SUITE_METHODS[1:]:
                for w in weights:
                    smooth = method == "fused" and w == w0 and config.smoothing_lag_s > 0
                    overrides = config.overrides_of(method, smooth)
                    specs.append(
                        RunSpec(
                            session,
                            method,
                            maps[OSM_MAP],
                            OSM_MAP,
                            metrics_map,
                            w,
                            config.particles_of(method),
                            None,
                            config.filter_seed,
                            snaps if w == w0 else (),
                            config.velocity_source,
                            overrides,
                        )
                    )
            if DATASF_MAP in maps:
                for method in config.datasf_methods:
                    specs.append(
                        RunSpec(
                            session,
                            method,
                            maps[DATASF_MAP],
                            DATASF_MAP,
                            metrics_map,
                            w0,
                            config.particles_of(method),
                            None,
                            config.filter_seed,
                            (),
                            config.velocity_source,
                            config.overrides_of(method),
                        )
                    )
    more_seeds = range(config.filter_seed + 1, config.filter_seed + config.filter_seeds)
    filters = [spec for spec in specs if spec.method != "gnss"]
    specs += [replace(spec, seed=seed, snapshot_times=()) for seed in more_seeds for spec in filters]
    return specs


def pooled_by_subset(results: list[dict[str, Any]], extra: tuple[str, ...] = ()) -> pd.DataFrame:
    """Metrics pooled per subset, map, method and w (and ``extra`` columns, e.g. ``session``)."""
    frames = []
    by = ("map", "method", "jaywalk_weight", *extra)
    for subset in dict.fromkeys(subset_of(r) for r in results):
        part = pool([r for r in results if subset_of(r) == subset], by)
        part.insert(0, "subset", subset)
        frames.append(part)
    return pd.concat(frames, ignore_index=True)


def _git_commit() -> str | None:
    try:
        out = subprocess.run(
            ["git", "rev-parse", "HEAD"],
            cwd=Path(curbside.__file__).parent,
            capture_output=True,
            text=True,
            timeout=10,
            check=False,
        )
    except OSError:
        return None
    return out.stdout.strip() or None


def _run_info(
    config: SuiteConfig, maps: dict[str, str], specs: list[RunSpec], sessions: dict[str, list[Path]],
    datasf_tiles: list[str | Path] | None, ipin: str | Path | None, ipin_ronin: str | Path | None,
    workers: int, scheduler: str | None,
) -> dict[str, Any]:
    """What ``run.json`` records: versions, parameters, machine, every run, then :func:`run_suite`'s other
    inputs."""
    return {
        "generator": f"curbside {curbside.__version__}",
        "git_commit": _git_commit(),
        "suite": asdict(config),
        "simulation": config.simulation().as_dict(),
        "maps": maps,
        "machine": {
            "cpus": os.cpu_count(),
            "platform": platform.platform(),
            "python": platform.python_version(),
        },
        "runs": [asdict(s) for s in specs],
        "sessions": {k: [p.name for p in v] for k, v in sessions.items()},
        "datasf_tiles": [str(t) for t in datasf_tiles or []],
        **ipin_info(ipin, ipin_ronin),
        "workers": workers,
        "scheduler": scheduler,
    }


def simulate_suite(
    out_dir: str | Path, config: SuiteConfig, osm_file: str | Path | None = None
) -> dict[str, list[Path]]:
    """Simulate (or reuse) every session of a benchmark into ``out_dir/sessions/<profile>/<split>/``
    (``<profile>-<gnss>`` for another GNSS model than ``canyon``).

    Returns
    -------
    dict
        Session folders per subset.
    """
    world = load_world(str(osm_file) if osm_file else None)
    models = config.profile if config.gnss == "canyon" else f"{config.profile}-{config.gnss}"
    root = Path(out_dir) / "sessions" / models / config.split
    return {
        subset: benchmark_sessions(
            root / subset,
            subset,
            config.split,
            seeds=config.seeds,
            n_routes=config.routes_of(subset),
            world=world,
            config=config.simulation(),
        )
        for subset in config.subsets
    }


def _scores(
    results: list[dict], config: SuiteConfig, maps: dict[str, str], ipin_scores: list[IpinScores]
) -> tuple[pd.DataFrame, pd.DataFrame, list[criteria.Check]]:
    """Pooled and per-session metrics and the done-when checks of a suite's results (and of the held-out
    IPIN trials' figures, the first of ``ipin_scores``, when they were scored)."""
    pooled = pooled_by_subset(results)
    per_session = pooled_by_subset(results, ("session",))
    datasf = DATASF_MAP if DATASF_MAP in maps else None
    ipin_summary = ipin_scores[0].summary if ipin_scores else None
    ipin_fused = ipin_summary["fused"] if ipin_summary else None
    ipin_baseline = ipin_summary.get(criteria.IPIN_BASELINE_RUN) if ipin_summary else None
    checks = criteria.done_when(
        pooled, per_session, config.jaywalk_weight, OSM_MAP, datasf, ipin_fused, ipin_baseline=ipin_baseline
    )
    return pooled, per_session, checks


def _maps_and_sessions(
    out_dir: Path,
    config: SuiteConfig,
    map_path: str | Path | None,
    datasf_tiles: list[str | Path] | None,
    osm_file: str | Path | None,
    overwrite: bool,
    timings: dict[str, float],
) -> tuple[dict[str, str], dict[str, list[Path]]]:
    """:func:`run_suite`'s maps and sessions, built (or reused) in ``out_dir`` once the given map reads
    (the folder is created only then); their seconds go into ``timings``."""
    if map_path is not None:
        if not Path(map_path).is_file():
            raise CurbsideInputError(map_path, "no such map file")
        check_map_area(map_path, read_map(map_path))  # a bad map fails now, not after the walks
    with folder_for_run(out_dir):
        start = time.perf_counter()
        maps = benchmark_maps(out_dir, map_path, datasf_tiles, overwrite)
        timings["maps_s"] = time.perf_counter() - start
        start = time.perf_counter()
        sessions = simulate_suite(out_dir, config, osm_file)
        timings["simulate_s"] = time.perf_counter() - start
    return maps, sessions


def _track(
    sessions: dict[str, list[Path]], maps: dict[str, str], config: SuiteConfig, workers: int,
    scheduler: str | None, timings: dict[str, float],
) -> tuple[list[RunSpec], list[dict]]:
    """:func:`run_suite`'s runs (:func:`plan_suite`) and their results, once every session is checked
    against every map; the tracking's seconds go into ``timings``."""
    # a map that misses some walks fails now, naming the map, not in the middle of the tracking
    check_sessions([s for group in sessions.values() for s in group], {p: read_map(p) for p in maps.values()})
    specs = plan_suite(sessions, maps, config)
    log.info("benchmark: %d runs over %d sessions", len(specs), sum(map(len, sessions.values())))
    start = time.perf_counter()
    results = run_all(specs, workers=workers, scheduler=scheduler)
    results += smoothed_results(results)
    timings["track_s"] = time.perf_counter() - start
    return specs, results


def _ipin_scores(
    ipin: str | Path | None, ipin_ronin: str | Path | None, config: SuiteConfig, timings: dict[str, float]
) -> list[IpinScores]:
    """:func:`~curbside.evaluate.suite_ipin.ipin_scorings` (none without ``ipin``); their seconds go into
    ``timings``."""
    if not ipin:
        return []
    start = time.perf_counter()
    scorings = ipin_scorings(ipin, ipin_ronin, config)
    timings["ipin_s"] = time.perf_counter() - start
    return scorings


def _write_report(
    results: list[dict], report_dir: Path, config: SuiteConfig, maps: dict[str, str],
    scores: tuple[pd.DataFrame, pd.DataFrame, list[criteria.Check]], run_info: dict[str, Any],
    timings: dict[str, float], ipin_scores: list[IpinScores],
) -> dict[str, Path]:
    """:func:`run_suite`'s report in ``report_dir``
    (:func:`~curbside.evaluate.suite_report.write_suite_report`): its files by name."""
    from curbside.evaluate.suite_report import write_suite_report

    start = time.perf_counter()
    layers = read_map(maps[OSM_MAP])
    tables_in = (*scores, layers, run_info, timings)
    paths = write_suite_report(results, report_dir, config, *tables_in, ipin_scores)
    log.info("report written in %.0f s", time.perf_counter() - start)
    return paths


def run_suite(
    out_dir: str | Path,
    config: SuiteConfig | None = None,
    map_path: str | Path | None = None,
    datasf_tiles: list[str | Path] | None = None,
    workers: int = 2,
    scheduler: str | None = None,
    ipin: str | Path | None = None,
    osm_file: str | Path | None = None,
    ipin_ronin: str | Path | None = None,
    overwrite: bool = False,
) -> dict[str, Path]:
    """Simulate, track, score and report a benchmark in one seeded run.

    Parameters
    ----------
    out_dir
        Gets ``map.geojson`` (unless ``map_path``), ``map-datasf.geojson`` (with ``datasf_tiles``),
        ``sessions/<profile>/<split>/<subset>/`` (reused when already simulated alike) and
        ``report/``.
    config
        What to run (:class:`SuiteConfig`).
    map_path
        An existing OSM map (default: build one from the bundled extract into ``out_dir``).
    datasf_tiles
        DataSF 2013 building tiles: adds the DataSF-buildings map (with OSM's streets and sidewalks).
    workers, scheduler
        Parallelism (:func:`curbside.evaluate.runner.run_all`).
    ipin
        ``ipin2023-t3.h5``: also score the held-out IPIN trials (real phones, no map).
    osm_file
        OSM extract for the simulator (default: the bundled one).
    ipin_ronin
        RoNIN weights never trained on IPIN (with ``ipin``): also score every trial with their velocity
        (a phone and place the model has not seen; reported, not judged by the criteria).
    overwrite
        Also write into a non-empty folder curbside did not write (:func:`check_suite_folder`); its
        ``map.geojson`` is then rebuilt, never taken for the benchmark's.

    Returns
    -------
    dict
        ``report`` and the report's files by name.
    """
    config = config or SuiteConfig()
    out_dir = check_suite_folder(out_dir, overwrite)
    timings: dict[str, float] = {}
    maps, sessions = _maps_and_sessions(out_dir, config, map_path, datasf_tiles, osm_file, overwrite, timings)
    specs, results = _track(sessions, maps, config, workers, scheduler, timings)
    ipin_scores = _ipin_scores(ipin, ipin_ronin, config, timings)
    scores = _scores(results, config, maps, ipin_scores)
    run_info = _run_info(config, maps, specs, sessions, datasf_tiles, ipin, ipin_ronin, workers, scheduler)
    paths = _write_report(results, out_dir / "report", config, maps, scores, run_info, timings, ipin_scores)
    return {"report": out_dir / "report", **paths}


def suite_summary(report_dir: str | Path) -> str:
    """A few lines per subset from a benchmark report's ``metrics.json`` (what a terminal shows)."""
    doc = json.loads((Path(report_dir) / "metrics.json").read_text(encoding="utf-8"))
    suite = doc["suite"]
    lines = [
        f"benchmark: profile {suite['profile']}, GNSS {suite.get('gnss', 'canyon')}, split {suite['split']}, "
        f"w = {suite['jaywalk_weight']:g}"
    ]
    pooled = pd.DataFrame(doc["pooled"])
    base = pooled[
        (pooled["map"] == OSM_MAP)
        & ((pooled["method"] == "gnss") | (pooled["jaywalk_weight"] == suite["jaywalk_weight"]))
    ]
    for subset, rows in base.groupby("subset", sort=False):
        n = doc["sessions_per_subset"].get(subset, "?")
        sessions = f"{subset} ({n} session{'' if n == 1 else 's'})"
        lines.append(f"  {sessions:<24} CSA  median  p90 (m)")
        for method in (*SUITE_METHODS, SMOOTHED_METHOD):
            r = rows[rows["method"] == method]
            if len(r):
                r = r.iloc[0]
                label = doc["labels"][method]
                if method == SMOOTHED_METHOD:
                    label = f"{label} {suite['smoothing_lag_s']:g} s"
                lines.append(
                    f"    {label:<22} {r['csa']:.2f}  {r['euclid_median_m']:5.1f}  {r['euclid_p90_m']:5.1f}"
                )
    lines.append(f"done when: {doc['done_when']['overall']}")
    return "\n".join(lines) + "\n"
