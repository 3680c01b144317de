"""Compare filter variants on the benchmark's *tuning* split (never on the scored test split).

Issue 9 asks that the fused filter's parameters be chosen on seeds and routes the benchmark does not
score. :func:`curbside.evaluate.subsets.benchmark_sessions` makes a disjoint ``tune`` split of every
subset (other route seeds, session seeds 101..); this script simulates it once (phone profile) and
runs each named variant -- a method plus ``--set``-style overrides of the run configuration -- over it
with several filter seeds (each method at the benchmark's N: curbside fused 2000, the paper's method and
RoNIN+PF 500; ``filter.n_particles`` overrides it), then prints per subset the pooled CSA, Euclidean
median and p90 and the across-street median, and per variant how many session-seed runs have a
median above 1.5x their GNSS median.

Usage::

    python benchmarks/tune_fusion.py OUT --variants variants.json [--seeds 0 1] [--session-seeds 9]
        [--workers 2] [--subsets paper6 downtown open] [--map MAP] [--no-map-likelihood]
        [--gnss canyon|persistent]

``variants.json`` maps names to ``[method, {"filter.motion.heading_noise_deg": 1.5, ...}]``; ``gnss``
is always added. ``docs/tuning.md`` ("Choosing the fused filter's parameters") lists the rounds that
chose the defaults.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import pandas as pd

from curbside.evaluate import metrics
from curbside.evaluate.gnss_model import GNSS_MODELS, GnssErrorModel
from curbside.evaluate.runner import RunSpec, run_all
from curbside.evaluate.simulate import SimulationConfig
from curbside.evaluate.subsets import SUBSETS, benchmark_sessions, load_world
from curbside.evaluate.suite import SuiteConfig
from curbside.evaluate.uncertainty import bootstrap_intervals


def sessions(out: Path, subsets: tuple[str, ...], seeds: int, gnss: str = "canyon") -> dict[str, list[Path]]:
    """The tune split's session folders per subset (simulated on first use, then reused); with another
    GNSS model than ``canyon``, in ``tune-<gnss>/`` (the same walks and velocities, other fixes)."""
    world = load_world()
    config = SimulationConfig(profile="phone", gnss=GnssErrorModel.named(gnss))
    folder = out / ("tune" if gnss == "canyon" else f"tune-{gnss}")
    return {sub: benchmark_sessions(folder / sub, sub, split="tune", seeds=seeds, world=world, config=config)
            for sub in subsets}


def run(folders: dict[str, list[Path]], map_path: str, variants: dict, seeds: tuple[int, ...], workers: int,
        filter_map: bool = True, score_map: str | None = None) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Pooled metrics per (variant, subset), each run's median error (for the GNSS ratios) and the
    variants' paired gains over the first (:func:`paired_gains`).

    ``filter_map=False`` runs the filters without the map likelihood (the map still scores them);
    ``score_map`` scores against another map's sidewalks than the filters use (default: the same).
    """
    suite = SuiteConfig()  # each method's N, as the benchmark runs it
    specs, keys = [], []
    for name, (method, overrides) in variants.items():
        for seed in seeds if method != "gnss" else seeds[:1]:
            for sub, paths in folders.items():
                for path in paths:
                    specs.append(RunSpec(str(path), method, map_path if filter_map else None, "osm",
                                         score_map or map_path,
                                         0.4, suite.particles_of(method), None, seed,
                                         overrides=tuple(sorted(overrides.items()))))
                    keys.append((name, seed, sub, path.name))
    results = run_all(specs, workers=workers)
    # A variant with filter.smoother.lag_s also scores its smoothed positions, as "<name>+smoothed".
    scored = [(k[0], k, r["errors"], r["metrics"]) for r, k in zip(results, keys, strict=True)]
    scored += [(k[0] + "+smoothed", k, r["errors_smoothed"], r["metrics_smoothed"])
               for r, k in zip(results, keys, strict=True) if r["errors_smoothed"] is not None]
    rows = []
    for name in dict.fromkeys(s[0] for s in scored):
        for sub in folders:
            errors = [e for n, k, e, _ in scored if n == name and k[2] == sub]
            m = metrics.summarize(pd.concat(errors, ignore_index=True))
            rows.append({"variant": name, "subset": sub, "csa": m["csa"], "median_m": m["euclid_median_m"],
                         "p90_m": m["euclid_p90_m"], "across_m": m["across_median_m"]})
    medians = [(n, *k[1:], summary["euclid_median_m"]) for n, k, _, summary in scored]
    runs = pd.DataFrame(medians, columns=["variant", "seed", "subset", "session", "median_m"])
    return pd.DataFrame(rows), runs, paired_gains(scored, folders)


