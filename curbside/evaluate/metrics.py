"""The paper's metrics, with SPEC names: Correct Sidewalk Assignment, Euclidean and along/across error.

Definitions (the paper's, made precise where it is silent):

- **Correct Sidewalk Assignment** (``csa``). The estimate and the ground truth at each footstep are each
  assigned to their nearest ``sidewalk`` polygon (STRtree nearest). A step is correct when both give
  the same ``segment_id``. *On a crossing* -- the ground truth is more than
  ``on_sidewalk_m`` (1.5 m; :class:`MetricsConfig`) from every sidewalk polygon (a crosswalk, a jaywalk,
  the carriageway) -- the step counts as correct when the estimate's segment is one of the segments
  the crossing joins, taken as every segment within ``crossing_slack_m`` (6 m) of
  the nearest one's distance (both kerbs of the street being crossed). These steps are counted
  (``n_crossing_steps``) so the rule's weight is visible.
- **Euclidean error**: distance between estimate and ground truth; mean, median, 90th percentile.
- **Along/across-street error**: the error vector decomposed against the street direction at the
  ground-truth location: the street of the sidewalk segment nearest to the ground truth, at right
  angles to its ``facing_deg`` (the bearing from its street's centreline, which ``osmseg build``
  records). A segment without it (a hand-drawn map) takes its polygon's long axis (minimum rotated
  rectangle), which follows the street except on short pieces at corners.
- **ATE / RTE** (RoNIN, Herath et al. 2020): RMSE of positions over the whole walk, and RMSE of the
  displacement error over windows of ``rte_window_s`` (60 s).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd
import shapely

from curbside.errors import CurbsideInputError
from curbside.localize.raster import street_axes
from curbside.osmseg.mapio import MapLayers

#: SPEC metric names, in report order.
METRIC_NAMES: tuple[str, ...] = (
    "csa",
    "euclid_mean_m",
    "euclid_median_m",
    "euclid_p90_m",
    "along_median_m",
    "across_median_m",
    "along_p90_m",
    "across_p90_m",
)


@dataclass(frozen=True)
class MetricsConfig:
    """The scoring parameters of the metrics (see the module docstring).

    Attributes
    ----------
    on_sidewalk_m
        A ground truth farther than this from every sidewalk polygon is "on a crossing" (metres).
    crossing_slack_m
        On a crossing, sidewalk segments within this much of the nearest one count as joined (metres).
    rte_window_s
        RoNIN's relative-trajectory-error window (seconds).
    """

    on_sidewalk_m: float = 1.5
    crossing_slack_m: float = 6.0
    rte_window_s: float = 60.0

    def __post_init__(self) -> None:
        if not (self.on_sidewalk_m >= 0 and self.crossing_slack_m >= 0 and self.rte_window_s > 0):
            raise ValueError(
                "on_sidewalk_m and crossing_slack_m must be non-negative and rte_window_s positive, got "
                f"{self.on_sidewalk_m}, {self.crossing_slack_m}, {self.rte_window_s}"
            )


@dataclass
class SidewalkIndex:
    """Sidewalk segments of a map with an STRtree and each segment's street direction.

    Attributes
    ----------
    geoms
        Sidewalk polygons (local metric CRS).
    segment_ids
        ``segment_id`` per polygon, as strings.
    axis
        ``(n, 2)`` unit vectors along each segment's street (:func:`~curbside.localize.raster.street_axes`).
    """

    geoms: np.ndarray
    segment_ids: np.ndarray
    axis: np.ndarray

    def __post_init__(self) -> None:
        self.tree = shapely.STRtree(self.geoms)

    @classmethod
    def from_layers(cls, layers: MapLayers) -> SidewalkIndex:
        """Index the ``sidewalk`` layer of a map.

        Raises
        ------
        CurbsideInputError
            The map has no sidewalk segments (a hand-labelled map may omit them: evaluate with a
            reference map that has them).
        """
        sw = layers.layer("sidewalk")
        sw = sw[sw.geometry.notna() & ~sw.geometry.is_empty]
        if len(sw) == 0:
            raise CurbsideInputError(
                layers.meta.get("source", "map"), "no sidewalk segments to evaluate against"
            )
        geoms = sw.geometry.values
        ids = sw["segment_id"].astype(str).to_numpy()
        return cls(np.asarray(geoms), ids, street_axes(sw))

    def nearest(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Index of, and distance to, the nearest segment for each point of an ``(n, 2)`` array."""
        points = shapely.points(np.asarray(xy, float))
        (src, idx), dist = self.tree.query_nearest(points, return_distance=True, all_matches=False)
        out_idx = np.empty(len(points), np.int64)
        out_dist = np.empty(len(points))
        out_idx[src] = idx
        out_dist[src] = dist
        return out_idx, out_dist


