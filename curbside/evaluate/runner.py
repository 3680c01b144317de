"""Run the paper's three methods over many sessions, maps and parameters, in parallel with dask.

One :class:`RunSpec` is one track: a session, a map, a method and the filter parameters. A run
reads its inputs itself (sessions and maps are paths, so a task is small to ship to a worker), tracks
with :func:`curbside.localize.pipeline.track_session`, and scores every footstep against the ground
truth (:mod:`curbside.evaluate.metrics`). Each run is seeded, so the results do not depend on which
worker ran what: a dask run equals a serial one.

Every run is scored twice: on the paper's estimate (the weighted mean of the particles; the SPEC metric
names) and on the posterior-mode estimate (the weighted mean of the particles on the MAP sidewalk
segment, ``track.csv``'s ``mode_lat, mode_lon``; the same names with :data:`MODE_SUFFIX`). Without
particles (``gnss``) or without sidewalks in the filter's map both estimates are the same.
"""

from __future__ import annotations

import contextlib
import functools
import logging
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pyproj
from tqdm.auto import tqdm

from curbside.errors import CurbsideInputError
from curbside.evaluate import dask_cluster, metrics
from curbside.evaluate.groundtruth import groundtruth_at
from curbside.localize.particle_store import select_footsteps, unpack_particles
from curbside.localize.runconstants import MODES
from curbside.localize.session import Session, read_session
from curbside.osmseg.mapio import MapLayers, read_map
from curbside.projection import LocalFrame

log = logging.getLogger(__name__)

METHODS: tuple[str, ...] = MODES
#: Report names of the methods: the paper's for its three, "paper PF" for the paper's GNSS+RoNIN+PF
#: re-implemented plainly (``track_session``'s ``paper`` mode), "curbside fused" for ours.
METHOD_LABELS: dict[str, str] = {
    "gnss": "GNSS",
    "inertial": "RoNIN+PF",
    "paper": "paper PF",
    "fused": "curbside fused",
    "fused_smoothed": "fused, smoothed",
}
#: The pseudo-method of :func:`smoothed_results`: curbside fused's fixed-lag smoothed positions (offline).
SMOOTHED_METHOD = "fused_smoothed"
#: Suffix of the metrics scored on the posterior-mode estimate (``csa_mode``...).
MODE_SUFFIX = "_mode"


@dataclass(frozen=True)
class RunSpec:
    """One track to compute and score.

    Attributes
    ----------
    session
        Session folder.
    method
        ``gnss``, ``inertial``, ``paper`` or ``fused``.
    map_path
        Map used by the filter (``None``: no map likelihood; always ``None`` for ``gnss``).
    map_name
        Label of the map source in reports.
    metrics_map
        Map whose sidewalk segments score the run (``None``: distances only).
    jaywalk_weight, particles, gnss_sigma_factor
        Filter parameters (``gnss_sigma_factor`` ``None``: the filter's default).
    seed
        Filter seed.
    snapshot_times
        Times (s) at which to keep the particle cloud (Fig. 3); empty for none.
    velocity_source
        ``auto``, ``file``, ``ronin`` or ``pdr``.
    overrides
        Further ``(key, value)`` overrides of the run configuration (``filter.gnss.sigma_factor``...; see
        :meth:`curbside.localize.runconfig.RunConfig.with_overrides`), for sweeps and tuning.
    """

    session: str
    method: str
    map_path: str | None = None
    map_name: str = "none"
    metrics_map: str | None = None
    jaywalk_weight: float = 0.4
    particles: int = 500
    gnss_sigma_factor: float | None = None
    seed: int = 0
    snapshot_times: tuple[float, ...] = ()
    velocity_source: str = "auto"
    overrides: tuple[tuple[str, Any], ...] = ()

    def key(self) -> dict[str, Any]:
        """The grouping columns of this run."""
        return {
            "map": self.map_name,
            "method": self.method,
            "jaywalk_weight": self.jaywalk_weight,
            "particles": self.particles,
            "gnss_sigma_factor": self.gnss_sigma_factor,
        }


@functools.lru_cache(maxsize=8)
def _map(path: str) -> MapLayers:
    return read_map(path)