def paired_gains(scored: list, folders: dict) -> pd.DataFrame:
    """Each variant against the first one named after ``gnss``: paired session-bootstrap intervals."""
    names = [n for n in dict.fromkeys(s[0] for s in scored) if n != "gnss"]
    frames = []
    for sub in folders:
        by_name = {n: [{"session": k[3], "errors": e} for m, k, e, _ in scored if m == n and k[2] == sub]
                   for n in names}
        for name in names[1:]:
            part = bootstrap_intervals({names[0]: by_name[names[0]], name: by_name[name]},
                                       reference=name, baselines=(names[0],))
            part = part[part["method"].str.contains(" - ")].assign(subset=sub)
            frames.append(part)
    return pd.concat(frames, ignore_index=True) if frames else pd.DataFrame()


def print_gains(gains: pd.DataFrame) -> None:
    """One line per variant and subset: the 95 % interval of each paired difference, share better."""
    for (method, sub), part in gains.groupby(["method", "subset"], sort=False):
        cells = [f"{r.metric.removesuffix('_m')} [{r.lo:+.3f}, {r.hi:+.3f}] {100 * r.better_share:.0f}%"
                 for r in part.itertuples()]
        print(f"{method:>28} {sub:>8}: " + "; ".join(cells))


def gnss_ratios(runs: pd.DataFrame) -> pd.DataFrame:
    """Per variant: the worst median / GNSS median over its runs and how many exceed 1.5."""
    gnss = runs[runs["variant"] == "gnss"].set_index(["subset", "session"])["median_m"]
    out = []
    for name, part in runs.groupby("variant", sort=False):
        ratio = part.set_index(["subset", "session"])["median_m"] / gnss.reindex(
            part.set_index(["subset", "session"]).index).to_numpy()
        out.append({"variant": name, "worst_ratio": float(np.nanmax(ratio)),
                    "over_1.5": int((ratio > 1.5).sum()), "runs": len(ratio)})
    return pd.DataFrame(out)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("out", help="working folder (tune sessions, map)")
    parser.add_argument("--variants", required=True, help="JSON file: name -> [method, overrides]")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1], help="filter seeds (default 0 1)")
    parser.add_argument("--session-seeds", type=int, default=9, metavar="N",
                        help="sessions per route (default 9; with 3, paper6 gains of 0.03 CSA did not "
                             "repeat on other sessions: docs/filter.md)")
    parser.add_argument("--subsets", nargs="+", choices=SUBSETS, default=list(SUBSETS))
    parser.add_argument("--map", help="map GeoJSON (default: built from the bundled extract into OUT)")
    parser.add_argument("--score-map", metavar="MAP",
                        help="score against this map's sidewalks (the true one) while the filters use --map "
                             "(e.g. one whose buildings were moved on purpose); default: --map")
    parser.add_argument("--gnss", choices=GNSS_MODELS, default="canyon",
                        help="GNSS error model of the tune sessions (default canyon, the benchmark's; "
                             "persistent: errors that last as long as real phones')")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--runs-csv", metavar="FILE", help="also write each run's figures to this CSV")
    parser.add_argument("--no-map-likelihood", action="store_true",
                        help="run the filters without the map (as on the IPIN trials); the map still scores")
    args = parser.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    map_path = args.map
    if map_path is None:
        from curbside.osmseg.build import build_map
        from curbside.osmseg.mapio import write_map

        map_path = str(out / "map.geojson")
        if not Path(map_path).is_file():
            write_map(build_map(), map_path)
    variants = {"gnss": ["gnss", {}], **json.loads(Path(args.variants).read_text(encoding="utf-8"))}
    t0 = time.perf_counter()
    folders = sessions(out, tuple(args.subsets), args.session_seeds, args.gnss)
    pooled, runs, gains = run(folders, map_path, variants, tuple(args.seeds), args.workers,
                              filter_map=not args.no_map_likelihood, score_map=args.score_map)
    pd.set_option("display.width", 200)
    wide = pooled.pivot(index="variant", columns="subset").loc[list(dict.fromkeys(pooled["variant"]))]
    print(wide.round(3).to_string())
    print(gnss_ratios(runs).round(2).to_string(index=False))
    if args.runs_csv:
        runs.to_csv(args.runs_csv, index=False)
    if len(gains):
        print("paired 95 % session-bootstrap intervals, each variant minus the first "
              "(share of resamples better):")
        print_gains(gains)
    print(f"({len(runs)} runs in {time.perf_counter() - t0:.0f} s; tune split, phone profile, "
          f"GNSS {args.gnss}, filter seeds {args.seeds})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
