"""The benchmark's subsets and splits: which routes and which sessions, reproducible by name.

Three subsets, each drawn on the real downtown San Francisco map (the bundled OSM extract):

``paper6``
    The six routes shaped like the paper's Table 1 (:data:`curbside.evaluate.routes.SF6`).
``downtown``
    Random routes in the downtown core (FiDi and SoMa north of Folsom, where the extract maps the
    buildings): a random start, 300-700 m, 0-4 crosswalk crossings and 0-2 jaywalks.
``open``
    Random routes on streets under open sky, chosen with the GNSS model's own sky mask: the mean
    across-street blockage along the route at most :data:`OPEN_MAX_SEVERITY`, nowhere above
    :data:`OPEN_PEAK_SEVERITY`, nothing under cover. In this extract those are the Embarcadero and
    the streets south of Folsom, where OSM maps few buildings (so the map is open too). The realised
    GNSS error of every session is in its ``meta.json`` and in the report.

Two disjoint splits: ``test`` (what the benchmark scores) and ``tune`` (what parameters may be chosen
on). They differ in their route seeds (so ``paper6`` has other routes of the same shape, and the
random subsets other random routes) and in their session seeds (``test``: 1..n, ``tune``:
101..100+n). Each session's simulator seed is derived from (subset, split, route, session seed), so
no two sessions share their random draws.
"""

from __future__ import annotations

import functools
import json
import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import shapely
from scipy.spatial import cKDTree
from tqdm.auto import tqdm

from curbside.errors import CurbsideInputError
from curbside.evaluate import routes as routes_mod
from curbside.evaluate.gnss_model import GnssErrorModel, canyon_axes, sky_mask
from curbside.evaluate.osmsource import OsmSource, load_osm
from curbside.evaluate.simulate import SimulationConfig, routes_geojson, simulate_session
from curbside.evaluate.subset_names import DEFAULT_ROUTES, SPLITS, SUBSETS
from curbside.io import atomic_path
from curbside.localize.session import write_session
from curbside.projection import LocalFrame

log = logging.getLogger(__name__)

#: First session seed of each split (seeds are ``first .. first + n - 1``; at most 100 per split).
FIRST_SESSION_SEED: dict[str, int] = {"test": 1, "tune": 101}
MAX_SEEDS = 100
#: Route seed of the ``paper6`` routes per split (seed 1: the routes of ``localize simulate --benchmark``).
PAPER6_ROUTE_SEED: dict[str, int] = {"test": 1, "tune": 2}
#: Where the extract's buildings give a true sky (west, south, east, north; WGS84): its building
#: bounds (lon -122.4125..-122.3850, lat 37.7800..37.8020; few buildings south of 37.783 and east of
#: -122.389) less the sky mask's reach. Random routes stay inside.
SKY_BBOX: tuple[float, float, float, float] = (-122.4105, 37.7845, -122.3905, 37.8005)
#: The downtown core where random ``downtown`` routes start (FiDi and SoMa north of Folsom).
DOWNTOWN_BBOX: tuple[float, float, float, float] = (-122.4080, 37.7850, -122.3905, 37.7990)
#: Open sky: route mean and peak of the across-street sky blockage (0 open, 1 blocked to the zenith).
#: At 0.2 the GNSS model's per-axis sigma is 3.6 m against 3 m under a fully open sky.
OPEN_MAX_SEVERITY = 0.20
OPEN_PEAK_SEVERITY = 0.45
#: ... and built up: this share of the route has a mapped building within ``BUILT_DISTANCE_M``, so
#: the open streets are wide streets and low buildings, not the extract's unmapped blocks.
OPEN_MIN_BUILT_SHARE = 0.3
BUILT_DISTANCE_M = 30.0
#: Random routes: length range (m), crosswalk crossings and jaywalks (inclusive ranges; for ``open``
#: routes, whose streets are few, the counts are maxima).
RANDOM_LENGTH_M: tuple[float, float] = (300.0, 700.0)
OPEN_LENGTH_M: tuple[float, float] = (250.0, 500.0)
RANDOM_CROSSINGS: tuple[int, int] = (0, 4)
RANDOM_JAYWALKS: tuple[int, int] = (0, 2)
_TAG = {"paper6": 6, "downtown": 7, "open": 8}
_SPLIT_CODE = {"test": 1, "tune": 2}