@functools.lru_cache(maxsize=8)
def _index(path: str) -> metrics.SidewalkIndex:
    return metrics.SidewalkIndex.from_layers(_map(path))


def run_one(spec: RunSpec) -> dict[str, Any]:
    """Track and score one :class:`RunSpec` (the unit of work sent to dask workers).

    Returns
    -------
    dict
        ``spec`` (dict), ``path`` (route name), ``metrics`` (SPEC names), ``ate_m``, ``rte_m``,
        ``errors`` (per-footstep DataFrame), ``metrics_mode`` and ``errors_mode`` (the same for the
        posterior-mode estimate, with the run's ``segment_prob`` beside each footstep),
        ``metrics_smoothed`` and ``errors_smoothed`` (the same for the fixed-lag smoother's positions;
        ``None`` without ``filter.smoother.lag_s``), ``track`` (``t, x_m, y_m, gt_x_m, gt_y_m``),
        ``snapshots`` (list of ``{"t", "x", "y"}`` clouds), ``recoveries``, ``velocity_source``.
    """
    from curbside.localize.pipeline import resolve_config, track_session

    session = read_session(spec.session)
    if session.waypoints is None:
        raise CurbsideInputError(spec.session, "no waypoints.csv: nothing to score against")
    layers = _map(spec.map_path) if spec.map_path and spec.method != "gnss" else None
    overrides = dict(spec.overrides)
    if spec.gnss_sigma_factor is not None:
        overrides["filter.gnss.sigma_factor"] = float(spec.gnss_sigma_factor)
    config = resolve_config(None, spec.method, particles=spec.particles, jaywalk_weight=spec.jaywalk_weight,
                            seed=spec.seed, velocity_source=spec.velocity_source).with_overrides(overrides)
    result = track_session(session, layers, config=config, map_name=spec.map_path,
                           save_particles=bool(spec.snapshot_times) and spec.method != "gnss")
    track = result.track
    if spec.metrics_map:
        frame = LocalFrame(pyproj.CRS(_map(spec.metrics_map).crs))
    else:
        frame = LocalFrame.around(
            float(session.waypoints["lon"].iat[0]), float(session.waypoints["lat"].iat[0])
        )
    ex, ey = frame.to_xy(track["lon"].to_numpy(), track["lat"].to_numpy())
    t = track["t"].to_numpy(float)
    gx, gy = groundtruth_at(session.waypoints, t, frame)
    est = np.column_stack([ex, ey])
    gt = np.column_stack([gx, gy])
    index = _index(spec.metrics_map) if spec.metrics_map else None
    errors = metrics.step_errors(est, gt, index)
    if "accuracy_m" in track:
        errors["accuracy_m"] = track["accuracy_m"].to_numpy(float)  # see evaluate.confidence
    errors_mode = errors
    if "mode_lat" in track:
        errors_mode = _errors_at(track, "mode", frame, gt, index)
        errors_mode["segment_prob"] = track["segment_prob"].to_numpy(float)  # see evaluate.confidence
    errors_smoothed = _errors_at(track, "smooth", frame, gt, index) if "smooth_lat" in track else None
    snapshots = _clouds_at(spec, result.snapshots, session, layers, frame) if spec.snapshot_times else []
    sim = session.meta.get("simulation", {}) if isinstance(session.meta, dict) else {}
    return {
        "spec": asdict(spec),
        "session": Path(spec.session).name,
        "path": sim.get("route", Path(spec.session).name),
        "metrics": metrics.summarize(errors),
        "ate_m": metrics.ate_m(est, gt),
        "rte_m": metrics.rte_m(t, est, gt),
        "errors": errors,
        "metrics_mode": metrics.summarize(errors_mode),
        "errors_mode": errors_mode,
        "metrics_smoothed": None if errors_smoothed is None else metrics.summarize(errors_smoothed),
        "errors_smoothed": errors_smoothed,
        "track": pd.DataFrame({"t": t, "x_m": ex, "y_m": ey, "gt_x_m": gx, "gt_y_m": gy}),
        "snapshots": snapshots,
        "recoveries": int(result.recoveries),
        "velocity_source": result.velocity_source,
    }


