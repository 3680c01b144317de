"""Where the fused filter's errors come from: its along-track bias and its wrong-side episodes.

Two questions that pooled CSA and medians do not answer, measured on the benchmark's sessions:

- **Along-track bias.** At footsteps on the right sidewalk, the error projected on the walker's true
  direction of travel (positive: the estimate is ahead). GNSS alone is the reference: its errors are
  unbiased along the street, so a method's median away from zero is the method's own lag or lead.
- **Wrong-side episodes.** Runs of consecutive footsteps scored wrong (``correct`` false). For each:
  its length, whether it starts within 10 m of a crosswalk (turns and crossings) and, for long ones,
  the share of its fixes nearer the truth than the estimate. A high share means the fixes were right
  and the filter did not follow them (a recovery question). A low one means the fixes led it there
  (a GNSS-model question).
- **Where the wrong footsteps stand.** The map class under the estimate at each wrong footstep
  (``wrong_on_sidewalk``, ``wrong_on_street``, ``wrong_on_crosswalk``, ``wrong_in_building``,
  ``wrong_in_free``: shares of the wrong footsteps). On the wrong sidewalk, the cloud chose a side;
  on the street surface, it sits between the two (its mean, or all of it, in the carriageway).
- **Left behind or flickering.** A wrong footstep whose estimate still stands on the segment the
  walker last left (``wrong_left_behind``: a lag at a corner or a crossing; with the median signed
  along-track error of those footsteps, ``left_behind_along_median_m``), and the wrong footsteps of
  short episodes during which the walker stayed on one segment (``wrong_in_flickers``: what a
  hysteresis on the reported side could remove).

Usage::

    python benchmarks/diagnose_fusion.py OUT --map MAP [--split tune|test] [--subsets paper6 downtown]
        [--methods gnss fused] [--seeds 0 1] [--set KEY=VALUE ...] [--episodes CSV]

``OUT`` is a working folder (e.g. ``benchmarks/tune_fusion.py``'s); the sessions of ``--split`` (default
``tune``) are simulated into it on first use. ``--set`` overrides the fused run's configuration. It
chooses nothing, so it may run on the scored ``test`` split.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import geopandas as gpd
import numpy as np
import pandas as pd
import pyproj
import shapely

from curbside.evaluate.runner import RunSpec, run_all
from curbside.evaluate.subsets import SUBSETS, benchmark_sessions, load_world
from curbside.evaluate.suite import SuiteConfig
from curbside.localize.session import read_session
from curbside.osmseg.mapio import MapLayers, read_map
from curbside.projection import LocalFrame

#: Episodes at least this long (footsteps) count as long.
LONG_EPISODE_STEPS = 20
#: An episode starting this close to a crosswalk (m) starts "at a crossing".
CROSSWALK_NEAR_M = 10.0


def signed_along_m(track: pd.DataFrame) -> np.ndarray:
    """Estimate minus truth along the truth's direction of travel (m; NaN where the walker stands)."""
    t = track["t"].to_numpy()
    gx, gy = track["gt_x_m"].to_numpy(), track["gt_y_m"].to_numpy()
    vx, vy = np.gradient(gx, t), np.gradient(gy, t)
    speed = np.hypot(vx, vy)
    ex, ey = track["x_m"].to_numpy() - gx, track["y_m"].to_numpy() - gy
    along = (ex * vx + ey * vy) / np.maximum(speed, 1e-9)
    return np.where(speed > 0.8, along, np.nan)


def episodes(wrong: np.ndarray) -> list[tuple[int, int]]:
    """``(start, stop)`` of each run of ``True`` in ``wrong`` (stop exclusive)."""
    edges = np.flatnonzero(np.diff(np.concatenate([[0], wrong.astype(np.int8), [0]])))
    return list(zip(edges[::2].tolist(), edges[1::2].tolist(), strict=True))


def segment_left(gt_segment: pd.Series) -> pd.Series:
    """At each footstep, the segment the walker was on before the one it is on (NaN before any change)."""
    on = gt_segment.ffill()
    changed = on.ne(on.shift()) & on.shift().notna()
    return on.shift().where(changed).ffill()


