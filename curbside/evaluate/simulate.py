"""Simulated sessions: a walker on a route, with ground-truth taps, RoNIN-like velocity, IMU and GNSS.

The walker follows the route's waypoints at a constant speed per leg and taps each waypoint on
arrival (``waypoints.csv``), as in the paper. Their true path wanders a little off the straight legs
(a lateral Ornstein-Uhlenbeck offset that vanishes at the waypoints), so the paper's ground-truth
assumption is as approximate here as it was there. Sensors see the true path:

- ``velocity.csv`` -- what RoNIN would output: the true velocity averaged over a 1 s window, rotated
  by a heading error (a constant bias, a linear drift and a random walk), scaled by a per-walk scale
  error that wanders slowly, plus correlated noise (:class:`VelocityErrorModel`).
- ``imu.csv`` -- a phone held in front of the chest: gait accelerations at the step frequency
  (vertical bounce, fore-aft surge, lateral sway at half the step frequency), the device orientation
  (``q``: device-to-ENU game rotation vector whose yaw drifts), gravity, sensor noise and biases.
- ``steps.csv`` -- the true footstep times; ``gnss.csv`` -- :mod:`curbside.evaluate.gnss_model`.
"""

from __future__ import annotations

import json
import logging
from dataclasses import asdict, dataclass
from pathlib import Path

import geopandas as gpd
import numpy as np
import pandas as pd
import shapely
from scipy.spatial.transform import Rotation
from tqdm.auto import tqdm

from curbside.errors import CurbsideInputError
from curbside.evaluate import routes as routes_mod
from curbside.evaluate.gnss_model import GnssErrorModel, simulate_gnss
from curbside.evaluate.osmsource import OsmSource, load_osm
from curbside.io import atomic_path
from curbside.localize.session import Session, write_session
from curbside.projection import WGS84, LocalFrame

log = logging.getLogger(__name__)

GRAVITY = 9.80665


@dataclass(frozen=True)
class WalkerModel:
    """How the simulated walker moves (values from gait literature; see docs/evaluate.md)."""

    #: Mean walking speed (m/s) and its spread between walks; legs vary by ``leg_speed_cv``.
    speed_mps: float = 1.35
    speed_sd_mps: float = 0.08
    leg_speed_cv: float = 0.05
    #: Step frequency (Hz) and its spread between walks.
    cadence_hz: float = 1.85
    cadence_sd_hz: float = 0.08
    #: Lateral wander off the straight legs: 1-sigma (m) and time constant (s).
    wander_m: float = 0.3
    wander_tau_s: float = 4.0


@dataclass(frozen=True)
class VelocityErrorModel:
    """RoNIN-like velocity errors (magnitudes from RoNIN's reported ATE/RTE; see docs/evaluate.md)."""

    #: Output rate (Hz) and averaging window (s).
    rate_hz: float = 10.0
    window_s: float = 1.0
    #: Heading error: constant bias 1-sigma (deg), linear drift 1-sigma (deg/min),
    #: random walk (deg/sqrt(min)).
    heading_bias_deg: float = 4.0
    heading_drift_deg_per_min: float = 1.0
    heading_walk_deg_per_sqrt_min: float = 2.0
    #: Scale error: 1-sigma of the per-walk scale, and of its slow wander (time constant 60 s).
    scale_sd: float = 0.06
    scale_wander_sd: float = 0.03
    #: Velocity noise 1-sigma per axis (m/s), correlated over ``noise_tau_s``.
    noise_mps: float = 0.12
    noise_tau_s: float = 1.0


@dataclass(frozen=True)
class ImuModel:
    """A hand-held phone's IMU (noise and bias magnitudes of consumer MEMS, e.g. Bosch BMI160)."""

    rate_hz: float = 100.0
    #: Gait acceleration amplitudes (m/s^2): vertical bounce, fore-aft surge, lateral sway.
    bounce: float = 2.0
    surge: float = 1.0
    sway: float = 0.5
    #: Phone pitch (deg; screen tilted up toward the face) and hand sway in yaw (deg).
    pitch_deg: float = 35.0
    hand_yaw_deg: float = 3.0
    accel_noise: float = 0.05
    accel_bias: float = 0.05
    gyro_noise: float = 0.01
    gyro_bias: float = 0.003


