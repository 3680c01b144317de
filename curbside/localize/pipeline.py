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
PDR (and PDR on an ``imu.csv`` that ``localize simulate`` made: RoNIN reads it about 100 deg off, see
:func:`~curbside.localize.session.warn_if_simulated_imu`); footsteps from ``steps.csv``,
else detected in ``imu.csv``, else a fixed cadence. Everything goes through
:class:`~curbside.localize.engine.SessionEngine`, the same engine the live service streams into.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pandas as pd
import pyproj

from curbside.errors import CurbsideInputError
from curbside.localize import input_warnings
from curbside.localize.engine import SessionEngine, StartPose, require_rows
from curbside.localize.fix_lag import estimate_fix_lag
from curbside.localize.raster import MapRaster, load_or_build_raster
from curbside.localize.runconfig import MODES, VELOCITY_SOURCES, RunConfig
from curbside.localize.session import Session, warn_if_simulated_imu
from curbside.localize.streams import DisplacementIntegrator
from curbside.localize.track_result import TrackResult, track_table, tracker_record
from curbside.osmseg.mapio import MapLayers
from curbside.projection import LocalFrame

if TYPE_CHECKING:
    from curbside.localize.ronin.model import RoninResNet

logger = logging.getLogger(__name__)

__all__ = ["MODES", "VELOCITY_SOURCES", "TrackResult", "track_session", "run_session"]

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


#: What ``--velocity-source auto`` does with an IMU curbside simulated, which RoNIN reads badly.
_AUTO_ON_SIMULATED = ("--velocity-source auto tracks with PDR instead (--velocity-source ronin runs RoNIN "
                      "anyway)")


def _velocity(
    session: Session, config: RunConfig, steps: np.ndarray | None, progress: bool = False,
    ronin_weights: RoninResNet | str | Path | None = None,
) -> tuple[pd.DataFrame, str, dict | None]:
    """The session's world-frame velocity, its source name and, for RoNIN, whether the model knows the
    recording (``run.json``'s ``ronin_familiarity``; see the module docstring); ``progress``: a progress
    bar over RoNIN's inference on a terminal; ``ronin_weights``: the RoNIN model (default: the bundled
    one). Under ``auto``, an IMU curbside simulated goes to PDR, not to RoNIN (one warning says so)."""
    source = config.engine.velocity_source
    if source in ("auto", "file") and session.velocity is not None:
        return session.velocity, "file", None
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
    imu_source = session.file_source("imu.csv")
    if source == "auto" and warn_if_simulated_imu(session, imu_source, _AUTO_ON_SIMULATED):
        source = "pdr"
    if source in ("auto", "ronin"):
        model = _ronin_model(ronin_weights, config)
        try:
            return _ronin_velocity(session, config, model, progress)
        except (ImportError, CurbsideInputError) as exc:
            if source == "ronin":
                raise
            logger.warning("RoNIN unavailable (%s): falling back to PDR", exc)
    from curbside.localize.pdr import pdr_velocity

    return pdr_velocity(session.imu, steps, config.engine.pdr, config.engine.steps), "pdr", None


def _ronin_velocity(
    session: Session, config: RunConfig, model: RoninResNet | None, progress: bool
) -> tuple[pd.DataFrame, str, dict]:
    """RoNIN's velocity of the session (``model`` ``None``: the bundled one) and the model's familiarity
    with it (:mod:`curbside.localize.ronin.familiarity`)."""
    from curbside.localize.ronin.familiarity import session_familiarity
    from curbside.localize.ronin.infer import load_model, ronin_velocity

    model = model or load_model(None)
    source_name = session.file_source("imu.csv")
    warn_if_simulated_imu(session, source_name)
    velocity = ronin_velocity(session.imu, model=model, config=config.engine.ronin, source=source_name,
                              progress=progress)
    familiarity = session_familiarity(model, session.imu, config.engine.ronin, source_name)
    logger.info("%s: %s", session.source, familiarity.describe())
    return velocity, "ronin", familiarity.to_dict()


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
    inputs = _inputs(session, map_layers, config, map_name, progress, ronin_weights)
    engine = _run_engine(session, map_layers, config, inputs, save_particles, spill_dir)
    if config.mode == "gnss":
        input_warnings.report_gnss_holds(session, config)
    return _result(session.source, engine, inputs, map_layers, save_particles)