def wrong_kinds(errors: pd.DataFrame) -> tuple[np.ndarray, np.ndarray]:
    """Two masks over the footsteps of one run: wrong with the estimate on the segment the walker last
    left, and wrong within a short episode (under :data:`LONG_EPISODE_STEPS`) during and around which
    the walker stayed on one segment."""
    errors = errors.reset_index(drop=True)
    wrong = ~errors["correct"].astype(bool).to_numpy() & ~errors["missing"].to_numpy()
    left = segment_left(errors["gt_segment"])
    left_behind = wrong & (errors["est_segment"] == left).to_numpy()
    flicker = np.zeros(len(wrong), bool)
    gt = errors["gt_segment"].to_numpy()
    for start, stop in episodes(wrong):
        if stop - start < LONG_EPISODE_STEPS and start > 0 and stop < len(wrong):
            flicker[start:stop] = pd.Series(gt[start - 1 : stop + 1]).nunique(dropna=False) == 1
    return left_behind, flicker


def fixes_nearer_truth(
    gnss: pd.DataFrame, track: pd.DataFrame, t0: float, t1: float, frame: LocalFrame
) -> float:
    """Share of the usable fixes between ``t0`` and ``t1`` nearer the truth than the estimate."""
    gnss = gnss[(gnss["t"] >= t0) & (gnss["t"] <= t1) & (gnss["accuracy_m"] <= 50)]
    if gnss.empty:
        return float("nan")
    fx, fy = frame.to_xy(gnss["lon"].to_numpy(), gnss["lat"].to_numpy())
    t = track["t"].to_numpy()
    at = {c: np.interp(gnss["t"].to_numpy(), t, track[c].to_numpy())
          for c in ("x_m", "y_m", "gt_x_m", "gt_y_m")}
    to_est = np.hypot(fx - at["x_m"], fy - at["y_m"])
    to_truth = np.hypot(fx - at["gt_x_m"], fy - at["gt_y_m"])
    return float(np.mean(to_truth < to_est))


def session_episodes(
    result: dict, session: Path, crosswalks, frame: LocalFrame, with_fixes: bool = True
) -> list[dict]:
    """One row per wrong-side episode of one run (``with_fixes``: where the fixes lay, for long ones)."""
    errors, track = result["errors"].reset_index(drop=True), result["track"].reset_index(drop=True)
    gnss = read_session(session).gnss if with_fixes else None
    wrong = ~errors["correct"].astype(bool).to_numpy() & ~errors["missing"].to_numpy()
    rows = []
    for start, stop in episodes(wrong):
        start_xy = shapely.points(track["gt_x_m"][start], track["gt_y_m"][start])
        long = with_fixes and stop - start >= LONG_EPISODE_STEPS
        rows.append({
            "session": session.name, "start_s": float(track["t"][start]), "steps": stop - start,
            "near_crosswalk": bool(shapely.distance(start_xy, crosswalks) < CROSSWALK_NEAR_M),
            "fixes_nearer_truth": fixes_nearer_truth(gnss, track, track["t"][start], track["t"][stop - 1],
                                                     frame) if long and gnss is not None else float("nan"),
        })
    return rows


def crosswalks_and_frame(layers: MapLayers) -> tuple[shapely.Geometry, LocalFrame]:
    """The map's crosswalks as one geometry, and its metric frame."""
    gdf = layers.gdf
    crosswalks = shapely.union_all(gdf.loc[gdf["class"] == "crosswalk"].geometry.to_numpy())
    return crosswalks, LocalFrame(pyproj.CRS(layers.crs))