def step_errors(
    est_xy: np.ndarray, gt_xy: np.ndarray, index: SidewalkIndex | None, config: MetricsConfig | None = None
) -> pd.DataFrame:
    """Per-footstep errors of an estimated track against ground truth.

    Parameters
    ----------
    est_xy, gt_xy
        ``(n, 2)`` metres in the same local frame. Rows of ``est_xy`` holding NaN (no estimate, e.g.
        no GNSS fix yet) are kept and flagged ``missing``; they count as incorrect for ``csa`` and are
        left out of the distance statistics.
    index
        The sidewalk segments; ``None`` gives Euclidean errors only (maps without sidewalks, IPIN).
    config
        The crossing rule's distances (default :class:`MetricsConfig`).

    Returns
    -------
    pandas.DataFrame
        ``euclid_m, along_m, across_m, gt_segment, est_segment, on_crossing, correct, missing``.
    """
    est_xy = np.asarray(est_xy, float).reshape(-1, 2)
    gt_xy = np.asarray(gt_xy, float).reshape(-1, 2)
    missing = ~np.isfinite(est_xy).all(axis=1)
    err = est_xy - gt_xy
    out = pd.DataFrame({"euclid_m": np.hypot(err[:, 0], err[:, 1]), "missing": missing})
    if index is None:
        return out
    gt_idx, gt_dist = index.nearest(gt_xy)
    axis = index.axis[gt_idx]
    out["along_m"] = np.abs(err[:, 0] * axis[:, 0] + err[:, 1] * axis[:, 1])
    out["across_m"] = np.abs(err[:, 0] * axis[:, 1] - err[:, 1] * axis[:, 0])
    est_seg = np.full(len(est_xy), None, dtype=object)
    if (~missing).any():
        est_idx, _ = index.nearest(est_xy[~missing])
        est_seg[~missing] = index.segment_ids[est_idx]
    gt_seg = index.segment_ids[gt_idx]
    correct = est_seg == gt_seg
    config = config or MetricsConfig()
    on_crossing = gt_dist > config.on_sidewalk_m
    rows = np.flatnonzero(on_crossing & ~missing)
    if len(rows):
        points = shapely.points(gt_xy[rows])
        src, tgt = index.tree.query(
            points, predicate="dwithin", distance=gt_dist[rows] + config.crossing_slack_m
        )
        joined = index.segment_ids[tgt] == est_seg[rows][src]
        hit = np.zeros(len(rows), bool)
        np.logical_or.at(hit, src, joined)
        correct[rows] = hit
    out["gt_segment"] = gt_seg
    out["est_segment"] = est_seg
    out["on_crossing"] = on_crossing
    out["correct"] = correct.astype(bool) & ~missing
    return out