@dataclass
class _Inputs:
    """What :func:`track_session` feeds the engine, and where it came from."""

    frame: LocalFrame
    start: StartPose | None
    t_begin: float | None
    steps: np.ndarray | None
    step_source: str
    velocity: pd.DataFrame | None
    velocity_source: str | None
    fix_lag: dict[str, object] | None
    ronin_familiarity: dict | None


def _inputs(
    session: Session, map_layers: MapLayers | None, config: RunConfig, map_name: str | None, progress: bool,
    ronin_weights: RoninResNet | str | Path | None,
) -> _Inputs:
    """The run's frame, start, footsteps, velocity (none in ``gnss`` mode) and fixes' lag, once the session
    is checked against the map (see the module docstring)."""
    frame = _frame_for(session, map_layers)
    start, t_begin = _start_of(session)
    _check_inputs(session, map_layers, config, frame, start, map_name)
    steps, step_source = _steps(session, config)
    velocity, velocity_source, ronin_familiarity = None, None, None
    if config.mode != "gnss":
        velocity, velocity_source, ronin_familiarity = _velocity(session, config, steps, progress,
                                                                 ronin_weights)
        if len(velocity) < 2:
            problem = f"the {velocity_source} velocity has fewer than two samples"
            raise CurbsideInputError(session.source, problem)
        input_warnings.report_short_velocity(session, velocity["t"].to_numpy(float), velocity_source)
    fix_lag = _fix_lag(session, config, frame, velocity, velocity_source == "pdr")
    return _Inputs(frame, start, t_begin, steps, step_source, velocity, velocity_source, fix_lag,
                   ronin_familiarity)


def _run_engine(
    session: Session, map_layers: MapLayers | None, config: RunConfig, inputs: _Inputs, save_particles: bool,
    spill_dir: str | Path | None,
) -> SessionEngine:
    """The engine, fed the whole session and finished (refused when it gave no estimate)."""
    pdr = inputs.velocity_source == "pdr"
    engine = SessionEngine(
        config, inputs.frame, _raster_for(map_layers, config), start=inputs.start, t_begin=inputs.t_begin,
        cadence=inputs.steps is None, save_particles=save_particles, step_means_velocity=pdr,
        fix_lag_s=None if inputs.fix_lag is None else float(inputs.fix_lag["lag_s"]), spill_dir=spill_dir,
    )
    velocity = inputs.velocity
    if velocity is not None:
        engine.push_velocity(velocity["t"].to_numpy(float), velocity[["ve", "vn"]].to_numpy(float))
    if inputs.steps is not None:
        engine.push_steps(inputs.steps, math.inf)
    engine.push_gnss(session.gnss)
    engine.finish()
    require_rows(engine, session.source)
    return engine


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


def _result(
    name: str,
    engine: SessionEngine,
    inputs: _Inputs,
    map_layers: MapLayers | None,
    save_particles: bool,
) -> TrackResult:
    """The finished engine's track table, counts and particle snapshots."""
    tracker = engine.tracker
    if tracker is not None and tracker.recoveries:
        logger.info("%s: the particle cloud collapsed %d time(s)", name, tracker.recoveries)
    track = track_table(
        engine.rows,
        inputs.frame,
        map_layers,
        segments=tracker is not None and tracker.segments is not None,
        smoothed=tracker is not None and tracker.smoother is not None,
    )
    snapshots = engine.snapshots.packed() if save_particles and tracker is not None else None
    return TrackResult(
        track,
        engine.config,
        inputs.velocity_source,
        inputs.step_source,
        snapshots=snapshots,
        unseen_velocity_from_s=engine.unseen_velocity_from_s,
        wall_tolerance_m=None if tracker is None else tracker.wall_tolerance_m,
        walkable_first=None if tracker is None else tracker.walkable_first,
        familiar_velocity=engine.familiar_velocity,
        fix_lag=inputs.fix_lag,
        ronin_familiarity=inputs.ronin_familiarity,
        **tracker_record(tracker),
    )


def run_session(
    session: Session, map_layers: MapLayers | None = None, mode: str | None = None, **kwargs
) -> pd.DataFrame:
    """Track one session and return only the track table (see :func:`track_session`)."""
    return track_session(session, map_layers, mode, **kwargs).track
