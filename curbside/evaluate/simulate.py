"""Simulated sessions: a walker on a route, with ground-truth taps, RoNIN-like velocity, IMU and GNSS.

The walker (:mod:`curbside.evaluate.walker`) follows the route's waypoints and taps each one on
arrival (``waypoints.csv``), as in the paper; where it stops at a kerb it taps again on departure.
Sensors see the true path:

- ``velocity.csv`` -- what RoNIN would output (:mod:`curbside.evaluate.inertial_model`): the true
  velocity averaged over a 1 s window, rotated by a heading error, scaled by a speed-scale error,
  plus noise -- and, in the ``phone`` profile, heading jumps and phantom motion while standing.
- ``imu.csv`` -- a phone held in front of the chest: gait accelerations at the step frequency, the
  device orientation (``q``, whose yaw carries the same heading error), gravity, noise and biases.
- ``steps.csv`` -- the true footstep times (none while standing); ``gnss.csv`` --
  :mod:`curbside.evaluate.gnss_model` (the same urban-canyon model in every profile).

Two profiles (:data:`PROFILES`): ``nominal`` (RoNIN's published error levels, no stops) and ``phone``
(a phone in a hand downtown; each magnitude's source is documented on its dataclass field).
``meta.json``'s ``simulation`` block records the profile, every parameter and the realised events
(heading bias, drift, jumps with their times and sizes, speed scale, stops).
"""

from __future__ import annotations

import json
import logging
from dataclasses import asdict, dataclass, fields
from pathlib import Path

import geopandas as gpd
import numpy as np
import pandas as pd
import shapely
from tqdm.auto import tqdm

from curbside import settings
from curbside.errors import CurbsideInputError
from curbside.evaluate import routes as routes_mod
from curbside.evaluate.gnss_model import GnssErrorModel, simulate_gnss
from curbside.evaluate.inertial_model import (
    GRAVITY,
    ImuModel,
    InertialErrors,
    PhoneVelocityErrorModel,
    VelocityErrorModel,
    inertial_errors,
    simulate_imu,
    simulate_velocity,
)
from curbside.evaluate.osmsource import OsmSource, load_osm
from curbside.evaluate.walker import PhoneWalkerModel, Walk, WalkerModel, simulate_walk
from curbside.io import atomic_path
from curbside.localize.session import Session, write_session
from curbside.projection import WGS84, LocalFrame

__all__ = [
    "GRAVITY",
    "PROFILES",
    "ImuModel",
    "OsmSource",
    "PhoneVelocityErrorModel",
    "PhoneWalkerModel",
    "SimulationConfig",
    "VelocityErrorModel",
    "WalkerModel",
    "routes_geojson",
    "sf6_routes",
    "simulate_benchmark",
    "simulate_imu",
    "simulate_session",
    "simulate_velocity",
    "simulate_walk",
]

log = logging.getLogger(__name__)

#: The simulation profiles: walker and velocity-error models by name.
PROFILES: dict[str, tuple[WalkerModel, VelocityErrorModel]] = {
    "nominal": (WalkerModel(), VelocityErrorModel()),
    "phone": (PhoneWalkerModel(), PhoneVelocityErrorModel()),
}