def summarize(errors: pd.DataFrame) -> dict[str, float]:
    """The SPEC metrics of a table of step errors (one session or many pooled).

    Parameters
    ----------
    errors
        Output of :func:`step_errors`, possibly concatenated over sessions.

    Returns
    -------
    dict
        :data:`METRIC_NAMES` (NaN where undefined) plus ``n_steps``, ``n_missing`` and
        ``n_crossing_steps``.
    """
    ok = ~errors["missing"].to_numpy(bool)
    e = errors["euclid_m"].to_numpy(float)[ok]

    def stat(values: np.ndarray, kind: str) -> float:
        if len(values) == 0:
            return float("nan")
        if kind == "mean":
            return float(np.mean(values))
        return float(np.percentile(values, 50 if kind == "median" else 90))

    out: dict[str, float] = {
        "csa": float(errors["correct"].mean()) if "correct" in errors and len(errors) else float("nan"),
        "euclid_mean_m": stat(e, "mean"),
        "euclid_median_m": stat(e, "median"),
        "euclid_p90_m": stat(e, "p90"),
    }
    for comp in ("along", "across"):
        values = errors[f"{comp}_m"].to_numpy(float)[ok] if f"{comp}_m" in errors else np.array([])
        out[f"{comp}_median_m"] = stat(values, "median")
        out[f"{comp}_p90_m"] = stat(values, "p90")
    out = {name: out[name] for name in METRIC_NAMES}
    out["n_steps"] = len(errors)
    out["n_missing"] = int((~ok).sum())
    out["n_crossing_steps"] = int(errors["on_crossing"].sum()) if "on_crossing" in errors else 0
    return out


def ate_m(est_xy: np.ndarray, gt_xy: np.ndarray) -> float:
    """Absolute trajectory error: RMSE of the position error over the walk (NaN rows skipped)."""
    err = np.asarray(est_xy, float) - np.asarray(gt_xy, float)
    sq = np.sum(err**2, axis=1)
    sq = sq[np.isfinite(sq)]
    return float(np.sqrt(sq.mean())) if len(sq) else float("nan")


def rte_m(
    t: np.ndarray, est_xy: np.ndarray, gt_xy: np.ndarray, window_s: float = MetricsConfig.rte_window_s
) -> float:
    """Relative trajectory error: RMSE of the displacement error over windows of ``window_s``.

    For each step ``i`` the window ends at the first step ``j`` with ``t[j] >= t[i] + window_s``. A
    walk shorter than the window gives the displacement error over the whole walk scaled to the
    window length, as RoNIN does.
    """
    t = np.asarray(t, float)
    est_xy = np.asarray(est_xy, float)
    gt_xy = np.asarray(gt_xy, float)
    if len(t) < 2:
        return float("nan")
    j = np.searchsorted(t, t + window_s)
    valid = j < len(t)
    if not valid.any():
        d = (est_xy[-1] - est_xy[0]) - (gt_xy[-1] - gt_xy[0])
        return float(np.hypot(*d) * window_s / max(t[-1] - t[0], 1e-9))
    i = np.flatnonzero(valid)
    d = (est_xy[j[i]] - est_xy[i]) - (gt_xy[j[i]] - gt_xy[i])
    sq = np.sum(d**2, axis=1)
    sq = sq[np.isfinite(sq)]
    return float(np.sqrt(sq.mean())) if len(sq) else float("nan")


#: Names of :func:`waypoint_summary`'s figures, in print order.
WAYPOINT_METRIC_NAMES: tuple[str, ...] = (
    "waypoint_median_m", "waypoint_p90_m", "waypoint_max_m", "n_waypoints", "waypoint_accuracy_held"
)


