"""Walking routes along real sidewalks and crossings, and the six San Francisco routes of the benchmark.

The walking graph is OSM's mapped pedestrian network: ``footway=sidewalk`` and ``footway=crossing``
ways, split at every vertex, joined where ways share a vertex. Jaywalks are extra edges: from the
middle of a sidewalk edge, straight across the carriageway (the segment must cross a road centreline
and no building) to the opposite sidewalk.

A route is drawn by a seeded random walk on that graph (no edge twice, a preference for going
straight on) that is accepted only when it has exactly the requested numbers of crosswalk crossings
and jaywalks, stays within ``radius_m`` of its start, and -- for routes that must lie under cover --
spends the requested share of its length inside a covered structure. The accepted walk is cut at the
requested length and simplified; its remaining vertices are the ground-truth waypoints (the turns).
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass, field

import networkx as nx
import numpy as np
import shapely
from tqdm.auto import tqdm

from curbside.errors import CurbsideInputError
from curbside.evaluate.osmsource import OsmSource
from curbside.projection import LocalFrame

log = logging.getLogger(__name__)

#: Vertices closer than this are the same graph node (metres).
_SNAP_M = 0.01


@dataclass(frozen=True)
class RouteSpec:
    """What a benchmark route must look like (the paper's Table 1 row plus where it is).

    Attributes
    ----------
    name
        ``path1`` ...
    start_lonlat
        Approximate start (WGS84); the walk starts at a graph node within ``start_radius_m``.
    length_m
        Route length.
    crossings
        Street crossings on marked crosswalks.
    jaywalks
        Street crossings not on crosswalks.
    area
        Free text for reports (``FiDi``, ``SoMa``...).
    covered_share
        Minimum share of the length inside a covered structure (the Transit Center); 0 for none.
    radius_m
        The route stays within this distance of its start.
    """

    name: str
    start_lonlat: tuple[float, float]
    length_m: float
    crossings: int
    jaywalks: int
    area: str
    covered_share: float = 0.0
    radius_m: float = 320.0
    start_radius_m: float = 80.0


@dataclass
class Route:
    """A generated route: a polyline in the local frame and what it crosses.

    Attributes
    ----------
    spec
        The request it satisfies.
    xy
        ``(n, 2)`` waypoints in metres (the simplified polyline: each vertex is a turn).
    kinds
        ``(n - 1,)`` kind of each leg: ``sidewalk``, ``crossing`` or ``jaywalk``.
    crossings, jaywalks
        Counts realised.
    covered_share
        Share of the length inside a covered structure.
    seed
        The walk's seed.
    """

    spec: RouteSpec
    xy: np.ndarray
    kinds: np.ndarray
    crossings: int
    jaywalks: int
    covered_share: float
    seed: int
    attempts: int = 0
    extra: dict = field(default_factory=dict)

    @property
    def length_m(self) -> float:
        """Length of the polyline."""
        return float(np.hypot(*np.diff(self.xy, axis=0).T).sum())


@dataclass
class WalkGraph:
    """The pedestrian graph with node coordinates, edge kinds and jaywalk partners."""

    graph: nx.Graph
    xy: np.ndarray
    #: for a sidewalk edge (u, v) with u < v: (point on the edge, (a, b) partner edge, point on it)
    jaywalk: dict[tuple[int, int], tuple[np.ndarray, tuple[int, int], np.ndarray]]
    covered: shapely.Geometry


def build_walk_graph(osm: OsmSource, covered_min_height_m: float = 15.0) -> WalkGraph:
    """Build the walking graph from an :class:`~curbside.evaluate.osmsource.OsmSource`.

    Parameters
    ----------
    osm
        Footways, roads and buildings in the local frame.
    covered_min_height_m
        Footways inside a building footprint at least this tall count as covered (the Transit Center
        deck spans streets; its sidewalks run underneath).

    Returns
    -------
    WalkGraph
    """
    fw = osm.footways
    if len(fw) == 0:
        raise CurbsideInputError("osm", "no footway=sidewalk/crossing ways to route along")
    coords, owner = shapely.get_coordinates(fw.geometry.values, return_index=True)
    keys = np.round(coords / _SNAP_M).astype(np.int64)
    uniq, node = np.unique(keys, axis=0, return_inverse=True)
    node = node.ravel()
    same_line = owner[1:] == owner[:-1]
    u, v = node[:-1][same_line], node[1:][same_line]
    kinds = fw["kind"].to_numpy()[owner[:-1][same_line]]
    keep = u != v
    u, v, kinds = u[keep], v[keep], kinds[keep]
    xy = uniq * _SNAP_M
    length = np.hypot(*(xy[u] - xy[v]).T)
    # where a sidewalk and a crossing way join the same two nodes, the edge is sidewalk
    _, pair = np.unique(np.sort(np.column_stack([u, v]), axis=1), axis=0, return_inverse=True)
    pair = pair.ravel()
    pair_is_sidewalk = np.zeros(pair.max() + 1, bool)
    np.logical_or.at(pair_is_sidewalk, pair, kinds == "sidewalk")
    kinds = np.where(pair_is_sidewalk[pair], "sidewalk", "crossing")
    graph = nx.Graph()
    graph.add_edges_from(
        (a, b, {"kind": k, "length": d})
        for a, b, k, d in zip(u.tolist(), v.tolist(), kinds.tolist(), length.tolist(), strict=True)
    )
    largest = max(nx.connected_components(graph), key=len)
    graph = graph.subgraph(largest).copy()
    tall = osm.buildings[osm.buildings["height_m"] >= covered_min_height_m]
    covered_fw = shapely.buffer(fw[fw["covered"]].geometry.values, 3.0)
    covered = shapely.union_all(np.concatenate([covered_fw, tall.geometry.values]))
    log.info("walking graph: %d nodes, %d edges", graph.number_of_nodes(), graph.number_of_edges())
    return WalkGraph(graph, xy, _jaywalk_partners(graph, xy, osm), covered)


def _jaywalk_partners(graph: nx.Graph, xy: np.ndarray, osm: OsmSource) -> dict:
    """For each long sidewalk edge, the opposite sidewalk straight across the street (vectorised)."""
    edges = np.array(
        [(a, b) for a, b, k in graph.edges(data="kind") if k == "sidewalk"], dtype=np.int64
    ).reshape(-1, 2)
    edges.sort(axis=1)
    p, q = xy[edges[:, 0]], xy[edges[:, 1]]
    seg_len = np.hypot(*(q - p).T)
    long_enough = seg_len >= 12.0
    edges, p, q, seg_len = edges[long_enough], p[long_enough], q[long_enough], seg_len[long_enough]
    if len(edges) == 0:
        return {}
    lines = shapely.linestrings(np.stack([p, q], axis=1))
    tree = shapely.STRtree(lines)
    mid = (p + q) / 2
    d = (q - p) / seg_len[:, None]
    normal = np.column_stack([-d[:, 1], d[:, 0]])
    reach = 40.0
    ray_src = np.repeat(np.arange(len(edges)), 2)
    sign = np.tile([1.0, -1.0], len(edges))
    ends = mid[ray_src] + normal[ray_src] * sign[:, None] * reach
    rays = shapely.linestrings(np.stack([mid[ray_src] + normal[ray_src] * sign[:, None] * 0.5, ends], axis=1))
    r_idx, e_idx = tree.query(rays, predicate="intersects")
    src_edge = ray_src[r_idx]
    ok = (e_idx != src_edge) & (np.abs(np.sum(d[src_edge] * d[e_idx], axis=1)) > 0.9)
    ea, eb = edges[e_idx], edges[src_edge]
    ok &= ~((ea[:, :1] == eb).any(axis=1) | (ea[:, 1:] == eb).any(axis=1))
    r_idx, e_idx, src_edge = r_idx[ok], e_idx[ok], src_edge[ok]
    hits = shapely.intersection(rays[r_idx], lines[e_idx])
    hit_xy = shapely.get_coordinates(shapely.centroid(hits))
    dist = np.hypot(*(hit_xy - mid[src_edge]).T)
    good = (dist >= 6.0) & (dist <= reach)
    r_idx, e_idx, src_edge, hit_xy, dist = r_idx[good], e_idx[good], src_edge[good], hit_xy[good], dist[good]
    # nearest hit per ray
    order = np.lexsort((dist, r_idx))
    first = np.ones(len(order), bool)
    first[1:] = r_idx[order][1:] != r_idx[order][:-1]
    pick = order[first]
    r_idx, e_idx, src_edge, hit_xy = r_idx[pick], e_idx[pick], src_edge[pick], hit_xy[pick]
    cross = shapely.linestrings(np.stack([mid[src_edge], hit_xy], axis=1))
    road_tree = shapely.STRtree(osm.roads.geometry.values)
    bldg_tree = shapely.STRtree(osm.buildings.geometry.values)
    crosses_road = np.zeros(len(cross), bool)
    crosses_road[np.unique(road_tree.query(cross, predicate="intersects")[0])] = True
    hits_building = np.zeros(len(cross), bool)
    hits_building[np.unique(bldg_tree.query(cross, predicate="intersects")[0])] = True
    out = {}
    for i in np.flatnonzero(crosses_road & ~hits_building):
        a, b = edges[src_edge[i]]
        key = (int(a), int(b))
        if key not in out:
            out[key] = (mid[src_edge[i]], (int(edges[e_idx[i], 0]), int(edges[e_idx[i], 1])), hit_xy[i])
    return out


def _walk_once(wg: WalkGraph, spec: RouteSpec, start: int, rng: np.random.Generator):
    """One random walk; returns (points, leg kinds) or None when it dead-ends or strays."""
    g, xy = wg.graph, wg.xy
    pts = [xy[start]]
    kinds: list[str] = []
    visited: set[tuple[int, int]] = set()
    cur, prev = start, None
    n_cross = n_jay = 0
    total = 0.0
    origin = xy[start]
    while total < spec.length_m:
        cands = []
        weights = []
        heading = pts[-1] - pts[-2] if len(pts) > 1 else None
        for nb in g.neighbors(cur):
            key = (min(cur, nb), max(cur, nb))
            if nb == prev or key in visited:
                continue
            kind = g[cur][nb]["kind"]
            entering = kind == "crossing" and (not kinds or kinds[-1] != "crossing")
            if entering and n_cross >= spec.crossings:
                continue
            step = xy[nb] - xy[cur]
            w = 1.0
            if heading is not None:
                cos = float(step @ heading) / (np.hypot(*step) * np.hypot(*heading) + 1e-9)
                w = float(np.exp(1.5 * cos))
            if entering:
                w *= 2.0
            cands.append((nb, kind, entering))
            weights.append(w)
        if not cands:
            return None
        weights_arr = np.asarray(weights)
        nb, kind, entering = cands[rng.choice(len(cands), p=weights_arr / weights_arr.sum())]
        key = (min(cur, nb), max(cur, nb))
        visited.add(key)
        n_cross += int(entering)
        partner = wg.jaywalk.get(key) if kind == "sidewalk" else None
        if partner is not None and n_jay < spec.jaywalks and rng.random() < 0.35:
            mid, (a, b), hit = partner
            if (min(a, b), max(a, b)) not in visited:
                pts.append(mid)
                kinds.append("sidewalk")
                pts.append(hit)
                kinds.append("jaywalk")
                n_jay += 1
                travel = xy[nb] - xy[cur]
                nxt, other = (b, a) if (xy[b] - xy[a]) @ travel > 0 else (a, b)
                visited.add((min(a, b), max(a, b)))
                pts.append(xy[nxt])
                kinds.append("sidewalk")
                total = float(np.hypot(*np.diff(np.asarray(pts), axis=0).T).sum())
                prev, cur = other, nxt
                if np.hypot(*(xy[cur] - origin)) > spec.radius_m:
                    return None
                continue
        pts.append(xy[nb])
        kinds.append(kind)
        total += float(np.hypot(*(xy[nb] - xy[cur])))
        prev, cur = cur, nb
        if np.hypot(*(xy[cur] - origin)) > spec.radius_m:
            return None
    return np.asarray(pts), np.asarray(kinds)


def _cut(pts: np.ndarray, kinds: np.ndarray, length_m: float) -> tuple[np.ndarray, np.ndarray]:
    """The polyline cut at ``length_m`` from its start."""
    seg = np.hypot(*np.diff(pts, axis=0).T)
    cum = np.concatenate([[0.0], np.cumsum(seg)])
    i = int(np.searchsorted(cum, length_m) - 1)
    i = min(max(i, 0), len(seg) - 1)
    frac = (length_m - cum[i]) / seg[i] if seg[i] > 0 else 0.0
    end = pts[i] + frac * (pts[i + 1] - pts[i])
    return np.vstack([pts[: i + 1], end]), kinds[: i + 1]


def _simplify(pts: np.ndarray, kinds: np.ndarray, tolerance_m: float = 0.75) -> tuple[np.ndarray, np.ndarray]:
    """Douglas-Peucker per run of equal kinds, so crossings keep both ends as waypoints."""
    change = np.flatnonzero(kinds[1:] != kinds[:-1]) + 1
    bounds = np.concatenate([[0], change, [len(kinds)]])
    out_pts = [pts[0]]
    out_kinds: list[str] = []
    for a, b in zip(bounds[:-1], bounds[1:], strict=True):
        run = shapely.simplify(shapely.linestrings(pts[a : b + 1]), tolerance_m)
        coords = shapely.get_coordinates(run)[1:]
        out_pts.extend(coords)
        out_kinds.extend([kinds[a]] * len(coords))
    return np.asarray(out_pts), np.asarray(out_kinds)


def far_from_footways(wg: WalkGraph, spec: RouteSpec, frame: LocalFrame) -> str | None:
    """Why no walk of ``spec`` can start on ``wg``, or ``None`` when a footway lies within
    ``spec.start_radius_m`` of its start: ``no footway of the OSM extract within 80 m of (LON, LAT), the
    nearest is 3.1 km away; the extract's footways span lon ... to ..., lat ... to ...``."""
    lon, lat = spec.start_lonlat
    sx, sy = frame.to_xy(np.array([lon]), np.array([lat]))
    xy = wg.xy[np.fromiter(wg.graph.nodes, np.int64)]
    if len(xy) == 0:
        return "the OSM extract has no footway (footway=sidewalk or footway=crossing)"
    nearest_m = float(np.min(np.hypot(xy[:, 0] - sx[0], xy[:, 1] - sy[0])))
    if nearest_m <= spec.start_radius_m:
        return None
    node_lon, node_lat = frame.to_lonlat(xy[:, 0], xy[:, 1])
    return (
        f"no footway of the OSM extract within {spec.start_radius_m:g} m of ({lon:.7g}, {lat:.7g}), the "
        f"nearest is {nearest_m / 1000:.1f} km away; the extract's footways span lon {node_lon.min():.4f} to "
        f"{node_lon.max():.4f}, lat {node_lat.min():.4f} to {node_lat.max():.4f}"
    )


def generate_route(
    wg: WalkGraph,
    spec: RouteSpec,
    frame: LocalFrame,
    seed: int,
    max_attempts: int = 20000,
    accept: Callable[[np.ndarray], bool] | None = None,
    exact_counts: bool = True,
    progress: bool = False,
) -> Route:
    """Draw a route that satisfies ``spec`` (deterministic for a given seed).

    Parameters
    ----------
    wg
        The walking graph.
    spec
        Length, crossings, jaywalks, area.
    frame
        The local frame of ``wg`` (to place ``spec.start_lonlat``).
    seed
        Seed of the random walks.
    max_attempts
        Random walks tried before giving up.
    accept
        A further condition on the polyline (``(n, 2)`` metres, before simplification), checked last
        (e.g. "under open sky").
    exact_counts
        ``False``: ``spec.crossings`` and ``spec.jaywalks`` are maxima, not exact counts.
    progress
        A progress bar over the random walks on a terminal (a command's one route: a hard request takes
        a minute to fail).

    Raises
    ------
    CurbsideInputError
        No footway near the start (:func:`far_from_footways`), or no walk satisfied the request.
    """
    rng = np.random.default_rng(seed)
    sx, sy = frame.to_xy(np.array([spec.start_lonlat[0]]), np.array([spec.start_lonlat[1]]))
    nodes = np.fromiter(wg.graph.nodes, np.int64)
    d = np.hypot(wg.xy[nodes, 0] - sx[0], wg.xy[nodes, 1] - sy[0])
    starts = nodes[d <= spec.start_radius_m]
    if len(starts) == 0:
        raise CurbsideInputError(spec.name, far_from_footways(wg, spec, frame) or "no footway near its start")
    attempts = tqdm(range(1, max_attempts + 1), desc=f"{spec.name}: route search", unit="walk",
                    disable=None if progress else True, leave=False)
    for attempt in attempts:
        walk = _walk_once(wg, spec, int(rng.choice(starts)), rng)
        if walk is None:
            continue
        pts, kinds = _cut(*walk[:2], spec.length_m)
        n_cross, n_jay = _runs(kinds, "crossing"), _runs(kinds, "jaywalk")
        counts_ok = (
            (n_cross, n_jay) == (spec.crossings, spec.jaywalks)
            if exact_counts
            else n_cross <= spec.crossings and n_jay <= spec.jaywalks
        )
        if kinds[-1] != "sidewalk" or not counts_ok:
            continue
        line = shapely.linestrings(pts)
        covered = shapely.intersection(line, wg.covered).length / line.length
        if covered < spec.covered_share:
            continue
        if accept is not None and not accept(pts):
            continue
        pts, kinds = _simplify(pts, kinds)
        log.debug("%s: accepted walk %d (covered %.0f%%)", spec.name, attempt, 100 * covered)
        return Route(spec, pts, kinds, n_cross, n_jay, float(covered), seed, attempt)
    counts = "exactly" if exact_counts else "at most"
    raise CurbsideInputError(
        spec.name,
        f"no route found in {max_attempts} random walks: a route of {spec.length_m:g} m must stay within "
        f"{spec.radius_m:g} m of its start, use no street twice and cross {counts} {spec.crossings} "
        f"crosswalk(s) and {spec.jaywalks} street(s) off them; ask for a shorter route or other counts",
    )


def _runs(kinds: np.ndarray, kind: str) -> int:
    """Number of maximal runs of ``kind`` in a sequence of leg kinds."""
    is_kind = np.asarray(kinds) == kind
    return int(is_kind[0] + np.count_nonzero(is_kind[1:] & ~is_kind[:-1])) if len(is_kind) else 0


#: The six routes of the benchmark, shaped like the paper's Table 1: path 1 in the Financial
#: District, 2-6 in SoMa near Salesforce Tower, 5 and 6 in and beside the Salesforce Transit Center.
SF6: tuple[RouteSpec, ...] = (
    RouteSpec("path1", (-122.4025, 37.7930), 628.0, 4, 4, "FiDi"),
    RouteSpec("path2", (-122.3968, 37.7897), 515.0, 4, 1, "SoMa, Salesforce Tower"),
    RouteSpec("path3", (-122.3980, 37.7878), 332.0, 0, 2, "SoMa, alleys south of Mission"),
    RouteSpec("path4", (-122.3990, 37.7885), 644.0, 2, 2, "SoMa, 2nd St / Mission"),
    RouteSpec("path5", (-122.3958, 37.7893), 467.0, 2, 0, "Transit Center", covered_share=0.25),
    RouteSpec("path6", (-122.3958, 37.7893), 309.0, 0, 0, "Transit Center", covered_share=0.3),
)