def map_class_at(classes: gpd.GeoDataFrame, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """The map class under each point (``free`` where no polygon covers it)."""
    out = np.full(len(x), "free", dtype=object)
    hit, poly = classes.sindex.query(shapely.points(x, y), predicate="within")
    out[hit] = classes["class"].to_numpy()[poly]
    return out


def summarise(
    method: str, subset: str, results: list[dict], sessions: list[Path], crosswalks, frame: LocalFrame,
    classes: gpd.GeoDataFrame,
) -> tuple[dict, list[dict]]:
    """The along-track bias, the episode statistics and the wrong footsteps' map classes of one method
    on one subset."""
    along, rows, n_steps, wrong_classes, behind_along = [], [], 0, [], []
    n_left_behind = n_flicker = 0
    for result, session in zip(results, sessions, strict=True):
        correct = result["errors"]["correct"].astype(bool).to_numpy()
        track = result["track"].reset_index(drop=True)
        signed = signed_along_m(track)
        along.append(signed[correct])
        wrong = ~correct & ~result["errors"]["missing"].to_numpy()
        left_behind, flicker = wrong_kinds(result["errors"])
        behind_along.append(signed[left_behind])
        n_left_behind, n_flicker = n_left_behind + left_behind.sum(), n_flicker + flicker.sum()
        x, y = track["x_m"].to_numpy()[wrong], track["y_m"].to_numpy()[wrong]
        wrong_classes.append(map_class_at(classes, x, y))
        n_steps += len(correct)
        found = session_episodes(result, session, crosswalks, frame, with_fixes=method != "gnss")
        rows += [dict(row, method=method, subset=subset) for row in found]
    along = np.concatenate(along)
    eps = pd.DataFrame(rows)
    summary = {"method": method, "subset": subset, "along_median_m": np.nanmedian(along),
               "along_mean_m": np.nanmean(along)}
    if len(eps):
        long = eps[eps["steps"] >= LONG_EPISODE_STEPS]
        scored = long.dropna(subset=["fixes_nearer_truth"])
        summary |= {
            "wrong_share": eps["steps"].sum() / n_steps,
            "in_long_episodes": long["steps"].sum() / eps["steps"].sum(),
            "long_start_near_crosswalk": long["near_crosswalk"].mean() if len(long) else np.nan,
            "long_fixes_nearer_truth": np.average(scored["fixes_nearer_truth"], weights=scored["steps"])
            if len(scored) else np.nan,
            "wrong_left_behind": n_left_behind / eps["steps"].sum(),
            "left_behind_along_median_m": np.nanmedian(np.concatenate(behind_along))
            if n_left_behind else np.nan,
            "wrong_in_flickers": n_flicker / eps["steps"].sum(),
        }
    wrong_classes = pd.Series(np.concatenate(wrong_classes))
    for cls in ("sidewalk", "street", "crosswalk", "building", "free"):
        summary[f"wrong_{'in' if cls in ('building', 'free') else 'on'}_{cls}"] = (
            float((wrong_classes == cls).mean()) if len(wrong_classes) else np.nan)
    return summary, rows


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("out", help="working folder (sessions are simulated into it on first use)")
    parser.add_argument("--map", required=True, help="map GeoJSON (filters and scoring)")
    parser.add_argument("--split", choices=("tune", "test"), default="tune",
                        help="which sessions: the tuning split (default) or the scored one")
    parser.add_argument("--subsets", nargs="+", choices=SUBSETS, default=["paper6", "downtown"],
                        help="default: paper6 downtown")
    parser.add_argument("--methods", nargs="+", choices=("gnss", "inertial", "paper", "fused"),
                        default=["gnss", "fused"],
                        help="default: gnss fused (GNSS is the along-track reference)")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0], help="filter seeds (default 0)")
    parser.add_argument("--set", nargs="*", default=[], metavar="KEY=VALUE",
                        help="overrides of the fused run (JSON values), e.g. filter.recovery.kernel_scale=3")
    parser.add_argument("--episodes", help="write every wrong-side episode to this CSV")
    parser.add_argument("--workers", type=int, default=2, help="dask worker processes (default 2)")
    args = parser.parse_args(argv)
    overrides = tuple(sorted((k, json.loads(v)) for k, v in (item.split("=", 1) for item in args.set)))
    world = load_world()
    layers = read_map(args.map)
    crosswalks, frame = crosswalks_and_frame(layers)
    classes = layers.gdf[["class", "geometry"]].reset_index(drop=True)
    suite = SuiteConfig()  # each method at the benchmark's N (curbside fused 2000, the others 500)
    summaries, all_rows = [], []
    for subset in args.subsets:
        sessions = benchmark_sessions(Path(args.out) / args.split / subset, subset, split=args.split,
                                      profile="phone", world=world)
        for method in args.methods:
            filter_map = args.map if method != "gnss" else None
            n = suite.particles_of(method)
            specs = [RunSpec(str(s), method, filter_map, "osm", args.map, 0.4, n, None, seed,
                             overrides=overrides if method == "fused" else ())
                     for seed in args.seeds for s in sessions]
            summary, rows = summarise(method, subset, run_all(specs, workers=args.workers),
                                      sessions * len(args.seeds), crosswalks, frame, classes)
            summaries.append(summary)
            all_rows += rows
    pd.set_option("display.width", 200)
    print(pd.DataFrame(summaries).round(3).to_string(index=False))
    if args.episodes:
        pd.DataFrame(all_rows).to_csv(args.episodes, index=False)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
