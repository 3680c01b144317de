"""From a recorded session to a track: choose the inputs, feed them to the engine, tabulate the estimates.

:func:`track_session` runs one of four methods (:data:`~curbside.localize.runconfig.MODES`) over a
:class:`~curbside.localize.session.Session`:

``gnss``
    the fixes at the update times (interpolated between fixes at most ``interp_max_gap_s`` apart, else
    the latest fix held, as a phone shows it; long holds are reported);
``inertial``
    inertial velocity + the map-aware particle filter, no GNSS (RoNIN+PF in the paper);
``paper``
    the paper's GNSS+RoNIN+PF, plainly (``FilterConfig.preset("paper")``): a baseline;
``fused``
    curbside's filter (GNSS+RoNIN+PF with robust fusion and recovery).

Inputs, unless the run's :class:`~curbside.localize.runconfig.EngineConfig` forces one: velocity from
``velocity.csv``, else the RoNIN model (the bundled one unless the caller gives its own) on ``imu.csv``, else
PDR; footsteps from ``steps.csv``,
else detected in ``imu.csv``, else a fixed cadence. Everything goes through
:class:`~curbside.localize.engine.SessionEngine`, the same engine the live service streams into.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pandas as pd
import pyproj
import shapely

from curbside.errors import CurbsideInputError
from curbside.localize import input_warnings
from curbside.localize.engine import Row, SessionEngine, StartPose, require_rows
from curbside.localize.filter.tracker import Tracker
from curbside.localize.fix_lag import estimate_fix_lag
from curbside.localize.raster import MapRaster, load_or_build_raster
from curbside.localize.runconfig import MODES, VELOCITY_SOURCES, RunConfig
from curbside.localize.session import Session, warn_if_simulated_imu
from curbside.localize.streams import DisplacementIntegrator
from curbside.osmseg.mapio import MapLayers
from curbside.projection import LocalFrame

if TYPE_CHECKING:
    from curbside.localize.ronin.model import RoninResNet

logger = logging.getLogger(__name__)

__all__ = ["MODES", "VELOCITY_SOURCES", "TrackResult", "track_session", "run_session"]

#: Columns of ``track.csv`` in order (:data:`SEGMENT_COLUMNS` follow when the map has sidewalks).
TRACK_COLUMNS = (
    "t",
    "lat",
    "lon",
    "x_m",
    "y_m",
    "accuracy_m",
    "update",
    "gnss_used",
    "theta_drift_deg",
    "speed_scale",
    "n_eff",
    "recovered",
    "injected",
    "motion",
)

#: Columns added with a map that has sidewalk segments: the filter's MAP segment (the polygon under the
#: estimate in ``gnss`` mode), its posterior probability (empty in ``gnss`` mode) and the mode estimate.
SEGMENT_COLUMNS = ("sidewalk_segment_id", "segment_prob", "mode_lat", "mode_lon")


@dataclass
class TrackResult:
    """The output of :func:`track_session`.

    Attributes
    ----------
    track
        One row per update: :data:`TRACK_COLUMNS` (and :data:`SEGMENT_COLUMNS` with a map with sidewalks).
    config
        The whole run configuration (``run.json``'s ``config``).
    velocity_source, step_source
        Where the velocity and the footsteps came from (``None`` for velocity in ``gnss`` mode).
    recoveries, injections, heading_corrections
        Collapses re-seeded; particles injected by the divergence recovery; re-draws of the heading
        correction (:func:`tracker_record`).
    calibration
        The calibration of ``segment_prob`` and ``accuracy_m`` at the end of the walk: the fixes'
        persistence, the temperature and the pairs it was read from (``None`` without one).
    unseen_velocity_from_s
        Time from which the filter moved with the unseen-velocity motion model (``None``: never).
    familiar_velocity
        The familiar-velocity test's record (``None`` when it did not run; see
        :attr:`~curbside.localize.engine.SessionEngine.familiar_velocity`).
    fix_lag
        The fixes' lag compensated: ``mode`` and ``lag_s``, and under ``auto`` the estimate's blocks and
        residual per candidate (``None`` with ``fix_lag.mode = off`` or without fixes to compensate).
    wall_tolerance_m
        How soft the walls were (m; ``None`` without a map): ``filter.map.wall_tolerance_m``, or
        ``conflict_wall_tolerance_m`` on a map whose buildings cover its sidewalks.
    walkable_first
        Whether the map's sidewalks and crosswalks won over its buildings (``filter.map.conflict_*``;
        ``None`` without a map).
    snapshots
        With ``save_particles``: the cloud at each update, packed as it was taken: the arrays of
        ``particles.npz`` (:mod:`curbside.localize.particle_store`; ``unpack_particles`` reads them), on
        disk (a :class:`~curbside.localize.particle_store.SpilledClouds`, read as memory maps), with
        ``weight_u8`` when the weights are not all uniform (particles killed by the map keep their place,
        with no weight, until the next resampling).
    """

    track: pd.DataFrame
    config: RunConfig
    velocity_source: str | None
    step_source: str
    recoveries: int = 0
    injections: int = 0
    snapshots: Mapping[str, np.ndarray] | None = None
    unseen_velocity_from_s: float | None = None
    wall_tolerance_m: float | None = None
    walkable_first: bool | None = None
    familiar_velocity: dict[str, object] | None = None
    fix_lag: dict[str, object] | None = None
    heading_corrections: int = 0
    calibration: dict[str, float] | None = None

    @property
    def mode(self) -> str:
        """The method run."""
        return self.config.mode


def resolve_config(
    config: RunConfig | None,
    mode: str | None,
    *,
    particles: int | None = None,
    jaywalk_weight: float | None = None,
    seed: int | None = None,
    velocity_source: str | None = None,
    use_start_pose: bool | None = None,
) -> RunConfig:
    """The run configuration from a base (default: ``mode``'s) and the common shortcuts.

    Raises
    ------
    CurbsideInputError
        Unknown mode or velocity source, or a bad value.
    """
    if mode is not None and mode not in MODES:
        raise CurbsideInputError("--mode", f"unknown mode {mode!r}; one of {MODES}")
    config = config or RunConfig.for_mode(mode or "fused")
    overrides: dict[str, object] = {}
    if mode is not None:
        overrides["mode"] = mode
    for key, value in (
        ("filter.n_particles", particles),
        ("filter.map.jaywalk_weight", jaywalk_weight),
        ("seed", seed),
        ("engine.velocity_source", velocity_source),
        ("use_start_pose", use_start_pose),
    ):
        if value is not None:
            overrides[key] = value
    return config.with_overrides(overrides)


def _frame_for(session: Session, map_layers: MapLayers | None) -> LocalFrame:
    if map_layers is not None:
        return LocalFrame(pyproj.CRS(map_layers.crs))
    start = session.start_pose
    if start is not None:
        return LocalFrame.around(start["lon"], start["lat"])
    if session.gnss is not None and len(session.gnss):
        return LocalFrame.around(float(session.gnss["lon"].median()), float(session.gnss["lat"].median()))
    raise CurbsideInputError(session.source, "no start pose in meta.json and no gnss.csv: nowhere to start")


def _start_of(session: Session) -> tuple[StartPose | None, float | None]:
    """The known start pose and the walk's start time (kept even when the pose is not used)."""
    pose = session.start_pose
    if pose is None:
        return None, None
    t = pose.get("t")
    t = float(t) if isinstance(t, int | float) else None
    try:
        start = StartPose(float(pose["lat"]), float(pose["lon"]), float(pose["heading_deg"]), t)
    except (KeyError, TypeError, ValueError):
        raise CurbsideInputError(
            session.file_source("meta.json"), "start needs numeric lat, lon, heading_deg"
        ) from None
    return start, t


def check_on_map(
    session: Session,
    map_layers: MapLayers,
    config: RunConfig | None = None,
    *,
    map_name: str | None = None,
) -> None:
    """Raise unless the session lies on the map: the check :func:`track_session` makes first, before any
    warning about its inputs.

    Parameters
    ----------
    session
        The recording (its ``gnss.csv`` and ``meta.json`` start pose are checked).
    map_layers
        The map.
    config
        The run's configuration (whether it uses the start pose; the extent tolerance); default
        :class:`RunConfig`'s.
    map_name
        How messages name the map (default "the map"; the session is named by its ``source``).

    Raises
    ------
    CurbsideInputError
        A start pose outside the map's extent, or no fix near it.
    """
    config = config or RunConfig()
    start, _ = _start_of(session)
    pose = start if config.use_start_pose else None
    _check_extent(session, map_layers, _frame_for(session, map_layers), pose,
                  config.engine.extent_tolerance_m, map_name=map_name)


def _check_inputs(
    session: Session, map_layers: MapLayers | None, config: RunConfig, frame: LocalFrame,
    start: StartPose | None, map_name: str | None,
) -> None:
    """Refuse a session off the map, then warn about weak inputs: a refusal comes alone, not after a
    warning about a run that never happens."""
    if map_layers is not None:
        pose = start if config.use_start_pose else None
        _check_extent(session, map_layers, frame, pose, config.engine.extent_tolerance_m, map_name=map_name)
    input_warnings.report_unanchored_inertial(session, config, start)
    input_warnings.report_unusable_fixes(session)


def _check_extent(
    session: Session, layers: MapLayers, frame: LocalFrame, start: StartPose | None, tolerance_m: float,
    *, map_name: str | None = None,
) -> None:
    where = f" ({map_name})" if map_name else ""
    xmin, ymin, xmax, ymax = layers.gdf.total_bounds
    if start is not None:
        x, y = frame.to_xy(start.lon, start.lat)
        if not (xmin <= x <= xmax and ymin <= y <= ymax):
            raise CurbsideInputError(
                session.file_source("meta.json"),
                f"start pose ({start.lat:.6f}, {start.lon:.6f}) lies outside the map's extent{where}",
            )
    gnss = session.gnss
    if gnss is not None and len(gnss):
        fx, fy = frame.to_xy(gnss["lon"].to_numpy(float), gnss["lat"].to_numpy(float))
        tol = tolerance_m
        near = (fx > xmin - tol) & (fx < xmax + tol) & (fy > ymin - tol) & (fy < ymax + tol)
        if not np.any(near):
            raise CurbsideInputError(
                session.file_source("gnss.csv"),
                f"the session lies outside the map's extent{where} (no fix near the map)",
            )


def valid_fixes(gnss: pd.DataFrame | None, frame: LocalFrame) -> tuple[np.ndarray, ...]:
    """``t, x, y, accuracy_m`` of the fixes with a valid accuracy (positive and finite), in ``frame``."""
    if gnss is None or len(gnss) == 0:
        return (np.empty(0),) * 4
    acc = gnss["accuracy_m"].to_numpy(float)
    ok = np.isfinite(acc) & (acc > 0)
    x, y = frame.to_xy(gnss["lon"].to_numpy(float)[ok], gnss["lat"].to_numpy(float)[ok])
    return gnss["t"].to_numpy(float)[ok], np.atleast_1d(x), np.atleast_1d(y), acc[ok]


def _ronin_model(weights: RoninResNet | str | Path | None, config: RunConfig) -> RoninResNet | None:
    """The caller's RoNIN model, loaded and checked against the stream (``None``: the bundled one): its
    problems are errors, never a reason to fall back to PDR."""
    if weights is None:
        return None
    from curbside.localize.ronin.infer import check_compatible, load_model

    model = load_model(weights) if isinstance(weights, str | Path) else weights
    check_compatible(model, config.engine.ronin)
    return model


def _velocity(
    session: Session, config: RunConfig, steps: np.ndarray | None, progress: bool = False,
    ronin_weights: RoninResNet | str | Path | None = None,
) -> tuple[pd.DataFrame, str]:
    """The session's world-frame velocity and its source name (see the module docstring); ``progress``: a
    progress bar over RoNIN's inference on a terminal; ``ronin_weights``: the RoNIN model (default: the
    bundled one)."""
    source = config.engine.velocity_source
    if source in ("auto", "file") and session.velocity is not None:
        return session.velocity, "file"
    if source == "file":
        raise CurbsideInputError(session.file_source("velocity.csv"), "no velocity.csv in the session")
    if session.imu is None:
        if session.velocity is not None:  # asked for RoNIN or PDR, which need the raw IMU
            raise CurbsideInputError(
                session.source, f"no imu.csv: --velocity-source {source} needs it (the session's "
                "velocity.csv is used with --velocity-source auto or file)"
            )
        raise CurbsideInputError(
            session.source, "no velocity.csv or imu.csv: the inertial, paper and fused modes need inertial "
            "data"
        )
    if source in ("auto", "ronin"):
        model = _ronin_model(ronin_weights, config)
        try:
            from curbside.localize.ronin.infer import ronin_velocity

            source_name = session.file_source("imu.csv")
            warn_if_simulated_imu(session, source_name)
            velocity = ronin_velocity(session.imu, model=model, config=config.engine.ronin,
                                      source=source_name, progress=progress)
            return velocity, "ronin"
        except (ImportError, CurbsideInputError) as exc:
            if source == "ronin":
                raise
            logger.warning("RoNIN unavailable (%s): falling back to PDR", exc)
    from curbside.localize.pdr import pdr_velocity

    return pdr_velocity(session.imu, steps, config.engine.pdr, config.engine.steps), "pdr"


def _steps(session: Session, config: RunConfig) -> tuple[np.ndarray | None, str]:
    """Footstep times (``None`` for a fixed cadence) and their source."""
    source = config.engine.step_source
    if source in ("auto", "file") and session.steps is not None:
        return session.steps["t"].to_numpy(float), "file"
    if source == "file":
        raise CurbsideInputError(session.file_source("steps.csv"), "no steps.csv in the session")
    if source in ("auto", "detect") and session.imu is not None:
        from curbside.localize.steps import detect_steps

        return np.asarray(detect_steps(session.imu, config.engine.steps), float), "detected"
    if source == "detect":
        raise CurbsideInputError(session.file_source("imu.csv"), "no imu.csv to detect footsteps in")
    return None, "cadence"


def track_session(
    session: Session,
    map_layers: MapLayers | None = None,
    mode: str | None = None,
    *,
    config: RunConfig | None = None,
    particles: int | None = None,
    jaywalk_weight: float | None = None,
    seed: int | None = None,
    velocity_source: str | None = None,
    use_start_pose: bool | None = None,
    save_particles: bool = False,
    progress: bool = False,
    map_name: str | None = None,
    ronin_weights: RoninResNet | str | Path | None = None,
    spill_dir: str | Path | None = None,
) -> TrackResult:
    """Track one session with one method.

    Parameters
    ----------
    session
        The recording (see :mod:`curbside.localize.session`).
    map_layers
        The map; ``None`` runs the filter without a map likelihood.
    mode
        ``gnss``, ``inertial``, ``paper`` or ``fused`` (default: ``config``'s, else ``fused``).
    config
        The whole run configuration (default: the mode's); the shortcuts below override its fields.
    particles, jaywalk_weight, seed, velocity_source, use_start_pose
        Shortcuts for ``filter.n_particles``, ``filter.map.jaywalk_weight``, ``seed``,
        ``engine.velocity_source`` and ``use_start_pose``.
    save_particles, spill_dir
        Keep each update's particle cloud in :attr:`TrackResult.snapshots`, on disk in ``spill_dir`` as
        the walk goes (default: the system's temporary folder).
    progress
        A progress bar over RoNIN's inference on a terminal (a command's single run; off in a batch).
    map_name
        How messages name the map, e.g. its path (default: "the map" alone).
    ronin_weights
        The RoNIN model (a loaded one, or a weights ``.pt`` with its ``.json``; default: the bundled one).

    Raises
    ------
    CurbsideInputError
        Unknown mode, missing inputs for the mode, start pose or session outside the map, a start pose
        in a building with no free space nearby, nothing to start from, unusable ``ronin_weights``.
    """
    config = resolve_config(config, mode, particles=particles, jaywalk_weight=jaywalk_weight, seed=seed,
                            velocity_source=velocity_source, use_start_pose=use_start_pose)
    frame = _frame_for(session, map_layers)
    start, t_begin = _start_of(session)
    _check_inputs(session, map_layers, config, frame, start, map_name)
    steps, step_source = _steps(session, config)
    velocity, velocity_source = None, None
    if config.mode != "gnss":
        velocity, velocity_source = _velocity(session, config, steps, progress, ronin_weights)
        if len(velocity) < 2:
            problem = f"the {velocity_source} velocity has fewer than two samples"
            raise CurbsideInputError(session.source, problem)
        input_warnings.report_short_velocity(session, velocity["t"].to_numpy(float), velocity_source)
    fix_lag = _fix_lag(session, config, frame, velocity, velocity_source == "pdr")
    engine = SessionEngine(
        config, frame, _raster_for(map_layers, config), start=start, t_begin=t_begin, cadence=steps is None,
        save_particles=save_particles, step_means_velocity=velocity_source == "pdr",
        fix_lag_s=None if fix_lag is None else float(fix_lag["lag_s"]), spill_dir=spill_dir,
    )
    if velocity is not None:
        engine.push_velocity(velocity["t"].to_numpy(float), velocity[["ve", "vn"]].to_numpy(float))
    if steps is not None:
        engine.push_steps(steps, math.inf)
    engine.push_gnss(session.gnss)
    engine.finish()
    require_rows(engine.rows, session.source)
    if config.mode == "gnss":
        input_warnings.report_gnss_holds(session, config)
    sources = (velocity_source, step_source)
    result = _result(session.source, engine, frame, map_layers, sources, save_particles)
    result.fix_lag = fix_lag
    return result


def _fix_lag(
    session: Session, config: RunConfig, frame: LocalFrame, velocity: pd.DataFrame | None, step_means: bool
) -> dict[str, object] | None:
    """The fixes' lag this run compensates (``run.json``'s ``fix_lag``): under ``auto``, estimated from
    the whole recording (:func:`~curbside.localize.fix_lag.estimate_fix_lag`)."""
    c = config.fix_lag
    if c.mode == "off" or config.mode not in ("paper", "fused") or velocity is None or session.gnss is None:
        return None
    if c.mode == "fixed":
        return {"mode": "fixed", "lag_s": c.lag_s}
    gnss = session.gnss
    x, y = frame.to_xy(gnss["lon"].to_numpy(float), gnss["lat"].to_numpy(float))
    displacement = DisplacementIntegrator(config.engine.velocity_max_gap_s, step_means)
    displacement.push(velocity["t"].to_numpy(float), velocity[["ve", "vn"]].to_numpy(float))
    fixes_xy = np.column_stack([x, y])
    estimate = estimate_fix_lag(gnss["t"].to_numpy(float), fixes_xy, gnss["accuracy_m"].to_numpy(float),
                                displacement, c)
    if estimate.lag_s > 0:
        logger.info(
            "%s: the fixes trail the inertial track by a %.0f s lag (residual %.2f m against %.2f m "
            "without): each fix is moved forward by the motion that lag holds back (fix_lag.mode = auto)",
            session.source, estimate.lag_s, estimate.residual_m[estimate.lag_s], estimate.residual_m[0.0],
        )
    return estimate.to_dict()


def _raster_for(map_layers: MapLayers | None, config: RunConfig) -> MapRaster | None:
    """The map raster the filter weighs particles on (``None`` without a map or in ``gnss`` mode)."""
    if map_layers is None or config.mode == "gnss":
        return None
    return load_or_build_raster(
        map_layers, config.filter.map.raster_resolution_m, config.filter.map.segment_reach_m
    )


def tracker_record(tracker: Tracker | None) -> dict[str, object]:
    """``recoveries``, ``injections`` and ``heading_corrections`` of a finished tracker (0 without one),
    and its ``calibration`` record (``None`` without one)."""
    if tracker is None:
        return {"recoveries": 0, "injections": 0, "heading_corrections": 0, "calibration": None}
    return {
        "recoveries": tracker.recoveries,
        "injections": 0 if tracker.divergence is None else tracker.divergence.injections,
        "heading_corrections": 0 if tracker.turn is None else tracker.turn.corrections,
        "calibration": None if tracker.calibration is None else tracker.calibration.record(),
    }


def _result(
    name: str,
    engine: SessionEngine,
    frame: LocalFrame,
    map_layers: MapLayers | None,
    sources: tuple[str | None, str],
    save_particles: bool,
) -> TrackResult:
    """The finished engine's track table, counts and particle snapshots."""
    tracker = engine.tracker
    if tracker is not None and tracker.recoveries:
        logger.info("%s: the particle cloud collapsed %d time(s)", name, tracker.recoveries)
    track = track_table(
        engine.rows,
        frame,
        map_layers,
        segments=tracker is not None and tracker.segments is not None,
        smoothed=tracker is not None and tracker.smoother is not None,
    )
    snapshots = engine.snapshots.packed() if save_particles and tracker is not None else None
    return TrackResult(
        track,
        engine.config,
        *sources,
        snapshots=snapshots,
        unseen_velocity_from_s=engine.unseen_velocity_from_s,
        wall_tolerance_m=None if tracker is None else tracker.wall_tolerance_m,
        walkable_first=None if tracker is None else tracker.walkable_first,
        familiar_velocity=engine.familiar_velocity,
        **tracker_record(tracker),
    )


def track_table(
    rows: list[Row], frame: LocalFrame, map_layers: MapLayers | None, segments: bool, smoothed: bool = False
) -> pd.DataFrame:
    """The ``track.csv`` table of the engine's rows (``smooth_lat, smooth_lon`` when ``smoothed``)."""
    x = np.array([r.x for r in rows])
    y = np.array([r.y for r in rows])
    lon, lat = frame.to_lonlat(x, y)
    track = pd.DataFrame(
        {
            "t": [r.t for r in rows],
            "lat": np.atleast_1d(lat),
            "lon": np.atleast_1d(lon),
            "x_m": x,
            "y_m": y,
            "accuracy_m": [r.accuracy_m for r in rows],
            "update": [r.kind for r in rows],
            "gnss_used": np.array([r.fix_used for r in rows], dtype=int),
            "theta_drift_deg": np.degrees([r.theta for r in rows]),
            "speed_scale": [r.scale for r in rows],
            "n_eff": [r.n_eff for r in rows],
            "recovered": np.array([r.recovered for r in rows], dtype=int),
            "injected": np.array([r.injected for r in rows], dtype=int),
            "motion": [r.motion for r in rows],
        }
    )
    if smoothed:
        smooth_lon, smooth_lat = frame.to_lonlat(
            np.array([r.smooth_x for r in rows]), np.array([r.smooth_y for r in rows])
        )
        track["smooth_lat"], track["smooth_lon"] = np.atleast_1d(smooth_lat), np.atleast_1d(smooth_lon)
    if map_layers is None or not len(map_layers.layer("sidewalk")):
        return track
    if segments:
        mode_lon, mode_lat = frame.to_lonlat(
            np.array([r.mode_x for r in rows]), np.array([r.mode_y for r in rows])
        )
        track["sidewalk_segment_id"] = np.array([r.segment_id for r in rows], dtype=object)
        track["segment_prob"] = [r.segment_prob for r in rows]
        track["mode_lat"], track["mode_lon"] = np.atleast_1d(mode_lat), np.atleast_1d(mode_lon)
    else:  # no particles (gnss mode) or no segment estimate: the polygon under the track's position
        track["sidewalk_segment_id"] = sidewalk_segments_at(map_layers, x, y)
        track["segment_prob"] = np.nan
        track["mode_lat"], track["mode_lon"] = track["lat"], track["lon"]
    return track


def sidewalk_segments_at(map_layers: MapLayers, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """``segment_id`` of the sidewalk polygon under each point (``None`` off sidewalks)."""
    sidewalks = map_layers.layer("sidewalk")
    out = np.full(len(x), None, dtype=object)
    if len(sidewalks) == 0 or len(x) == 0:
        return out
    point_idx, poly_idx = sidewalks.sindex.query(shapely.points(x, y), predicate="within")
    out[point_idx[::-1]] = sidewalks["segment_id"].to_numpy()[poly_idx[::-1]]  # first match wins
    return out


def run_session(
    session: Session, map_layers: MapLayers | None = None, mode: str | None = None, **kwargs
) -> pd.DataFrame:
    """Track one session and return only the track table (see :func:`track_session`)."""
    return track_session(session, map_layers, mode, **kwargs).track