@dataclass
class World:
    """What route drawing needs, computed once: the OSM source, frame, walking graph, node sky.

    ``node_severity``, ``node_covered`` and ``node_built`` describe each graph node (in ``nodes``
    order): the GNSS model's across-street sky blockage there, whether it is under cover, and
    whether a mapped building lies within :data:`BUILT_DISTANCE_M`.
    """

    osm: OsmSource
    frame: LocalFrame
    graph: routes_mod.WalkGraph
    nodes: np.ndarray
    node_severity: np.ndarray
    node_covered: np.ndarray
    node_built: np.ndarray

    def __post_init__(self) -> None:
        self._tree = cKDTree(self.graph.xy[self.nodes])

    def at(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Severity, cover and built-up flags of the graph node nearest to each position."""
        _, i = self._tree.query(np.asarray(xy, float).reshape(-1, 2))
        return self.node_severity[i], self.node_covered[i], self.node_built[i]

    @functools.cached_property
    def in_sky_bbox(self) -> np.ndarray:
        """Whether each node lies inside :data:`SKY_BBOX`."""
        xy = self.graph.xy[self.nodes]
        lon, lat = self.frame.to_lonlat(xy[:, 0], xy[:, 1])
        west, south, east, north = SKY_BBOX
        return (lon >= west) & (lon <= east) & (lat >= south) & (lat <= north)

    def subgraph(self, keep: np.ndarray) -> routes_mod.WalkGraph:
        """The walking graph on the nodes where ``keep`` (in ``nodes`` order) holds."""
        kept = set(self.nodes[keep].tolist())
        jaywalk = {k: v for k, v in self.graph.jaywalk.items() if set(k) <= kept and set(v[1]) <= kept}
        return routes_mod.WalkGraph(
            self.graph.graph.subgraph(kept).copy(), self.graph.xy, jaywalk, self.graph.covered
        )

    @functools.cached_property
    def core_graph(self) -> routes_mod.WalkGraph:
        """The walking graph inside :data:`SKY_BBOX` (where ``downtown`` routes run)."""
        return self.subgraph(self.in_sky_bbox)

    @functools.cached_property
    def open_graph(self) -> routes_mod.WalkGraph:
        """The core graph on open, uncovered nodes (where ``open`` routes run)."""
        return self.subgraph(
            self.in_sky_bbox & (self.node_severity <= OPEN_PEAK_SEVERITY) & ~self.node_covered
        )


@functools.lru_cache(maxsize=2)
def load_world(osm_file: str | None = None) -> World:
    """The benchmark's world from an OSM extract (default: the bundled one); cached per file."""
    osm = load_osm(osm_file)
    graph = routes_mod.build_walk_graph(osm)
    nodes = np.fromiter(graph.graph.nodes, np.int64)
    xy = graph.xy[nodes]
    mask = sky_mask(xy, osm, GnssErrorModel())
    tree = shapely.STRtree(osm.buildings.geometry.values)
    src, _ = tree.query(shapely.points(xy), predicate="dwithin", distance=BUILT_DISTANCE_M)
    built = np.zeros(len(xy), bool)
    built[src] = True
    return World(osm, LocalFrame(osm.crs), graph, nodes, canyon_axes(mask)[1], mask.covered, built)


def session_seeds(split: str, n: int) -> tuple[int, ...]:
    """The session seeds of a split: ``test`` 1..n, ``tune`` 101..100+n."""
    _check_split(split)
    if not 1 <= n <= MAX_SEEDS:
        raise CurbsideInputError("--seeds", f"need 1 to {MAX_SEEDS} seeds per route, got {n}")
    first = FIRST_SESSION_SEED[split]
    return tuple(range(first, first + n))


def simulator_seed(subset: str, split: str, route_index: int, seed: int) -> int:
    """The simulator seed of one session: distinct for every (subset, split, route, session seed)."""
    return int(
        np.random.SeedSequence([_TAG[subset], _SPLIT_CODE[split], route_index, seed]).generate_state(1)[0]
    )


def _check_split(split: str) -> None:
    if split not in SPLITS:
        raise CurbsideInputError("--split", f"unknown split {split!r}; one of {list(SPLITS)}")


def _check_subset(subset: str) -> None:
    if subset not in SUBSETS:
        raise CurbsideInputError("--subsets", f"unknown subset {subset!r}; one of {list(SUBSETS)}")


def _open_sky(world: World, pts: np.ndarray, spacing_m: float = 5.0) -> tuple[bool, float]:
    """Whether a polyline runs along built-up streets under open sky, and its mean blockage.

    Sampled every ``spacing_m``; each sample takes the values of its nearest graph node.
    """
    line = shapely.linestrings(pts)
    dist = np.arange(0.0, line.length, spacing_m)
    sev, covered, built = world.at(shapely.get_coordinates(shapely.line_interpolate_point(line, dist)))
    ok = (
        sev.mean() <= OPEN_MAX_SEVERITY
        and sev.max() <= OPEN_PEAK_SEVERITY
        and not covered.any()
        and built.mean() >= OPEN_MIN_BUILT_SHARE
    )
    return bool(ok), float(sev.mean())


def _start_nodes(world: World, subset: str) -> np.ndarray:
    """Graph nodes where a random route of ``subset`` may start."""
    if subset == "downtown":
        xy = world.graph.xy[world.nodes]
        lon, lat = world.frame.to_lonlat(xy[:, 0], xy[:, 1])
        west, south, east, north = DOWNTOWN_BBOX
        keep = (lon >= west) & (lon <= east) & (lat >= south) & (lat <= north)
        graph = world.core_graph
    else:
        keep = world.node_severity <= OPEN_MAX_SEVERITY
        graph = world.open_graph
    return world.nodes[keep & np.isin(world.nodes, list(graph.graph.nodes))]


def random_route(world: World, subset: str, split: str, index: int, max_specs: int = 60) -> routes_mod.Route:
    """Route ``index`` of a random subset (``downtown`` or ``open``) in a split (deterministic).

    Draws a request (start, length, crossings, jaywalks) and a route that satisfies it, drawing a
    new request when none does. ``open`` routes run on :attr:`World.open_graph`, must pass
    :func:`_open_sky` and take their counts as maxima; ``downtown`` routes run on
    :attr:`World.core_graph` with exact counts.
    """
    rng = np.random.default_rng([_TAG[subset], _SPLIT_CODE[split], index])
    starts = _start_nodes(world, subset)
    is_open = subset == "open"
    graph = world.open_graph if is_open else world.core_graph
    name = f"{subset}-{'' if split == 'test' else 't'}{index + 1:02d}"
    for _ in range(max_specs):
        node = int(rng.choice(starts))
        lon, lat = world.frame.to_lonlat(world.graph.xy[node, 0], world.graph.xy[node, 1])
        spec = routes_mod.RouteSpec(
            name,
            (float(lon), float(lat)),
            float(np.round(rng.uniform(*(OPEN_LENGTH_M if is_open else RANDOM_LENGTH_M)))),
            int(rng.integers(RANDOM_CROSSINGS[0], RANDOM_CROSSINGS[1] + 1)),
            int(rng.integers(RANDOM_JAYWALKS[0], RANDOM_JAYWALKS[1] + 1)),
            subset,
            start_radius_m=1.0,
        )
        seed = int(rng.integers(2**31))
        accept = (lambda pts: _open_sky(world, pts)[0]) if is_open else None
        try:
            route = routes_mod.generate_route(
                graph, spec, world.frame, seed, 1000, accept, exact_counts=not is_open
            )
        except CurbsideInputError:
            continue
        route.extra["sky_severity_mean"] = round(_open_sky(world, route.xy)[1], 3)
        return route
    raise CurbsideInputError(name, f"no {subset} route found for {max_specs} random requests")


def benchmark_routes(
    subset: str, split: str = "test", n_routes: int | None = None, world: World | None = None
) -> list[routes_mod.Route]:
    """The routes of a subset in a split (deterministic, reproducible by name).

    Parameters
    ----------
    subset
        ``paper6``, ``downtown`` or ``open``.
    split
        ``test`` or ``tune``.
    n_routes
        Routes of a random subset (default :data:`DEFAULT_ROUTES`); ``paper6`` always has six.
    world
        A :func:`load_world` result (default: the bundled extract).
    """
    _check_subset(subset)
    _check_split(split)
    world = world or load_world()
    if subset == "paper6":
        seed = PAPER6_ROUTE_SEED[split]
        out = [routes_mod.generate_route(world.graph, spec, world.frame, seed) for spec in routes_mod.SF6]
        for route in out:
            route.extra["sky_severity_mean"] = round(_open_sky(world, route.xy)[1], 3)
        return out
    n = DEFAULT_ROUTES[subset] if n_routes is None else n_routes
    if n < 1:
        raise CurbsideInputError("--routes", f"need at least one route, got {n}")
    return [random_route(world, subset, split, i) for i in range(n)]


def _reusable(folder: Path, expected: dict) -> bool:
    """Whether ``folder`` holds the session ``expected`` describes; refuses to touch foreign folders."""
    meta_path = folder / "meta.json"
    if not folder.exists():
        return False
    sim = json.loads(meta_path.read_text()).get("simulation") if meta_path.is_file() else None
    if sim is None:
        raise CurbsideInputError(folder, "exists and is not a curbside simulated session; not overwriting it")
    return all(sim.get(k) == v for k, v in expected.items())


def benchmark_sessions(
    out_dir: str | Path,
    subset: str,
    split: str = "test",
    profile: str = "phone",
    seeds: int = 3,
    n_routes: int | None = None,
    world: World | None = None,
    write_imu: bool = False,
    config: SimulationConfig | None = None,
) -> list[Path]:
    """Simulate (or reuse) every session of a subset and split into ``out_dir``.

    Parameters
    ----------
    out_dir
        Gets ``<route>-s<seed>/`` session folders, ``routes.geojson`` and ``benchmark.json``. A
        session folder already there is reused when its ``meta.json`` records the same route,
        seeds, profile and parameters, and simulated again otherwise.
    subset, split
        Which routes (:func:`benchmark_routes`) and which session seeds (:func:`session_seeds`).
    profile
        ``phone`` (the benchmark's default) or ``nominal``.
    seeds
        Sessions per route.
    n_routes
        Routes of a random subset.
    world
        A :func:`load_world` result.
    write_imu
        Also write ``imu.csv``.
    config
        Simulation models in place of ``profile``'s (e.g. to calibrate one component); the
        sessions' seeds stay those of the subset and split.

    Returns
    -------
    list of pathlib.Path
        Session folders, in route then seed order.
    """
    seed_list = session_seeds(split, seeds)
    world = world or load_world()
    config = config or SimulationConfig(profile=profile, write_imu=write_imu)
    route_list = benchmark_routes(subset, split, n_routes, world)
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    written, reused = [], 0
    config_dict = json.loads(json.dumps(config.as_dict()))
    jobs = [(i, r, s) for i, r in enumerate(route_list) for s in seed_list]
    for i, route, seed in tqdm(jobs, desc=f"simulate {subset}", unit="session", disable=None):
        folder = out_dir / f"{route.spec.name}-s{seed}"
        sim_seed = simulator_seed(subset, split, i, seed)
        expected = {
            "route": route.spec.name,
            "seed": sim_seed,
            "route_seed": route.seed,
            "config": config_dict,
        }
        if _reusable(folder, expected):
            written.append(folder)
            reused += 1
            continue
        session = simulate_session(route, world.osm, world.frame, sim_seed, config, name=folder.name)
        session.meta["simulation"].update({"subset": subset, "split": split, "session_seed": seed})
        written.append(write_session(session, folder))
    _write_manifest(out_dir, subset, split, seed_list, written, route_list, world, config_dict)
    log.info("%s/%s: %d sessions (%d reused) in %s", subset, split, len(written), reused, out_dir)
    return written


def _write_manifest(
    out_dir: Path,
    subset: str,
    split: str,
    seed_list: tuple[int, ...],
    written: list[Path],
    route_list: list[routes_mod.Route],
    world: World,
    config_dict: dict,
) -> None:
    """``routes.geojson`` and ``benchmark.json`` (subset, split, seeds, sessions, routes, parameters)."""
    table = routes_geojson(route_list, world.frame)
    with atomic_path(out_dir / "routes.geojson") as tmp:
        tmp.write_text(table.to_json(), encoding="utf-8")
    routes = [
        {
            "name": r.spec.name,
            "route_seed": r.seed,
            "length_m": round(r.length_m, 1),
            "crossings": r.crossings,
            "jaywalks": r.jaywalks,
            **r.extra,
        }
        for r in route_list
    ]
    manifest = {
        "subset": subset,
        "split": split,
        "profile": config_dict["profile"],
        "session_seeds": list(seed_list),
        "sessions": [p.name for p in written],
        "routes": routes,
        "config": config_dict,
    }
    with atomic_path(out_dir / "benchmark.json") as tmp:
        tmp.write_text(json.dumps(manifest, indent=2), encoding="utf-8")
