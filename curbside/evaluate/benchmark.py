"""The six-walk San Francisco benchmark (``sf6``) and the evaluation plans behind ``localize evaluate``.

:func:`run_benchmark` is what ``make demo`` calls: build the OSM map, simulate the six walks, run
GNSS / RoNIN+PF / GNSS+RoNIN+PF at the paper's three jaywalking weights and write the report with
the paper's tables beside the paper's numbers.
"""

from __future__ import annotations

import dataclasses
import json
import logging
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
import pandas as pd

from curbside.errors import CurbsideInputError
from curbside.evaluate.groundtruth import groundtruth_at, waypoints_xy
from curbside.evaluate.report import INTERVAL_NOTE, interval_table, write_report
from curbside.evaluate.report_tables import Table
from curbside.evaluate.runner import METHOD_LABELS, METHODS, RunSpec, run_all
from curbside.evaluate.uncertainty import waypoint_intervals
from curbside.localize.runconfig import RunConfig
from curbside.localize.session import Session, read_session
from curbside.osmseg.mapio import read_map, write_map
from curbside.projection import LocalFrame

log = logging.getLogger(__name__)

#: The paper's Table 1: length (m), crossings on crosswalks, crossings elsewhere.
PAPER_TABLE1 = {
    "path1": (628, 4, 4),
    "path2": (515, 4, 1),
    "path3": (332, 0, 2),
    "path4": (644, 2, 2),
    "path5": (467, 2, 0),
    "path6": (309, 0, 0),
}


def plan(
    sessions: list[Path],
    maps: dict[str, str],
    methods: tuple[str, ...] = METHODS,
    jaywalk_weights: tuple[float, ...] = (0.0, 0.4, 1.0),
    particles: tuple[int, ...] = (500,),
    gnss_sigma_factors: tuple[float | None, ...] = (None,),
    seed: int = 0,
    metrics_map: str | None = None,
    snapshots: bool = True,
    velocity_source: str = "auto",
) -> tuple[list[RunSpec], dict[str, Any]]:
    """The runs of an evaluation: every session x map x method, with one-at-a-time parameter sweeps.

    The base configuration is the first map, ``w = 0.4`` (or the first weight given), the first
    particle count and the first sigma factor. Each parameter list is swept with the other two held at
    their base values (Table 2 is the jaywalk-weight sweep). ``gnss`` runs once per session and map.

    Returns
    -------
    (list of RunSpec, dict)
        The runs and the base configuration.
    """
    for m in methods:
        if m not in METHODS:
            raise CurbsideInputError("--methods", f"unknown method {m!r}; one of {METHODS}")
    if not maps:
        raise CurbsideInputError("--maps", "need at least one map")
    w0 = 0.4 if 0.4 in jaywalk_weights else jaywalk_weights[0]
    n0, s0 = particles[0], gnss_sigma_factors[0]
    combos = {(w, n0, s0) for w in jaywalk_weights}
    combos |= {(w0, n, s0) for n in particles}
    combos |= {(w0, n0, s) for s in gnss_sigma_factors}
    combos_sorted = sorted(combos, key=lambda c: (c[0], c[1], -1 if c[2] is None else c[2]))
    first_map = next(iter(maps))
    metrics_map = metrics_map or maps[first_map]
    specs: list[RunSpec] = []
    for i, session in enumerate(sessions):
        snap_times: tuple[float, ...] = ()
        if snapshots and i == 0:
            snap_times = snapshot_times(read_session(session))
        for name, path in maps.items():
            for method in methods:
                if method == "gnss":
                    specs.append(RunSpec(str(session), "gnss", None, name, metrics_map, w0, n0, s0, seed))
                    continue
                for w, n, s in combos_sorted:
                    if method == "inertial" and s != s0:
                        continue  # the inertial method ignores GNSS
                    base = (w, n, s) == (w0, n0, s0) and name == first_map
                    specs.append(
                        RunSpec(
                            str(session),
                            method,
                            path,
                            name,
                            metrics_map,
                            w,
                            n,
                            s,
                            seed,
                            snap_times if base else (),
                            velocity_source,
                        )
                    )
    base_cfg = {"map": first_map, "jaywalk_weight": w0, "particles": n0, "gnss_sigma_factor": s0}
    return specs, base_cfg