def waypoint_errors(track: pd.DataFrame, waypoints: pd.DataFrame, exclude_first: bool = True) -> pd.DataFrame:
    """Error of a track at surveyed waypoints: the one place curbside scores a track against them.

    The estimate is interpolated linearly in time at each waypoint's ``t`` and compared with the
    surveyed point, in a local metric frame around the first waypoint. Only waypoints inside the
    track's time span are scored (a GNSS track spans only the fixes), and, with ``exclude_first``, not
    the first waypoint: a filter started from the known start pose is exact there.

    Parameters
    ----------
    track
        ``t, lat, lon`` per footstep (``track.csv``), and ``accuracy_m`` where the track has it; rows
        without an estimate (NaN) are skipped.
    waypoints
        ``t, lat, lon`` (``waypoints.csv``).
    exclude_first
        Leave the first waypoint out.

    Returns
    -------
    pandas.DataFrame
        One row per scored waypoint: ``t, lat, lon`` (surveyed), ``est_lat, est_lon`` and ``error_m``;
        ``accuracy_m`` too (interpolated like the position) when the track has it.

    Raises
    ------
    CurbsideInputError
        Fewer than two waypoints, or a track with fewer than two estimates.
    """
    from curbside.projection import LocalFrame

    if waypoints is None or len(waypoints) < 2:
        raise CurbsideInputError("waypoints.csv", "scoring at waypoints needs at least two of them")
    est = track.dropna(subset=["t", "lat", "lon"])
    if len(est) < 2:
        raise CurbsideInputError("track", "scoring at waypoints needs at least two estimates")
    t = est["t"].to_numpy(float)
    wt = waypoints["t"].to_numpy(float)
    keep = (wt >= t[0]) & (wt <= t[-1])
    if exclude_first:
        keep[0] = False
    scored = waypoints.loc[keep, ["t", "lat", "lon"]].reset_index(drop=True)
    frame = LocalFrame.around(float(waypoints["lon"].iat[0]), float(waypoints["lat"].iat[0]))
    ex, ey = frame.to_xy(est["lon"].to_numpy(float), est["lat"].to_numpy(float))
    wx, wy = frame.to_xy(scored["lon"].to_numpy(float), scored["lat"].to_numpy(float))
    at = scored["t"].to_numpy(float)
    ix, iy = np.interp(at, t, ex), np.interp(at, t, ey)
    est_lon, est_lat = frame.to_lonlat(ix, iy)
    scored["est_lat"] = np.atleast_1d(est_lat)
    scored["est_lon"] = np.atleast_1d(est_lon)
    scored["error_m"] = np.hypot(ix - wx, iy - wy)
    if "accuracy_m" in est:
        scored["accuracy_m"] = np.interp(at, t, est["accuracy_m"].to_numpy(float))
    return scored


def waypoint_summary(errors: pd.DataFrame) -> dict[str, float]:
    """Median, 90th percentile and largest error of :func:`waypoint_errors`, how many waypoints, and the
    share of them that the track's ``accuracy_m`` (its 68 % radius) held.

    Returns
    -------
    dict
        :data:`WAYPOINT_METRIC_NAMES`; NaN figures when no waypoint was scored, and a NaN share when the
        track has no ``accuracy_m``.
    """
    e = errors["error_m"].to_numpy(float)
    if len(e) == 0:
        return {name: (0 if name == "n_waypoints" else float("nan")) for name in WAYPOINT_METRIC_NAMES}
    radius = errors["accuracy_m"].to_numpy(float) if "accuracy_m" in errors else np.full(len(e), np.nan)
    held = float(np.mean(e <= radius)) if np.isfinite(radius).all() else float("nan")
    return {
        "waypoint_median_m": float(np.median(e)),
        "waypoint_p90_m": float(np.percentile(e, 90)),
        "waypoint_max_m": float(e.max()),
        "n_waypoints": len(e),
        "waypoint_accuracy_held": held,
    }


def format_waypoint_summary(summary: dict[str, float]) -> str:
    """One line for a command's output, e.g. ``error at 12 waypoints: median 3.1 m, p90 7.9 m, max 9.4 m;
    accuracy_m held 8 of 12``."""
    n = int(summary["n_waypoints"])
    if n == 0:
        return "error at waypoints: no waypoint inside the track's time span"
    line = (
        f"error at {n} waypoint{'s' if n != 1 else ''}: median {summary['waypoint_median_m']:.1f} m, "
        f"p90 {summary['waypoint_p90_m']:.1f} m, max {summary['waypoint_max_m']:.1f} m"
    )
    held = summary.get("waypoint_accuracy_held", float("nan"))
    return line if not np.isfinite(held) else f"{line}; accuracy_m held {round(held * n)} of {n}"