@dataclass(frozen=True)
class SimulationConfig:
    """Everything that shapes a simulated session besides the route and the seed.

    Attributes
    ----------
    profile
        ``nominal`` or ``phone`` (:data:`PROFILES`): the defaults of ``walker`` and ``velocity``.
    walker, velocity
        ``None``: the profile's models; a model given here overrides it.
    imu, gnss
        The IMU and the urban-canyon GNSS models (the same in every profile).
    write_velocity, write_imu, write_steps
        Which files the session gets.
    """

    profile: str = "nominal"
    walker: WalkerModel | None = None
    velocity: VelocityErrorModel | None = None
    imu: ImuModel = ImuModel()
    gnss: GnssErrorModel = GnssErrorModel()
    write_velocity: bool = True
    write_imu: bool = False
    write_steps: bool = True

    def __post_init__(self) -> None:
        if self.profile not in PROFILES:
            known = list(PROFILES)
            raise CurbsideInputError("--profile", f"unknown profile {self.profile!r}; one of {known}")
        walker, velocity = PROFILES[self.profile]
        if self.walker is None:
            object.__setattr__(self, "walker", walker)
        if self.velocity is None:
            object.__setattr__(self, "velocity", velocity)

    def as_dict(self) -> dict:
        """JSON-ready parameters (recorded in each session's ``meta.json``)."""
        out = {f.name: getattr(self, f.name) for f in fields(self)}
        return {k: asdict(v) if hasattr(v, "__dataclass_fields__") else v for k, v in out.items()}


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
        Profile, models and which files to write.
    name
        Session name (default ``<route>-s<seed>``).

    Returns
    -------
    Session
        With ``waypoints``, ``gnss`` and, per ``config``, ``velocity``, ``imu``, ``steps``;
        ``meta`` holds the start pose, the simulation parameters and the realised error events.
    """
    config = config or SimulationConfig()
    # one independent stream per component: writing imu.csv or not leaves the other files unchanged;
    # the phone profile's stops and error events have streams of their own, so nominal sessions are
    # the same as before those existed
    walk_rng, vel_rng, imu_rng, gnss_rng, stop_rng, event_rng = (
        np.random.default_rng(s) for s in np.random.SeedSequence([seed, 0x5EED]).spawn(6)
    )
    walk = simulate_walk(route, config.walker, walk_rng, stop_rng=stop_rng)
    errors = inertial_errors(walk, config.velocity, vel_rng, event_rng)
    velocity = simulate_velocity(walk, config.velocity, errors, vel_rng) if config.write_velocity else None
    imu = simulate_imu(walk, config.imu, errors, imu_rng) if config.write_imu else None
    gnss_stride = max(1, int(round(1.0 / (config.gnss.rate_hz * (walk.t[1] - walk.t[0])))))
    fixes = simulate_gnss(walk.t[::gnss_stride], walk.xy[::gnss_stride], osm, config.gnss, gnss_rng)
    lon, lat = frame.to_lonlat(fixes["x_m"].to_numpy(), fixes["y_m"].to_numpy())
    gnss = pd.DataFrame(
        {"t": np.round(fixes["t"], 3), "lat": lat, "lon": lon, "accuracy_m": fixes["accuracy_m"]}
    )
    wlon, wlat = frame.to_lonlat(walk.waypoint_xy[:, 0], walk.waypoint_xy[:, 1])
    waypoints = pd.DataFrame({"t": np.round(walk.waypoint_t, 3), "lat": wlat, "lon": wlon})
    meta = _session_meta(route, walk, fixes, errors, config, seed, (float(wlat[0]), float(wlon[0])))
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


def _session_meta(
    route: routes_mod.Route,
    walk: Walk,
    fixes: pd.DataFrame,
    errors: InertialErrors,
    config: SimulationConfig,
    seed: int,
    start_latlon: tuple[float, float],
) -> dict:
    """``meta.json`` of a simulated session: the start pose, the parameters, the realised events."""
    first = walk.waypoint_xy[1] - walk.waypoint_xy[0]
    gnss_err = np.hypot(fixes["x_m"] - fixes["true_x_m"], fixes["y_m"] - fixes["true_y_m"])
    events = {
        **errors.events,
        "stops": [
            {"t_s": round(s.t_s, 2), "wait_s": round(s.wait_s, 2), "waypoint": s.waypoint, "kind": s.kind}
            for s in walk.stops
        ],
    }
    return {
        "start": {
            "lat": start_latlon[0],
            "lon": start_latlon[1],
            "heading_deg": float(np.degrees(np.arctan2(first[0], first[1])) % 360),
        },
        "simulation": {
            "route": route.spec.name,
            "area": route.spec.area,
            "profile": config.profile,
            "seed": int(seed),
            "route_seed": int(route.seed),
            "length_m": round(route.length_m, 1),
            "crosswalk_crossings": route.crossings,
            "jaywalks": route.jaywalks,
            "covered_share": round(route.covered_share, 3),
            "speed_mps": round(walk.speed_mps, 3),
            "cadence_hz": round(walk.cadence_hz, 3),
            "duration_s": round(float(walk.t[-1]), 1),
            "gnss_wrong_side_share": round(float(fixes["wrong_side"].mean()), 3),
            "gnss_outlier_share": round(float(fixes["outlier"].mean()), 3),
            "gnss_fixes": len(fixes),
            "gnss_error_median_m": round(float(np.median(gnss_err)), 2) if len(fixes) else None,
            "route_extra": route.extra,
            "events": events,
            "config": config.as_dict(),
        },
    }


def sf6_routes(
    osm: OsmSource | None = None, source: str | Path | None = None, only: str | None = None
) -> tuple[list[routes_mod.Route], LocalFrame, OsmSource]:
    """The benchmark's six routes (deterministic: each has a fixed route seed), or the one named ``only``.

    Raises
    ------
    CurbsideInputError
        A route outside the extract ``osm`` (named by ``source``, its file; default: the bundled one).
    """
    osm = osm or load_osm(source)
    frame = LocalFrame(osm.crs)
    wg = routes_mod.build_walk_graph(osm)
    specs = [spec for spec in routes_mod.SF6 if only in (None, spec.name)]
    for spec in specs:
        far = routes_mod.far_from_footways(wg, spec, frame)
        if far:
            raise CurbsideInputError(
                source or settings.default_osm_file,
                f"route {spec.name} lies outside it: {far}; the benchmark's routes need downtown San "
                "Francisco (leave --osm out for the bundled extract)",
            )
    out = [routes_mod.generate_route(wg, spec, frame, seed=1) for spec in specs]
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
    route_list, frame, osm = sf6_routes(load_osm(osm_file), osm_file)
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