def snapshot_times(session: Session) -> tuple[float, ...]:
    """Two moments worth a particle-cloud figure, like the paper's Fig. 3.

    The worst confidently-wrong GNSS fix (largest error among fixes reporting at most 25 m) and the
    waypoint (a turn) nearest to two thirds of the walk; the middle and two thirds of the walk when
    there are no fixes or waypoints.
    """
    t0, t1 = session.time_span()
    fallback = (t0 + (t1 - t0) / 2, t0 + 2 * (t1 - t0) / 3)
    if session.gnss is None or session.waypoints is None or len(session.waypoints) < 3:
        return fallback
    frame = LocalFrame.around(float(session.waypoints["lon"].iat[0]), float(session.waypoints["lat"].iat[0]))
    gnss = session.gnss[session.gnss["accuracy_m"] <= 25.0]
    if len(gnss) == 0:
        return fallback
    x, y = frame.to_xy(gnss["lon"].to_numpy(), gnss["lat"].to_numpy())
    gx, gy = groundtruth_at(session.waypoints, gnss["t"].to_numpy(), frame)
    worst = float(gnss["t"].iat[int(np.argmax(np.hypot(x - gx, y - gy)))])
    wt = session.waypoints["t"].to_numpy()[1:-1]
    turn = float(wt[np.argmin(np.abs(wt - (t0 + 2 * (t1 - t0) / 3)))])
    return tuple(sorted({worst, turn}))


def route_table(sessions: list[Path]) -> Table | None:
    """Table 1 as simulated: per route, length, crosswalk crossings and jaywalks beside the paper's."""
    seen: dict[str, dict] = {}
    for s in sessions:
        meta_path = s / "meta.json"
        if meta_path.is_file():
            sim = json.loads(meta_path.read_text()).get("simulation")
            if sim and sim["route"] not in seen:
                seen[sim["route"]] = sim
    if not seen:
        return None
    rows = []
    for name, sim in seen.items():
        paper = PAPER_TABLE1.get(name, ("", "", ""))
        rows.append(
            [
                name,
                sim["area"],
                f"{sim['length_m']:.0f} ({paper[0]})",
                f"{sim['crosswalk_crossings']} ({paper[1]})",
                f"{sim['jaywalks']} ({paper[2]})",
                f"{100 * sim['covered_share']:.0f}%",
            ]
        )
    return Table(
        "Table 1. Simulated routes (paper)",
        ["path", "area", "length m", "crosswalk crossings", "jaywalks", "under cover"],
        rows,
    )


def datasf_osm_map(osm_map: str | Path, tiles: list[str | Path], out_path: str | Path) -> Path:
    """A third map source: DataSF 2013 building footprints with the OSM map's streets and sidewalks.

    Parameters
    ----------
    osm_map
        The automatic OSM map (its non-building layers are kept).
    tiles
        DataSF TopoJSON tiles (``osmseg import-datasf`` reads the same).
    out_path
        Where to write the combined GeoJSON.
    """
    from curbside.osmseg.datasf import read_datasf_over

    return write_map(read_datasf_over(tiles, read_map(osm_map)), out_path)