def check_sessions(
    sessions: list[Path], maps: dict[str, MapLayers], methods: tuple[str, ...] = METHODS
) -> None:
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

    configs = [resolve_config(None, method) for method in methods]
    for folder in sessions:
        session = read_session(folder, kinds=("gnss", "waypoints"))
        waypoints = Path(folder) / "waypoints.csv"
        if session.waypoints is None:
            raise CurbsideInputError(waypoints, "missing: no ground truth to score the session against")
        if len(session.waypoints) < 2:
            raise CurbsideInputError(
                waypoints, f"ground truth needs at least two waypoints; it holds {len(session.waypoints)}"
            )
        for path, layers in maps.items():
            for config in configs:
                check_on_map(session, layers, config, map_name=path)


def _clouds_at(
    spec: RunSpec, snap: dict | None, session: Session, layers: MapLayers | None, frame: LocalFrame
) -> list[dict[str, Any]]:
    """The particle clouds nearest ``spec.snapshot_times``, in the metrics frame, with the fix then."""
    if snap is None:
        return []
    t_s = np.asarray(snap["t"], np.float64)
    nearest = [int(np.argmin(np.abs(t_s - want))) for want in spec.snapshot_times]
    # Only these footsteps are unpacked: all of a 59-min walk's at N = 2000 took 2 s and 620 MB.
    stored = unpack_particles(select_footsteps(snap, nearest))
    clouds = []
    for t, px, py in zip(stored.t.tolist(), stored.x, stored.y, strict=True):
        if layers is not None and spec.metrics_map and _map(spec.metrics_map).crs != layers.crs:
            lon, lat = LocalFrame(pyproj.CRS(layers.crs)).to_lonlat(px, py)
            px, py = frame.to_xy(lon, lat)
        clouds.append({"t": t, "x": np.asarray(px, np.float32), "y": np.asarray(py, np.float32),
                       "fix": _fix_at(session.gnss, t, frame)})
    return clouds