def _ou(n: int, dt: float, tau: float, rng: np.random.Generator) -> np.ndarray:
    """Unit-variance Ornstein-Uhlenbeck samples (exact AR(1) discretisation) via a linear filter."""
    from scipy.signal import lfilter

    phi = np.exp(-dt / tau)
    noise = rng.standard_normal(n) * np.sqrt(1 - phi**2)
    noise[0] = rng.standard_normal()
    return lfilter([1.0], [1.0, -phi], noise)


@dataclass
class Walk:
    """The true motion of one simulated walk, sampled at ``rate_hz``."""

    t: np.ndarray
    xy: np.ndarray
    waypoint_t: np.ndarray
    waypoint_xy: np.ndarray
    step_t: np.ndarray
    cadence_hz: float
    speed_mps: float


def simulate_walk(
    route: routes_mod.Route, walker: WalkerModel, rng: np.random.Generator, rate_hz: float = 100.0
) -> Walk:
    """Walk ``route`` at a constant speed per leg; return the true path at ``rate_hz``.

    Parameters
    ----------
    route
        Waypoints in the local frame.
    walker
        Speed, cadence and wander.
    rng
        Seeded generator.
    rate_hz
        Sampling rate of the returned path.
    """
    wp = route.xy
    legs = np.hypot(*np.diff(wp, axis=0).T)
    speed = max(0.6, rng.normal(walker.speed_mps, walker.speed_sd_mps))
    leg_speed = speed * np.clip(1 + walker.leg_speed_cv * rng.standard_normal(len(legs)), 0.7, 1.3)
    wt = np.concatenate([[0.0], np.cumsum(legs / leg_speed)])
    dt = 1.0 / rate_hz
    t = np.arange(0.0, wt[-1] + dt / 2, dt)
    x = np.interp(t, wt, wp[:, 0])
    y = np.interp(t, wt, wp[:, 1])
    leg = np.clip(np.searchsorted(wt, t, side="right") - 1, 0, len(legs) - 1)
    direction = np.diff(wp, axis=0) / np.maximum(legs, 1e-9)[:, None]
    normal = np.column_stack([-direction[:, 1], direction[:, 0]])[leg]
    # the wander fades out within 3 m of each waypoint: the walker taps at the waypoint itself
    dist_to_wp = np.minimum(t - wt[leg], wt[leg + 1] - t) * leg_speed[leg]
    fade = np.clip(dist_to_wp / 3.0, 0, 1)
    offset = walker.wander_m * _ou(len(t), dt, walker.wander_tau_s, rng) * fade
    xy = np.column_stack([x, y]) + normal * offset[:, None]
    cadence = max(1.4, rng.normal(walker.cadence_hz, walker.cadence_sd_hz))
    n_steps = int(wt[-1] * cadence)
    step_t = (np.arange(1, n_steps + 1) / cadence) + rng.normal(0, 0.01, n_steps)
    step_t = np.sort(np.clip(step_t, dt, t[-1]))
    return Walk(t, xy, wt, wp, step_t, cadence, speed)


def _window_mean(values: np.ndarray, n: int) -> np.ndarray:
    """Centred moving average over ``n`` samples (edges shrink the window)."""
    kernel = np.ones(n)
    num = np.apply_along_axis(lambda c: np.convolve(c, kernel, mode="same"), 0, values)
    den = np.convolve(np.ones(len(values)), kernel, mode="same")
    return num / den[:, None]