def run_benchmark(
    out_dir: str | Path,
    seeds: int = 2,
    fast: bool = True,
    workers: int = 2,
    scheduler: str | None = None,
    map_path: str | Path | None = None,
    datasf_tiles: list[str | Path] | None = None,
    profile: str = "phone",
) -> dict[str, Path]:
    """Build the map, simulate the six SF walks and write the benchmark report, from scratch.

    Parameters
    ----------
    out_dir
        Gets ``map.geojson`` (unless ``map_path``), ``sessions/`` and ``report/``.
    seeds
        Recordings per route.
    fast
        ``True``: ``velocity.csv`` input only (the demo, a few minutes on 2 cores). ``False``: also
        ``imu.csv`` in the sessions.
    workers, scheduler
        Parallelism (see :func:`curbside.evaluate.runner.run_all`).
    map_path
        An existing map to use instead of building one.
    datasf_tiles
        DataSF building tiles: adds a second map source (DataSF buildings + OSM streets and
        sidewalks) and the map-source comparison table. ``fast=False`` also sweeps the particle
        count (100, 500, 2000) and the GNSS sigma factor (default, 2).
    profile
        The inertial error profile of the simulated walks (``phone``: phone-in-hand errors;
        ``nominal``: RoNIN's published error levels).

    Returns
    -------
    dict
        ``map``, ``sessions``, ``report`` and the report files.
    """
    from curbside.evaluate.simulate import SimulationConfig, simulate_benchmark

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    if map_path is None:
        from curbside.osmseg.build import build_map

        map_path = out_dir / "map.geojson"
        log.info("building the OSM map -> %s", map_path)
        write_map(build_map(), map_path)
    map_path = Path(map_path)
    simulation = SimulationConfig(write_imu=not fast, profile=profile)
    sessions = simulate_benchmark(out_dir / "sessions", seeds, simulation)
    maps = {"osm": str(map_path)}
    if datasf_tiles:
        maps["datasf+osm"] = str(datasf_osm_map(map_path, list(datasf_tiles), out_dir / "map-datasf.geojson"))
    sweeps: dict[str, Any] = (
        {} if fast else {"particles": (500, 100, 2000), "gnss_sigma_factors": (None, 2.0)}
    )
    specs, base = plan(sessions, maps, seed=0, metrics_map=str(map_path), **sweeps)
    log.info("benchmark: %d runs over %d sessions", len(specs), len(sessions))
    results = run_all(specs, workers=workers, scheduler=scheduler)
    table1 = route_table(sessions)
    intro = (
        f"Six simulated walks in downtown San Francisco shaped like the paper's Table 1, {seeds} "
        f"recording{'' if seeds == 1 else 's'} each, tracked on the automatic OSM map. GNSS errors come "
        "from an urban-canyon model driven by OSM building heights; inertial velocity is RoNIN-like "
        f"(velocity.csv) with the '{profile}' error profile. Numbers in parentheses are the paper's "
        "(real walks, real RoNIN)."
    )
    paths = write_report(
        results,
        out_dir / "report",
        base,
        read_map(map_path),
        lead_tables=[table1] if table1 else [],
        intro=intro,
    )
    return {"map": map_path, "sessions": out_dir / "sessions", "report": out_dir / "report", **paths}


def ipin_errors(
    h5: str | Path,
    trials: int | None = None,
    seed: int = 0,
    held_out: bool = False,
    extra_runs: dict[str, RunConfig] | None = None,
    training: bool = False,
    ronin_weights: str | Path | None = None,
    methods: tuple[str, ...] = METHODS,
) -> tuple[dict[str, np.ndarray], list[dict], int]:
    """The ``methods``' errors at the surveyed IPIN 2023 waypoints (real data, no map).

    Each trial is tracked from its start pose; the estimate is interpolated at each waypoint time and
    compared with the surveyed point. All runs are scored at the same waypoints: those inside every
    run's track (the GNSS track spans only the fixes), the start waypoint excluded.

    Parameters
    ----------
    h5
        ``ipin2023-t3.h5``.
    trials
        Only the first ``trials`` trials (after ``held_out``'s selection).
    seed
        Filter seed.
    held_out
        Only the ``repetition04`` trials, which the bundled RoNIN model never saw.
    extra_runs
        More runs scored at the same waypoints, by name (e.g. a reference configuration).
    training
        Only the trials the bundled RoNIN model was trained on (not ``repetition04``): where filter
        parameters may be chosen.
    ronin_weights
        RoNIN weights (``.pt`` with its ``.json``) whose velocity every method tracks with (default: the
        bundled model). Each trial's velocity is inferred once and shared by the methods.
    methods
        The methods to run (default: all of them; ``localize evaluate --methods``), in this order,
        before ``extra_runs``.

    Returns
    -------
    (dict, list of dict, int)
        Errors (m) pooled per method; one row per trial and method (``trial, method, n_waypoints,
        median_m``, and ``held``: the waypoints whose error is at most the track's ``accuracy_m``
        there); the number of trials read.
    """
    from curbside.localize.readers.ipin import list_trials, read_trial
    from curbside.localize.ronin.data import IPIN_TEST_MARK
    from curbside.localize.ronin.infer import load_model

    names = [
        n for n in list_trials(h5)
        if (not held_out or IPIN_TEST_MARK in n) and not (training and IPIN_TEST_MARK in n)
    ][: trials or None]
    runs = {m: RunConfig.for_mode(m) for m in methods} | dict(extra_runs or {})
    model = load_model(ronin_weights)
    errors: dict[str, list[np.ndarray]] = {m: [] for m in runs}
    rows = []
    for name in names:
        session = read_trial(h5, name)
        if session.waypoints is None or len(session.waypoints) < 2:
            continue  # nothing to score: no RoNIN inference either
        session = _with_velocity(session, model)
        if session is None:
            continue
        tracks = _track_every_run(session, runs, seed, name)
        if len(tracks) < len(runs):
            continue
        for method, (e, radius) in _waypoint_errors(session.waypoints, tracks).items():
            errors[method].append(e)
            median = float(np.median(e)) if len(e) else None
            rows.append({"trial": name, "method": method, "n_waypoints": len(e), "median_m": median,
                         "held": int(np.sum(e <= radius))})
    pooled = {m: np.concatenate(v) if v else np.array([]) for m, v in errors.items()}
    return pooled, rows, len(names)