def smoothed_results(results: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Each fused run that kept fixed-lag smoothed positions, as a run of :data:`SMOOTHED_METHOD`.

    The copies score the smoothed positions (``errors``, ``metrics``) and pool like any method's runs.
    """
    out = []
    for r in results:
        if r["spec"]["method"] == "fused" and r.get("errors_smoothed") is not None:
            errors, summary = r["errors_smoothed"], r["metrics_smoothed"]
            out.append({**r, "spec": {**r["spec"], "method": SMOOTHED_METHOD}, "errors": errors,
                        "metrics": summary, "errors_mode": errors, "metrics_mode": summary, "snapshots": []})
    return out


def _errors_at(
    track: pd.DataFrame, prefix: str, frame: LocalFrame, gt: np.ndarray, index: metrics.SidewalkIndex | None
) -> pd.DataFrame:
    """Per-footstep errors of the track's ``{prefix}_lat, {prefix}_lon`` columns."""
    x, y = frame.to_xy(track[f"{prefix}_lon"].to_numpy(), track[f"{prefix}_lat"].to_numpy())
    return metrics.step_errors(np.column_stack([x, y]), gt, index)


def _fix_at(gnss: pd.DataFrame | None, t: float, frame: LocalFrame) -> tuple[float, float, float] | None:
    """The latest GNSS fix at or before ``t`` as ``(x, y, accuracy_m)`` in ``frame``."""
    if gnss is None or len(gnss) == 0:
        return None
    i = int(np.searchsorted(gnss["t"].to_numpy(), t, side="right")) - 1
    if i < 0:
        return None
    x, y = frame.to_xy(gnss["lon"].iat[i], gnss["lat"].iat[i])
    return float(x), float(y), float(gnss["accuracy_m"].iat[i])


def run_all(
    specs: list[RunSpec],
    workers: int = 1,
    scheduler: str | None = None,
    progress: bool | None = None,
) -> list[dict[str, Any]]:
    """Run many specs, serially or on a dask.distributed cluster; results come back in ``specs`` order.

    Parameters
    ----------
    specs
        The runs.
    workers
        Worker processes of a local cluster; ``1`` (and no ``scheduler``) runs serially in-process.
    scheduler
        Address of an existing dask scheduler (``tcp://host:8786``); overrides ``workers``.
    progress
        tqdm bar (``None``: only on a terminal).

    Returns
    -------
    list of dict
        :func:`run_one` outputs.

    Raises
    ------
    CurbsideInputError
        Naming ``--scheduler`` when no dask scheduler answers at ``scheduler`` within
        :data:`curbside.evaluate.dask_cluster.SCHEDULER_TIMEOUT_S`.
    KeyboardInterrupt
        On Ctrl-C, at any moment, the local cluster's start-up included: the runs are cancelled and the
        local workers killed first (:func:`curbside.evaluate.dask_cluster.kill_cluster`), within a second
        or two. A run that raises stops the others the same way before its error propagates.
    """
    disable = (not progress) if progress is not None else None
    if scheduler is None and workers <= 1:
        return [run_one(s) for s in tqdm(specs, desc="evaluate", unit="run", disable=disable)]
    from dask.distributed import Client, as_completed

    cluster = dask_cluster.start_local_cluster(workers) if scheduler is None else None
    client, futures, stopped, interrupted = None, [], False, False
    try:
        if cluster is None:
            client = dask_cluster.connect(scheduler)
        else:
            client = Client(cluster)
            client.run(dask_cluster.quiet_heartbeat_at_shutdown)
        futures = client.map(run_one, specs, pure=False)
        order = {f.key: i for i, f in enumerate(futures)}
        out: list[dict[str, Any] | None] = [None] * len(specs)
        for future in tqdm(
            as_completed(futures), total=len(futures), desc="evaluate", unit="run", disable=disable
        ):
            out[order[future.key]] = future.result()
        return out  # type: ignore[return-value]
    except BaseException as exc:  # Ctrl-C, or a run that failed: the other runs are of no use now
        stopped, interrupted = True, isinstance(exc, KeyboardInterrupt)
        raise
    finally:
        # a second Ctrl-C waits for this
        with dask_cluster.ctrl_c_blocked() if interrupted else contextlib.nullcontext():
            if stopped:
                dask_cluster.silence_distributed()
            if client is not None:
                if stopped:
                    client.cancel(futures)  # on --scheduler, the user's cluster drops them (it lives on)
                client.close()
            if cluster is not None:
                (dask_cluster.kill_cluster if stopped else dask_cluster.close_cluster)(cluster)


def subset_of(result: dict[str, Any]) -> str:
    """The group of a run: its session folder's parent folder name (a benchmark subset)."""
    return Path(result["spec"]["session"]).parent.name


def pool(results: list[dict[str, Any]], by: tuple[str, ...]) -> pd.DataFrame:
    """Metrics pooled over all footsteps of the runs sharing the ``by`` columns.

    Parameters
    ----------
    results
        :func:`run_one` outputs.
    by
        Columns among ``map, method, jaywalk_weight, particles, gnss_sigma_factor, path, session``.

    Returns
    -------
    pandas.DataFrame
        One row per group: ``by`` columns, the SPEC metrics, the same for the posterior-mode estimate
        (suffixed :data:`MODE_SUFFIX`: ``csa_mode``...), ``ate_m`` and ``rte_m`` (means over runs),
        ``n_runs``.
    """
    rows = []
    keys = [{**RunSpec(**r["spec"]).key(), "path": r["path"], "session": r["session"]} for r in results]
    frame = pd.DataFrame(keys)
    frame["gnss_sigma_factor"] = frame["gnss_sigma_factor"].astype(object)
    groups = frame.groupby(list(by), sort=False, dropna=False).indices
    for group, idx in groups.items():
        group = group if isinstance(group, tuple) else (group,)
        errs = pd.concat([results[i]["errors"] for i in idx], ignore_index=True)
        row = dict(zip(by, group, strict=True))
        row.update(metrics.summarize(errs))
        errs_mode = pd.concat([results[i].get("errors_mode", results[i]["errors"]) for i in idx],
                              ignore_index=True)
        mode = metrics.summarize(errs_mode)
        row.update({f"{name}{MODE_SUFFIX}": mode[name] for name in metrics.METRIC_NAMES})
        row["ate_m"] = float(np.nanmean([results[i]["ate_m"] for i in idx]))
        row["rte_m"] = float(np.nanmean([results[i]["rte_m"] for i in idx]))
        row["n_runs"] = len(idx)
        rows.append(row)
    return pd.DataFrame(rows)