def simulate_velocity(walk: Walk, model: VelocityErrorModel, rng: np.random.Generator) -> pd.DataFrame:
    """RoNIN-like world-frame velocity ``t, ve, vn`` along a walk (see :class:`VelocityErrorModel`)."""
    dt = walk.t[1] - walk.t[0]
    v_true = np.gradient(walk.xy, dt, axis=0)
    v_smooth = _window_mean(v_true, max(1, int(round(model.window_s / dt))))
    stride = max(1, int(round(1.0 / (model.rate_hz * dt))))
    t = walk.t[::stride]
    v = v_smooth[::stride]
    n = len(t)
    step = stride * dt
    minutes = t / 60.0
    heading = np.radians(
        model.heading_bias_deg * rng.standard_normal()
        + model.heading_drift_deg_per_min * rng.standard_normal() * minutes
        + model.heading_walk_deg_per_sqrt_min * np.cumsum(rng.standard_normal(n)) * np.sqrt(step / 60.0)
    )
    scale = 1 + model.scale_sd * rng.standard_normal() + model.scale_wander_sd * _ou(n, step, 60.0, rng)
    c, s = np.cos(heading), np.sin(heading)
    # heading error is clockwise-positive (a compass bearing error): rotate (e, n) by -heading
    ve = scale * (c * v[:, 0] + s * v[:, 1])
    vn = scale * (-s * v[:, 0] + c * v[:, 1])
    ve += model.noise_mps * _ou(n, step, model.noise_tau_s, rng)
    vn += model.noise_mps * _ou(n, step, model.noise_tau_s, rng)
    return pd.DataFrame({"t": np.round(t, 3), "ve": ve, "vn": vn})


def simulate_imu(
    walk: Walk, model: ImuModel, vel_model: VelocityErrorModel, rng: np.random.Generator
) -> pd.DataFrame:
    """Phone IMU ``t, ax..gz, qx..qw`` at ``model.rate_hz`` along a walk.

    The phone points along the walking direction (device +y forward, screen tilted up by
    ``pitch_deg``), swaying a little in the hand. ``q`` is the device-to-ENU quaternion with a yaw
    error that drifts like :class:`VelocityErrorModel`'s heading error.
    """
    dt_walk = walk.t[1] - walk.t[0]
    stride = max(1, int(round(1.0 / (model.rate_hz * dt_walk))))
    t = walk.t[::stride]
    dt = stride * dt_walk
    xy = walk.xy[::stride]
    n = len(t)
    v = _window_mean(np.gradient(xy, dt, axis=0), max(1, int(round(0.5 / dt))))
    speed = np.hypot(*v.T)
    heading = np.unwrap(np.arctan2(v[:, 0], v[:, 1]))  # clockwise from north
    heading = _window_mean(heading[:, None], max(1, int(round(0.5 / dt))))[:, 0]
    phase = 2 * np.pi * walk.cadence_hz * t
    moving = np.clip(speed / max(walk.speed_mps, 1e-6), 0, 1)
    fwd = np.column_stack([np.sin(heading), np.cos(heading)])
    right = np.column_stack([fwd[:, 1], -fwd[:, 0]])
    a_h = np.gradient(v, dt, axis=0)
    a_world = np.zeros((n, 3))
    a_world[:, :2] = (
        a_h
        + (fwd * (model.surge * np.sin(phase))[:, None] + right * (model.sway * np.sin(phase / 2))[:, None])
        * moving[:, None]
    )
    a_world[:, 2] = model.bounce * np.cos(phase) * moving
    yaw_hand = np.radians(model.hand_yaw_deg) * np.sin(phase / 2 + 0.3)
    # device-to-ENU: yaw about Up (heading is clockwise, ENU yaw counter-clockwise), then pitch about x
    true_rot = Rotation.from_euler(
        "ZX", np.column_stack([-(heading + yaw_hand), np.full(n, np.radians(model.pitch_deg))])
    )
    specific = a_world + [0.0, 0.0, GRAVITY]
    acc = true_rot.inv().apply(specific)
    acc += model.accel_bias * rng.standard_normal(3) + model.accel_noise * rng.standard_normal((n, 3))
    rel = (true_rot[:-1].inv() * true_rot[1:]).as_rotvec() / dt
    gyro = np.vstack([rel, rel[-1:]])
    gyro += model.gyro_bias * rng.standard_normal(3) + model.gyro_noise * rng.standard_normal((n, 3))
    minutes = t / 60.0
    yaw_err = np.radians(
        vel_model.heading_bias_deg * rng.standard_normal()
        + vel_model.heading_drift_deg_per_min * rng.standard_normal() * minutes
        + vel_model.heading_walk_deg_per_sqrt_min * np.cumsum(rng.standard_normal(n)) * np.sqrt(dt / 60.0)
    )
    reported = Rotation.from_euler("Z", -yaw_err[:, None]) * true_rot
    q = reported.as_quat()  # x, y, z, w
    q *= np.where(q[:, 3:] < 0, -1.0, 1.0)
    return pd.DataFrame(
        {
            "t": np.round(t, 4),
            "ax": acc[:, 0],
            "ay": acc[:, 1],
            "az": acc[:, 2],
            "gx": gyro[:, 0],
            "gy": gyro[:, 1],
            "gz": gyro[:, 2],
            "qx": q[:, 0],
            "qy": q[:, 1],
            "qz": q[:, 2],
            "qw": q[:, 3],
        }
    )


