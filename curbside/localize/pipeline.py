"""From a session to a track: velocity source -> footsteps -> displacements and fixes -> tracker.

:func:`track_session` runs one of the paper's three methods over a :class:`Session`:

``gnss``
    the raw fixes, linearly interpolated at the footsteps (no filter);
``inertial``
    inertial velocity + the map-aware particle filter, no GNSS (RoNIN+PF in the paper);
``paper``
    the paper's GNSS+RoNIN+PF, plainly: a Gaussian GNSS likelihood with sigma equal to the reported
    accuracy, fixes under ``gnss_max_accuracy_m`` only, nothing else of ours (a baseline);
``fused``
    curbside's filter: the same, with the robust GNSS fusion and recovery (GNSS+RoNIN+PF).

Inputs are chosen in this order. Velocity: ``velocity.csv``, else the bundled RoNIN model on
``imu.csv``, else the PDR baseline (``--velocity-source`` forces one). Footsteps: ``steps.csv``, else
detected from ``imu.csv``, else a fixed cadence of ``settings.default_step_cadence_s`` over the span of
the velocity (or GNSS) data. The filter is started from ``meta.json``'s start pose (at its ``t`` when
given, else at the first footstep) with the drift chosen so that the first motion points along the
start heading; without a start pose (or when told to ignore it), from the first usable GNSS fix at or
after the start time (in ``inertial`` mode too: that one fix only places the start).

Fixes are associated with footsteps by ``settings.gnss_fix_association``. ``"interpolate"`` (the
paper): at each footstep, interpolated between the bracketing fixes when both lie within
``settings.gnss_interp_max_gap_s``, else the latest earlier fix if it is not older than
``settings.gnss_max_fix_age_s``; otherwise no GNSS update (gaps of minutes run on inertial data
alone). The interpolation looks up to 2 s ahead, which a batch run can do. ``"once"``: each fix is
applied at the first footstep at or after it and never again (:func:`fresh_fixes_at`), as a live app
passing its newest fix to :meth:`Tracker.step` would.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, replace

import numpy as np
import pandas as pd
import pyproj
import shapely
from tqdm.auto import tqdm

from curbside import settings
from curbside.errors import CurbsideInputError
from curbside.localize.filter import Estimate, FilterConfig, GnssFix, Tracker
from curbside.localize.maplikelihood import load_or_build_raster
from curbside.localize.session import Session
from curbside.osmseg.mapio import MapLayers
from curbside.projection import LocalFrame

logger = logging.getLogger(__name__)

MODES = ("gnss", "inertial", "paper", "fused")
VELOCITY_SOURCES = ("auto", "file", "ronin", "pdr")
GNSS_ASSOCIATIONS = ("interpolate", "once")

#: Columns of ``track.csv`` in order (:data:`SEGMENT_COLUMNS` follow when the map has sidewalks).
TRACK_COLUMNS = ("t", "lat", "lon", "x_m", "y_m", "theta_drift_deg", "speed_scale", "n_eff", "recovered")

#: Columns added when the map has sidewalk segments: the filter's MAP segment (the polygon under the
#: estimate in ``gnss`` mode), its posterior probability (NaN in ``gnss`` mode) and the mode estimate
#: (the weighted mean of the particles on the MAP segment; the track's own position in ``gnss`` mode).
SEGMENT_COLUMNS = ("sidewalk_segment_id", "segment_prob", "mode_lat", "mode_lon")

#: What the ``paper`` mode changes in the filter: the plain Gaussian GNSS likelihood of Ren & Ke (2010)
#: with sigma = the reported accuracy, no outlier mixture, no tempering, no divergence recovery.
PAPER_OVERRIDES = {
    "gnss_sigma_factor": 1.0, "gnss_outlier_prob": 0.0, "gnss_error_correlation_s": 0.0,
    "gnss_bias_sigma_m": 0.0, "recovery_max_fraction": 0.0, "scale_init_sigma": 0.0,
    "scale_noise_per_step": 0.0, "resample": "always",
}

#: Velocity samples further apart than this (s) are a gap: no motion is integrated across it.
VELOCITY_MAX_GAP_S = 1.0

#: Length of the first motion (m) whose direction is aligned with the start heading.
HEADING_ALIGN_DISTANCE_M = 3.0

#: A session is outside the map when none of its fixes lies within this distance (m) of the map.
EXTENT_TOLERANCE_M = 100.0


@dataclass
class InertialInput:
    """The inertial velocity of a session and how to integrate it.

    Attributes
    ----------
    velocity
        ``t,ve,vn`` table, m/s east/north.
    source
        ``"file"``, ``"ronin"`` or ``"pdr"``.
    step_means
        ``True`` when each row holds the mean velocity since the previous row (the PDR output);
        ``False`` for a sampled signal (``velocity.csv``, RoNIN), integrated with the trapezoid rule.
    """

    velocity: pd.DataFrame
    source: str
    step_means: bool


@dataclass
class TrackResult:
    """The output of :func:`track_session`.

    Attributes
    ----------
    track
        One row per footstep: :data:`TRACK_COLUMNS` (and :data:`SEGMENT_COLUMNS` with a map that has
        sidewalks).
    mode
        The method run.
    velocity_source, step_source
        Where the velocity and the footsteps came from (``None`` in ``gnss`` mode for velocity).
    recoveries
        How many times the particle cloud collapsed and was re-seeded.
    snapshots
        With ``save_particles``: ``t`` ``(K,)``, ``x``, ``y`` ``(K, N)`` float32 metres relative to
        ``origin``, ``theta`` ``(K, N)`` float32 radians, ``scale`` ``(K, N)`` float32, ``origin``
        ``(2,)``, ``crs`` (WKT).
    config
        The filter parameters used (``None`` in ``gnss`` mode).
    """

    track: pd.DataFrame
    mode: str
    velocity_source: str | None
    step_source: str
    recoveries: int
    snapshots: dict[str, np.ndarray] | None = None
    config: FilterConfig | None = None


# -- inputs ---------------------------------------------------------------------------------------------


def inertial_velocity(
    session: Session, source: str = "auto", steps: np.ndarray | None = None
) -> InertialInput:
    """The session's world-frame walking velocity from the requested source.

    Parameters
    ----------
    session
        The recording.
    source
        ``auto`` (``velocity.csv``, else RoNIN on ``imu.csv``, else PDR), ``file``, ``ronin`` or ``pdr``.
    steps
        Footstep times for PDR (detected when ``None``).

    Returns
    -------
    InertialInput

    Raises
    ------
    CurbsideInputError
        The requested source is missing (no ``velocity.csv``, no ``imu.csv``, RoNIN weights absent).
    """
    if source not in VELOCITY_SOURCES:
        raise CurbsideInputError("--velocity-source", f"unknown source {source!r}; one of {VELOCITY_SOURCES}")
    if source in ("auto", "file") and session.velocity is not None:
        logger.info("velocity source: velocity.csv")
        return InertialInput(session.velocity, "file", step_means=False)
    if source == "file":
        raise CurbsideInputError(f"{session.name}/velocity.csv", "no velocity.csv in the session")
    if session.imu is None:
        raise CurbsideInputError(
            session.name, "no velocity.csv or imu.csv: the inertial and fused modes need inertial data"
        )
    if source in ("auto", "ronin"):
        try:
            from curbside.localize.ronin.infer import ronin_velocity

            velocity = ronin_velocity(session.imu, source=f"{session.name}/imu.csv")
            logger.info("velocity source: RoNIN on imu.csv")
            return InertialInput(velocity, "ronin", step_means=False)
        except (ImportError, CurbsideInputError) as exc:
            if source == "ronin":
                raise
            logger.warning("RoNIN unavailable (%s): falling back to PDR", exc)
    from curbside.localize.pdr import pdr_velocity

    velocity = pdr_velocity(session.imu, steps)
    logger.info("velocity source: PDR on imu.csv")
    return InertialInput(velocity, "pdr", step_means=True)


def footstep_times(session: Session, span: tuple[float, float] | None = None) -> tuple[np.ndarray, str]:
    """Footstep times: ``steps.csv``, else detected in ``imu.csv``, else a fixed cadence over ``span``.

    Returns
    -------
    (numpy.ndarray, str)
        Increasing times (s) and their source (``"file"``, ``"detected"`` or ``"cadence"``).
    """
    if session.steps is not None:
        return session.steps["t"].to_numpy(float), "file"
    if session.imu is not None:
        from curbside.localize.steps import detect_steps

        steps = np.asarray(detect_steps(session.imu), float)
        if len(steps) >= 2:
            return steps, "detected"
        logger.warning("fewer than two footsteps detected in imu.csv: using a fixed cadence")
    if span is None:
        span = session.time_span()
    cadence = settings.default_step_cadence_s
    return np.arange(span[0], span[1] + 1e-9, cadence), "cadence"


def cumulative_displacement(inertial: InertialInput) -> tuple[np.ndarray, np.ndarray]:
    """Knots ``(t, D)`` of the integrated velocity: ``D(t)`` in metres east/north, linear between knots.

    A sampled velocity is integrated with the trapezoid rule, nothing across gaps longer than
    :data:`VELOCITY_MAX_GAP_S`; step means are held over the interval they describe.
    """
    t = inertial.velocity["t"].to_numpy(float)
    v = inertial.velocity[["ve", "vn"]].to_numpy(float)
    dt = np.diff(t)
    if inertial.step_means:
        increments = v[1:] * dt[:, None]
    else:
        increments = 0.5 * (v[1:] + v[:-1]) * dt[:, None]
        increments[dt > VELOCITY_MAX_GAP_S] = 0.0
    return t, np.vstack([np.zeros((1, 2)), np.cumsum(increments, axis=0)])


def displacements_between(knots: tuple[np.ndarray, np.ndarray], times: np.ndarray) -> np.ndarray:
    """Displacement ``D(times[k]) - D(times[k-1])`` for ``k >= 1`` (row 0 is zero), shape ``(K, 2)``."""
    t, d = knots
    if len(t) == 0:
        return np.zeros((len(times), 2))
    at = np.column_stack([np.interp(times, t, d[:, 0]), np.interp(times, t, d[:, 1])])
    return np.vstack([np.zeros((1, 2)), np.diff(at, axis=0)])[: len(times)]


Fixes = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]


def valid_fixes(gnss: pd.DataFrame | None, frame: LocalFrame) -> Fixes:
    """``t, x, y, accuracy_m`` of the fixes with a valid accuracy (positive and finite)."""
    if gnss is None or len(gnss) == 0:
        return (np.empty(0),) * 4
    acc = gnss["accuracy_m"].to_numpy(float)
    ok = np.isfinite(acc) & (acc > 0)
    x, y = frame.to_xy(gnss["lon"].to_numpy(float)[ok], gnss["lat"].to_numpy(float)[ok])
    return gnss["t"].to_numpy(float)[ok], np.atleast_1d(x), np.atleast_1d(y), acc[ok]


def fixes_at(
    fixes: Fixes,
    times: np.ndarray,
    max_gap_s: float | None = None,
    max_age_s: float | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The fix to use at each time (see the module docstring); ``accuracy_m`` NaN where there is none.

    Parameters
    ----------
    fixes
        ``t, x, y, accuracy_m`` of valid fixes, ``t`` increasing.
    times
        Footstep times.
    max_gap_s, max_age_s
        Override ``settings.gnss_interp_max_gap_s`` and ``settings.gnss_max_fix_age_s``.

    Returns
    -------
    (x, y, accuracy_m)
        Arrays of ``len(times)``.
    """
    max_gap_s = settings.gnss_interp_max_gap_s if max_gap_s is None else max_gap_s
    max_age_s = settings.gnss_max_fix_age_s if max_age_s is None else max_age_s
    tf, xf, yf, af = fixes
    n = len(times)
    out = np.full((3, n), np.nan)
    if len(tf) == 0:
        return out[0], out[1], out[2]
    prev = np.searchsorted(tf, times, side="right") - 1
    has_prev = prev >= 0
    p = np.clip(prev, 0, len(tf) - 1)
    q = np.clip(prev + 1, 0, len(tf) - 1)
    age = times - tf[p]
    lead = tf[q] - times
    interp = has_prev & (prev + 1 < len(tf)) & (age <= max_gap_s) & (lead <= max_gap_s)
    hold = has_prev & ~interp & (age <= max_age_s)
    span = np.where(interp, tf[q] - tf[p], 1.0)
    a = np.where(interp, age / span, 0.0)
    for row, values in enumerate((xf, yf, af)):
        blended = values[p] + a * (values[q] - values[p])
        out[row] = np.where(interp | hold, blended, np.nan)
    return out[0], out[1], out[2]