def _waypoint_errors(
    waypoints: pd.DataFrame, tracks: dict[str, Any]
) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Each track's error (m) at the same surveyed waypoints, those inside every track's span, the start
    one excluded, and its ``accuracy_m`` there (NaN where the track has none)."""
    frame = LocalFrame.around(float(waypoints["lon"].iat[0]), float(waypoints["lat"].iat[0]))
    wt, wx, wy = waypoints_xy(waypoints, frame)
    common = np.arange(len(wt)) > 0
    for track in tracks.values():
        common &= (wt >= track["t"].iat[0]) & (wt <= track["t"].iat[-1])
    errors = {}
    for method, track in tracks.items():
        x, y = frame.to_xy(track["lon"].to_numpy(), track["lat"].to_numpy())
        t = track["t"].to_numpy()
        dx, dy = np.interp(wt[common], t, x) - wx[common], np.interp(wt[common], t, y) - wy[common]
        radius = track["accuracy_m"].to_numpy(float) if "accuracy_m" in track else np.full(len(t), np.nan)
        errors[method] = np.hypot(dx, dy), np.interp(wt[common], t, radius)
    return errors


def _with_velocity(session: Session, model: Any) -> Session | None:
    """The trial with its RoNIN velocity from ``model`` (``None``, logged, when it has none)."""
    from curbside.localize.ronin.infer import ronin_velocity

    if session.imu is None:
        return session
    try:
        velocity = ronin_velocity(session.imu, model, source=f"{session.name}/imu.csv")
    except CurbsideInputError as exc:
        log.warning("IPIN %s skipped: %s", session.name, exc)
        return None
    return dataclasses.replace(session, velocity=velocity)


def _track_every_run(session: Session, runs: dict[str, RunConfig], seed: int, name: str) -> dict[str, Any]:
    """Each run's track of an IPIN trial (no map); a run the trial cannot start is logged and left out."""
    from curbside.localize.pipeline import track_session

    tracks = {}
    for method, config in runs.items():
        try:
            track = track_session(session, None, config=config, seed=seed).track
        except CurbsideInputError as exc:
            log.warning("IPIN %s %s skipped: %s", name, method, exc)
            continue
        if len(track) >= 2:
            tracks[method] = track
    return tracks


def ipin_table(
    h5: str | Path, trials: int | None = None, seed: int = 0, held_out: bool = False,
    methods: tuple[str, ...] = METHODS,
) -> tuple[list[Table], list[dict]]:
    """Real data without a map: the ``methods`` (default: all) at the surveyed IPIN 2023 waypoints
    (:func:`ipin_errors`), then, when curbside fused is among them and a trial was scored, curbside fused
    against those of the paper's method and GNSS alone that ran, with trial-bootstrap intervals."""
    errors, rows, n_trials = ipin_errors(h5, trials, seed, held_out, methods=methods)
    tables = [ipin_errors_table(errors, n_trials, held_out, rows=rows)]
    if rows and "fused" in errors:
        baselines = tuple(m for m in ("paper", "gnss") if m in errors)
        intervals = waypoint_intervals(errors, rows, "fused", baselines, seed=seed)
        tables.append(ipin_interval_table(intervals, "IPIN 2023: how sure (m)"))
    return tables, rows


class IpinScores(NamedTuple):
    """One scoring of the IPIN trials in a benchmark report.

    Attributes
    ----------
    key, intervals_key
        Its ``metrics.json`` keys: of the pooled figures and of the intervals.
    summary
        ``{method: {"n", "median_m", "p90_m"}}`` pooled over trials and filter seeds.
    table
        The errors table (:func:`ipin_errors_table`).
    intervals
        Trial-bootstrap intervals of curbside fused and its differences (empty when no trial scored).
    sure_title
        Title of the intervals' table.
    """

    key: str
    intervals_key: str
    summary: dict[str, dict[str, float]]
    table: Table
    intervals: pd.DataFrame
    sure_title: str

    def tables(self) -> list[Table]:
        """The errors table and, when a trial was scored, the "how sure" table."""
        if self.intervals.empty:
            return [self.table]
        return [self.table, ipin_interval_table(self.intervals, self.sure_title)]