@dataclass(frozen=True)
class SimulationConfig:
    """Everything that shapes a simulated session besides the route and the seed."""

    walker: WalkerModel = WalkerModel()
    velocity: VelocityErrorModel = VelocityErrorModel()
    imu: ImuModel = ImuModel()
    gnss: GnssErrorModel = GnssErrorModel()
    write_velocity: bool = True
    write_imu: bool = False
    write_steps: bool = True

    def as_dict(self) -> dict:
        """JSON-ready parameters (recorded in each session's ``meta.json``)."""
        return asdict(self)


def simulate_session(
    route: routes_mod.Route,
    osm: OsmSource,
    frame: LocalFrame,
    seed: int,
    config: SimulationConfig | None = None,
    name: str | None = None,
) -> Session:
    """One simulated recording of ``route``.

    Parameters
    ----------
    route
        The route (local frame of ``osm``).
    osm
        Buildings with heights (for the GNSS model).
    frame
        The local frame (to write lat/lon).
    seed
        Seed for the walker and every sensor; the same seed gives the same session.
    config
        Models and which files to write.
    name
        Session name (default ``<route>-s<seed>``).

    Returns
    -------
    Session
        With ``waypoints``, ``gnss`` and, per ``config``, ``velocity``, ``imu``, ``steps``;
        ``meta`` holds the start pose and the simulation parameters.
    """
    config = config or SimulationConfig()
    # one independent stream per component: writing imu.csv or not leaves the other files unchanged
    walk_rng, vel_rng, imu_rng, gnss_rng = (
        np.random.default_rng(s) for s in np.random.SeedSequence([seed, 0x5EED]).spawn(4)
    )
    walk = simulate_walk(route, config.walker, walk_rng)
    velocity = simulate_velocity(walk, config.velocity, vel_rng) if config.write_velocity else None
    imu = simulate_imu(walk, config.imu, config.velocity, imu_rng) if config.write_imu else None
    gnss_stride = max(1, int(round(1.0 / (config.gnss.rate_hz * (walk.t[1] - walk.t[0])))))
    fixes = simulate_gnss(walk.t[::gnss_stride], walk.xy[::gnss_stride], osm, config.gnss, gnss_rng)
    lon, lat = frame.to_lonlat(fixes["x_m"].to_numpy(), fixes["y_m"].to_numpy())
    gnss = pd.DataFrame(
        {"t": np.round(fixes["t"], 3), "lat": lat, "lon": lon, "accuracy_m": fixes["accuracy_m"]}
    )
    wlon, wlat = frame.to_lonlat(walk.waypoint_xy[:, 0], walk.waypoint_xy[:, 1])
    waypoints = pd.DataFrame({"t": np.round(walk.waypoint_t, 3), "lat": wlat, "lon": wlon})
    first = walk.waypoint_xy[1] - walk.waypoint_xy[0]
    meta = {
        "start": {
            "lat": float(wlat[0]),
            "lon": float(wlon[0]),
            "heading_deg": float(np.degrees(np.arctan2(first[0], first[1])) % 360),
        },
        "simulation": {
            "route": route.spec.name,
            "area": route.spec.area,
            "seed": int(seed),
            "route_seed": int(route.seed),
            "length_m": round(route.length_m, 1),
            "crosswalk_crossings": route.crossings,
            "jaywalks": route.jaywalks,
            "covered_share": round(route.covered_share, 3),
            "speed_mps": round(walk.speed_mps, 3),
            "cadence_hz": round(walk.cadence_hz, 3),
            "gnss_wrong_side_share": round(float(fixes["wrong_side"].mean()), 3),
            "gnss_outlier_share": round(float(fixes["outlier"].mean()), 3),
            "gnss_fixes": len(fixes),
            "config": config.as_dict(),
        },
    }
    steps = pd.DataFrame({"t": np.round(walk.step_t, 3)}) if config.write_steps else None
    return Session(
        name=name or f"{route.spec.name}-s{seed}",
        imu=imu,
        velocity=velocity,
        steps=steps,
        gnss=gnss,
        waypoints=waypoints,
        meta=meta,
    )