def fresh_fixes_at(
    fixes: Fixes, times: np.ndarray, max_age_s: float | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each fix once: the newest fix in ``(times[k-1], times[k]]`` at footstep ``k``, NaN where none.

    Footsteps (about 2 Hz) come faster than fixes (1 Hz); interpolating at every footstep would apply
    the same information about twice. Here a fix is used at the first footstep at or after it (at most
    half a step late: well under a metre), and a footstep with no new fix makes no GNSS update.

    Parameters
    ----------
    fixes
        ``t, x, y, accuracy_m`` of valid fixes, ``t`` increasing.
    times
        Footstep times, increasing.
    max_age_s
        A fix older than this at the footstep is dropped (default ``settings.gnss_max_fix_age_s``).

    Returns
    -------
    (x, y, accuracy_m)
        Arrays of ``len(times)``.
    """
    max_age_s = settings.gnss_max_fix_age_s if max_age_s is None else max_age_s
    tf, xf, yf, af = fixes
    out = np.full((3, len(times)), np.nan)
    if len(tf) == 0 or len(times) == 0:
        return out[0], out[1], out[2]
    newest = np.searchsorted(tf, times, side="right") - 1
    before = np.concatenate([[-1], newest[:-1]])
    p = np.clip(newest, 0, len(tf) - 1)
    fresh = (newest > before) & (times - tf[p] <= max_age_s)
    for row, values in enumerate((xf, yf, af)):
        out[row] = np.where(fresh, values[p], np.nan)
    return out[0], out[1], out[2]


def start_heading_offset(heading_deg: float, displacements: np.ndarray) -> float:
    """Drift angle (rad, counter-clockwise) that turns the first motion onto the start heading.

    Parameters
    ----------
    heading_deg
        Start heading, degrees clockwise from north.
    displacements
        ``(K, 2)`` inertial step displacements from the start.

    Returns
    -------
    float
        0 when the inertial data show no motion.
    """
    path = np.cumsum(np.hypot(displacements[:, 0], displacements[:, 1]))
    if len(path) == 0 or path[-1] < 0.5:
        logger.warning("no inertial motion to align with the start heading: drift starts at 0")
        return 0.0
    k = int(min(np.searchsorted(path, HEADING_ALIGN_DISTANCE_M), len(path) - 1))
    first = displacements[: k + 1].sum(axis=0)
    target = math.pi / 2 - math.radians(heading_deg)
    offset = target - math.atan2(first[1], first[0])
    return math.atan2(math.sin(offset), math.cos(offset))


def _frame_for(session: Session, map_layers: MapLayers | None) -> LocalFrame:
    if map_layers is not None:
        return LocalFrame(pyproj.CRS(map_layers.crs))
    start = session.start_pose
    if start is not None:
        return LocalFrame.around(start["lon"], start["lat"])
    if session.gnss is not None and len(session.gnss):
        return LocalFrame.around(float(session.gnss["lon"].median()), float(session.gnss["lat"].median()))
    raise CurbsideInputError(session.name, "no start pose in meta.json and no gnss.csv: nowhere to start")


def _check_extent(
    session: Session, start: dict | None, tracker: Tracker, frame: LocalFrame, fixes: Fixes
) -> None:
    raster = tracker.map_likelihood.raster
    if start is not None:
        x, y = frame.to_xy(start["lon"], start["lat"])
        if not bool(raster.contains(x, y)):
            raise CurbsideInputError(
                f"{session.name}/meta.json",
                f"start pose ({start['lat']:.6f}, {start['lon']:.6f}) lies outside the map's extent",
            )
    _, fx, fy, _ = fixes
    if len(fx):
        xmin, ymin, xmax, ymax = raster.bounds
        tol = EXTENT_TOLERANCE_M
        near = (fx > xmin - tol) & (fx < xmax + tol) & (fy > ymin - tol) & (fy < ymax + tol)
        if not near.any():
            raise CurbsideInputError(
                f"{session.name}/gnss.csv", "the session lies outside the map's extent (no fix near the map)"
            )


def sidewalk_segments_at(map_layers: MapLayers, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """``segment_id`` of the sidewalk polygon under each point (``None`` off sidewalks)."""
    sidewalks = map_layers.layer("sidewalk")
    out = np.full(len(x), None, dtype=object)
    if len(sidewalks) == 0 or len(x) == 0:
        return out
    points = shapely.points(x, y)
    point_idx, poly_idx = sidewalks.sindex.query(points, predicate="within")
    out[point_idx[::-1]] = sidewalks["segment_id"].to_numpy()[poly_idx[::-1]]  # first match wins
    return out


# -- the three methods ------------------------------------------------------------------------------------


def _gnss_track(
    session: Session, frame: LocalFrame, steps: np.ndarray, t_start: float | None
) -> pd.DataFrame:
    tf, xf, yf, _ = valid_fixes(session.gnss, frame)
    if len(tf) == 0:
        raise CurbsideInputError(f"{session.name}/gnss.csv", "no valid GNSS fix (gnss mode needs some)")
    keep = (steps >= tf[0]) & (steps <= tf[-1])
    if t_start is not None:
        keep &= steps >= t_start
    t = steps[keep]
    x, y = np.interp(t, tf, xf), np.interp(t, tf, yf)
    n = len(t)
    return pd.DataFrame(
        {"t": t, "x_m": x, "y_m": y, "theta_drift_deg": np.full(n, np.nan), "speed_scale": np.full(n, np.nan),
         "n_eff": np.full(n, np.nan), "recovered": np.zeros(n, dtype=int)}
    )


def track_session(
    session: Session,
    map_layers: MapLayers | None = None,
    mode: str = "fused",
    *,
    config: FilterConfig | None = None,
    particles: int | None = None,
    jaywalk_weight: float | None = None,
    seed: int | None = 0,
    velocity_source: str = "auto",
    use_start_pose: bool = True,
    save_particles: bool = False,
    progress: bool | None = None,
) -> TrackResult:
    """Track one session with one method.

    Parameters
    ----------
    session
        The recording (see :mod:`curbside.localize.session`).
    map_layers
        The map; ``None`` runs the filter without a map likelihood.
    mode
        ``gnss``, ``inertial`` or ``fused``.
    config
        Filter parameters; ``particles`` and ``jaywalk_weight`` override its fields.
    particles, jaywalk_weight
        Shortcuts for the two parameters the paper varies.
    seed
        Seed of the filter: same seed, same track.
    velocity_source
        ``auto``, ``file``, ``ronin`` or ``pdr`` (see :func:`inertial_velocity`).
    use_start_pose
        Start from ``meta.json``'s start pose when there is one (the paper's setting); ``False``
        starts from the first usable fix at or after the pose's ``t`` (when given).
    save_particles
        Keep a particle snapshot per footstep in :attr:`TrackResult.snapshots`.
    progress
        Show a tqdm bar (``None``: only on a terminal).

    Returns
    -------
    TrackResult

    Raises
    ------
    CurbsideInputError
        Unknown mode, missing inputs for the mode, start pose or session outside the map, a start pose
        in a building with no free space nearby.
    """
    if mode not in MODES:
        raise CurbsideInputError("--mode", f"unknown mode {mode!r}; one of {MODES}")
    config = config or FilterConfig()
    overrides = {}
    if particles is not None:
        overrides["n_particles"] = int(particles)
    if jaywalk_weight is not None:
        overrides["jaywalk_weight"] = float(jaywalk_weight)
    if mode == "paper":
        overrides.update(PAPER_OVERRIDES)
    config = replace(config, **overrides) if overrides else config
    frame = _frame_for(session, map_layers)
    # The start time is kept without the pose: it says when the walk began (an app knows when
    # navigation starts), and what the phone logged before (handling, calibration) is not a walk.
    pose = session.start_pose
    t_start = float(pose["t"]) if pose is not None and isinstance(pose.get("t"), int | float) else None
    start = pose if use_start_pose else None

    if mode == "gnss":
        span = None
        if session.imu is None and session.gnss is not None:
            span = (float(session.gnss["t"].iat[0]), float(session.gnss["t"].iat[-1]))
        steps, step_source = footstep_times(session, span)
        track = _gnss_track(session, frame, steps, t_start)
        return _finish(TrackResult(track, mode, None, step_source, 0), frame, map_layers)

    span = None
    if session.velocity is not None:
        span = (float(session.velocity["t"].iat[0]), float(session.velocity["t"].iat[-1]))
    steps, step_source = footstep_times(session, span)
    inertial = inertial_velocity(session, velocity_source, steps)
    if len(inertial.velocity) < 2:
        raise CurbsideInputError(session.name, f"the {inertial.source} velocity has fewer than two samples")
    if t_start is not None and start is not None:
        steps = np.concatenate([[t_start], steps[steps > t_start]])
    elif t_start is not None:
        steps = steps[steps >= t_start]
    if len(steps) < 2:
        raise CurbsideInputError(session.name, "fewer than two footsteps after the start")
    disp = displacements_between(cumulative_displacement(inertial), steps)
    fixes = valid_fixes(session.gnss, frame)
    association = settings.gnss_fix_association
    if association not in GNSS_ASSOCIATIONS:
        raise CurbsideInputError(
            "settings.gnss_fix_association", f"unknown {association!r}; one of {GNSS_ASSOCIATIONS}"
        )
    fx, fy, facc = (fresh_fixes_at if association == "once" else fixes_at)(fixes, steps)
    tracker = Tracker(
        load_or_build_raster(map_layers, config.raster_resolution_m) if map_layers is not None else None,
        config,
        seed,
        frame,
    )
    if map_layers is not None:
        _check_extent(session, start, tracker, frame, fixes)
    first = 0
    if start is not None:
        x0, y0 = frame.to_xy(start["lon"], start["lat"])
        offset = start_heading_offset(float(start["heading_deg"]), disp[1:])
        t0 = steps[0] if t_start is None else t_start
        estimates = [tracker.start_at_pose(float(t0), float(x0), float(y0), offset)]
        first = 1
    else:
        estimates = []
        if not np.isfinite(facc).any():
            raise CurbsideInputError(
                session.name, "no start pose in meta.json and no usable GNSS fix to start from"
            )
    label = f"{session.name} {mode}"
    estimates, snaps = _filter_steps(
        tracker, steps[first:], disp[first:], (fx[first:], fy[first:], facc[first:]),
        use_gnss=mode in ("paper", "fused"), save_particles=save_particles, progress=progress, label=label,
        estimates=estimates,
    )
    if not estimates:
        raise CurbsideInputError(session.name, "no usable GNSS fix to start the filter from")
    track = pd.DataFrame(
        {
            "t": [e.t for e in estimates],
            "x_m": [e.x for e in estimates],
            "y_m": [e.y for e in estimates],
            "theta_drift_deg": np.degrees([e.theta for e in estimates]),
            "speed_scale": [e.scale for e in estimates],
            "n_eff": [e.n_eff for e in estimates],
            "recovered": np.array([e.recovered for e in estimates], dtype=int),
        }
    )
    if tracker.segment_ids is not None:
        track["sidewalk_segment_id"] = np.array([e.segment_id for e in estimates], dtype=object)
        track["segment_prob"] = [e.segment_prob for e in estimates]
        track["mode_x_m"] = [e.mode_x for e in estimates]
        track["mode_y_m"] = [e.mode_y for e in estimates]
    if tracker.recoveries:
        # Reported by `localize run`'s summary and in the evaluation's run records; expected at w = 0.
        logger.info("%s: the particle cloud collapsed %d time(s)", session.name, tracker.recoveries)
    snapshots = _stack_snapshots(snaps, track, frame) if save_particles else None
    result = TrackResult(track, mode, inertial.source, step_source, tracker.recoveries, snapshots, config)
    return _finish(result, frame, map_layers)


def _filter_steps(
    tracker: Tracker,
    steps: np.ndarray,
    disp: np.ndarray,
    fixes: tuple[np.ndarray, np.ndarray, np.ndarray],
    *,
    use_gnss: bool,
    save_particles: bool,
    progress: bool | None,
    label: str,
    estimates: list[Estimate],
) -> tuple[list[Estimate], list[tuple[np.ndarray, ...]]]:
    """Feed the footsteps to the tracker; a fix starts an unstarted tracker even without ``use_gnss``."""
    fx, fy, facc = fixes
    snaps = [_snapshot(tracker)] if save_particles and estimates else []
    for k in tqdm(range(len(steps)), desc=label, unit="step", leave=False,
                  disable=(not progress) if progress is not None else None):
        fix = None
        if math.isfinite(facc[k]) and (use_gnss or not tracker.started):
            fix = GnssFix(fx[k], fy[k], facc[k])
        estimate = tracker.step(float(steps[k]), displacement_en=disp[k], gnss_fix=fix)
        if estimate is not None:
            estimates.append(estimate)
            if save_particles:
                snaps.append(_snapshot(tracker))
    return estimates, snaps


def _snapshot(tracker: Tracker) -> tuple[np.ndarray, ...]:
    p = tracker.particles
    return p.x.copy(), p.y.copy(), p.theta.copy(), p.scale.copy()


def _stack_snapshots(
    snaps: list[tuple[np.ndarray, ...]], track: pd.DataFrame, frame: LocalFrame
) -> dict[str, np.ndarray]:
    """Snapshots as ``(K, N)`` float32 arrays, positions relative to the first estimate."""
    origin = np.array([track["x_m"].iat[0], track["y_m"].iat[0]])
    return {
        "t": track["t"].to_numpy(),
        "x": (np.stack([s[0] for s in snaps]) - origin[0]).astype(np.float32),
        "y": (np.stack([s[1] for s in snaps]) - origin[1]).astype(np.float32),
        "theta": np.stack([s[2] for s in snaps]).astype(np.float32),
        "scale": np.stack([s[3] for s in snaps]).astype(np.float32),
        "origin": origin,
        "crs": np.array(frame.crs.to_wkt()),
    }


def _finish(result: TrackResult, frame: LocalFrame, map_layers: MapLayers | None) -> TrackResult:
    track = result.track
    lon, lat = frame.to_lonlat(track["x_m"].to_numpy(), track["y_m"].to_numpy())
    track.insert(1, "lat", np.atleast_1d(lat))
    track.insert(2, "lon", np.atleast_1d(lon))
    if map_layers is None or not len(map_layers.layer("sidewalk")):
        return result
    if "mode_x_m" in track:  # the filter's posterior mode over segments
        mode_x, mode_y = track.pop("mode_x_m").to_numpy(), track.pop("mode_y_m").to_numpy()
        mode_lon, mode_lat = frame.to_lonlat(mode_x, mode_y)
        track["mode_lat"] = np.atleast_1d(mode_lat)
        track["mode_lon"] = np.atleast_1d(mode_lon)
    else:  # no particles (gnss mode) or no segment estimate: the polygon under the track's position
        track["sidewalk_segment_id"] = sidewalk_segments_at(
            map_layers, track["x_m"].to_numpy(), track["y_m"].to_numpy()
        )
        track["segment_prob"] = np.nan
        track["mode_lat"] = track["lat"]
        track["mode_lon"] = track["lon"]
    return result


def run_session(
    session: Session,
    map_layers: MapLayers | None = None,
    mode: str = "fused",
    **kwargs,
) -> pd.DataFrame:
    """Track one session and return only the track table (see :func:`track_session` for arguments)."""
    return track_session(session, map_layers, mode, **kwargs).track