def ipin_interval_table(intervals: pd.DataFrame, title: str) -> Table:
    """The IPIN trials' "how sure" table: curbside fused and its paired differences."""
    fused = intervals[intervals["method"].str.startswith("fused")]
    return interval_table(fused, title, INTERVAL_NOTE.format(unit="trials", points="waypoints", one="trial"))


def accuracy_held(rows: list[dict]) -> dict[str, float]:
    """Per method, the share of scored waypoints within the track's ``accuracy_m`` (:func:`ipin_errors`'
    rows; methods without a ``held`` count or a waypoint are left out)."""
    frame = pd.DataFrame([r for r in rows if r.get("held") is not None and r["n_waypoints"]])
    if frame.empty:
        return {}
    sums = frame.groupby("method", sort=False)[["held", "n_waypoints"]].sum()
    return (sums["held"] / sums["n_waypoints"]).to_dict()


def trials_above_gnss(rows: list[dict]) -> dict[str, tuple[int, int]]:
    """Per method of :func:`ipin_errors`' ``rows`` (one filter seed's, or several seeds' in turn): in how
    many trial runs its median error exceeds GNSS alone's on the same run, and how many it was scored
    in (a trial scored once per seed). GNSS itself is left out."""
    frame = pd.DataFrame(rows, columns=["trial", "method", "n_waypoints", "median_m"])
    frame["run"] = frame.groupby(["trial", "method"]).cumcount()  # the filter seed, in order
    medians = frame.pivot_table(index=["trial", "run"], columns="method", values="median_m", dropna=False)
    if "gnss" not in medians:
        return {}
    gnss = medians["gnss"]
    scored = gnss.notna()
    return {
        m: (int((medians[m][scored] > gnss[scored]).sum()), int(medians[m][scored].notna().sum()))
        for m in medians.columns
        if m != "gnss"
    }


def ipin_errors_table(
    errors: dict[str, np.ndarray],
    n_trials: int,
    held_out: bool = False,
    seeds: int = 1,
    ronin_weights: str | Path | None = None,
    rows: list[dict] | None = None,
) -> Table:
    """The table of :func:`ipin_errors`' pooled errors: waypoints, median, p90 and mean per run, and
    with its ``rows``, the trial runs whose median is above GNSS alone's (:func:`trials_above_gnss`; a
    column only when GNSS alone ran) (``seeds``: how many filter seeds the errors pool, each scoring
    every waypoint once; ``ronin_weights``: the RoNIN model the methods tracked with, when not the
    bundled one)."""
    above = trials_above_gnss(rows or [])
    held = accuracy_held(rows or [])
    with_gnss = "gnss" in errors
    table_rows = []
    for m, e in errors.items():
        worse, scored = above.get(m, (0, 0))
        table_rows.append(
            [
                METHOD_LABELS.get(m, m),
                str(len(e)),
                f"{np.median(e):.1f}" if len(e) else "n/a",
                f"{np.percentile(e, 90):.1f}" if len(e) else "n/a",
                f"{e.mean():.1f}" if len(e) else "n/a",
                *([f"{worse} of {scored}" if scored else "–"] if with_gnss else []),
                f"{held[m]:.2f}" if m in held else "n/a",
            ]
        )
    which = "held-out " if held_out else ""
    pooled = f" x {seeds} filter seeds" if seeds > 1 else ""
    model, note = "", ""
    if above:
        note = ("Trials above GNSS: trial runs (a trial at one filter seed) whose median error exceeds "
                "GNSS alone's on the same run, of those scored. ")
    if held:
        gnss_radius = " (for GNSS alone the phone's reported accuracy)" if with_gnss else ""
        note += ("accuracy_m held: the share of waypoints within the track's accuracy_m, the radius that "
                 f"should hold the walker 68 % of the time{gnss_radius}. ")
    if ronin_weights:
        model = f", RoNIN {Path(ronin_weights).name}"
        note += (f"Every method tracks with the velocity of {Path(ronin_weights).name}, a RoNIN model that "
                "was not trained on these trials: the case of a phone and a place the model has not seen. "
                "Reported beside the done-when checks, which use the bundled model on the held-out trials.")
    return Table(
        f"IPIN 2023 Track 3 ({n_trials} {which}trials{pooled}, no map{model}): "
        "error at surveyed waypoints (m)",
        ["method", "waypoints", "median", "p90", "mean", *(["trials above GNSS"] if with_gnss else []),
         "accuracy_m held"],
        table_rows,
        note,
    )