def sf6_routes(osm: OsmSource | None = None) -> tuple[list[routes_mod.Route], LocalFrame, OsmSource]:
    """The benchmark's six routes (deterministic: each has a fixed route seed)."""
    osm = osm or load_osm()
    frame = LocalFrame(osm.crs)
    wg = routes_mod.build_walk_graph(osm)
    out = [routes_mod.generate_route(wg, spec, frame, seed=1) for spec in routes_mod.SF6]
    return out, frame, osm


def routes_geojson(route_list: list[routes_mod.Route], frame: LocalFrame) -> gpd.GeoDataFrame:
    """Routes as WGS84 LineStrings with their Table-1 attributes."""
    lines = [
        shapely.linestrings(np.column_stack(frame.to_lonlat(r.xy[:, 0], r.xy[:, 1]))) for r in route_list
    ]
    return gpd.GeoDataFrame(
        {
            "name": [r.spec.name for r in route_list],
            "area": [r.spec.area for r in route_list],
            "length_m": [round(r.length_m, 1) for r in route_list],
            "crosswalk_crossings": [r.crossings for r in route_list],
            "jaywalks": [r.jaywalks for r in route_list],
            "covered_share": [round(r.covered_share, 3) for r in route_list],
        },
        geometry=lines,
        crs=WGS84,
    )


def simulate_benchmark(
    out_dir: str | Path,
    seeds: int | list[int] = 3,
    config: SimulationConfig | None = None,
    osm_file: str | Path | None = None,
) -> list[Path]:
    """Write the six SF benchmark walks, ``seeds`` recordings each, as SPEC session folders.

    Parameters
    ----------
    out_dir
        Destination; gets ``<path>-s<seed>/`` folders, ``routes.geojson`` and ``benchmark.json``.
    seeds
        A count (seeds ``1..n``) or explicit seeds.
    config
        Simulation models.
    osm_file
        OSM extract for heights and footways (default the bundled one).

    Returns
    -------
    list of pathlib.Path
        The session folders, in route then seed order.
    """
    seed_list = list(range(1, seeds + 1)) if isinstance(seeds, int) else [int(s) for s in seeds]
    if not seed_list:
        raise CurbsideInputError("--seeds", "need at least one seed")
    out_dir = Path(out_dir)
    route_list, frame, osm = sf6_routes(load_osm(osm_file))
    out_dir.mkdir(parents=True, exist_ok=True)
    written = []
    jobs = [(r, s) for r in route_list for s in seed_list]
    for route, seed in tqdm(jobs, desc="simulate", unit="session", disable=None):
        session = simulate_session(route, osm, frame, seed, config)
        written.append(write_session(session, out_dir / session.name))
    table = routes_geojson(route_list, frame)
    with atomic_path(out_dir / "routes.geojson") as tmp:
        tmp.write_text(table.to_json(), encoding="utf-8")
    summary = {
        "benchmark": "sf6",
        "seeds": seed_list,
        "sessions": [p.name for p in written],
        "routes": json.loads(table.drop(columns="geometry").to_json(orient="records")),
        "config": (config or SimulationConfig()).as_dict(),
    }
    with atomic_path(out_dir / "benchmark.json") as tmp:
        tmp.write_text(json.dumps(summary, indent=2), encoding="utf-8")
    log.info("wrote %d sessions to %s", len(written), out_dir)
    return written
