"""Choose the GNSS fusion parameters on the IPIN 2023 training trials; confirm on held-out repetition04.

The parameters (``docs/filter.md``, "GNSS fusion"):

- ``gnss_fix_association``: ``interpolate`` (a fix at every footstep, the paper) or ``once`` (each fix
  at the first footstep after it);
- ``gnss_sigma_factor``: Gaussian sigma = factor * reported accuracy;
- ``gnss_error_correlation_s``: time constant of the GNSS error, which tempers each fix's likelihood;
- ``gnss_outlier_prob``: weight of the flat outlier component (radius ``gnss_outlier_radius_m``, fixed).

Protocol: the fused method (PDR velocity, no map: IPIN has none, N=500, started at the first surveyed
waypoint as in ``ipin_fused_vs_gnss.py``) runs over the full grid on the training trials (every trial
except the ``repetition04`` ones), for each filter seed. The score is the mean error at the surveyed
waypoints, pooled over trials and averaged over seeds (the mean weighs the tail, which is where GNSS
fusion goes wrong, without being as noisy as p90). The best grid point is then run once on the
held-out repetition04 trials, next to the previous defaults and the inertial-only filter. The simulated
SF benchmark is never used here.

Usage::

    python benchmarks/tune_gnss_ipin.py ../shared/data/ipin2023/ipin2023-t3.h5 [--seeds 0 1]
        [--workers 2] [--csv grid.csv]
"""

from __future__ import annotations

import argparse
import functools
import itertools
import logging
import sys
from concurrent.futures import ProcessPoolExecutor

import numpy as np
import pandas as pd
from ipin_fused_vs_gnss import waypoint_errors
from tqdm import tqdm

from curbside import projection, settings
from curbside.localize.filter import FilterConfig
from curbside.localize.pipeline import track_session, valid_fixes
from curbside.localize.readers.ipin import list_trials, read_trial

HELD_OUT = "repetition04"
GRID = {
    "gnss_fix_association": ("interpolate", "once"),
    "gnss_sigma_factor": (0.66, 1.0, 1.5, 2.0),
    "gnss_error_correlation_s": (0.0, 3.0, 10.0, 30.0),
    "gnss_outlier_prob": (0.0, 0.05, 0.2),
}
#: The values before this tuning (the paper's association, plain Gaussian, independent fixes).
PREVIOUS = {"gnss_fix_association": "interpolate", "gnss_sigma_factor": 1.5,
            "gnss_error_correlation_s": 0.0, "gnss_outlier_prob": 0.0}

_sessions: dict = {}


def _load(h5: str, trials: list[str]) -> None:
    # Every IPIN trial gets its own UTM lookup from pyproj's database (~0.1 s); the grid repeats them.
    projection.utm_crs_for = functools.lru_cache(maxsize=None)(projection.utm_crs_for)
    logging.basicConfig(level=logging.ERROR)
    for trial in trials:
        session = read_trial(h5, trial)
        frame = projection.LocalFrame.around(session.meta["start"]["lon"], session.meta["start"]["lat"])
        tf = valid_fixes(session.gnss, frame)[0]
        tw = session.waypoints["t"].to_numpy()
        scored = (tw >= tf[0]) & (tw <= tf[-1]) if len(tf) else np.zeros(len(tw), bool)
        scored[0] = False  # the start pose: the filter is placed there
        _sessions[trial] = (session, frame, scored)


def _errors(params: dict, mode: str, seed: int, trials: list[str]) -> np.ndarray:
    """Pooled waypoint errors (m) of one parameter set, one mode and one seed over ``trials``."""
    settings.gnss_fix_association = params["gnss_fix_association"]
    config = FilterConfig(
        n_particles=500, gnss_sigma_factor=params["gnss_sigma_factor"],
        gnss_error_correlation_s=params["gnss_error_correlation_s"],
        gnss_outlier_prob=params["gnss_outlier_prob"],
    )
    out = []
    for trial in trials:
        session, frame, scored = _sessions[trial]
        track = track_session(session, None, mode, config=config, seed=seed, velocity_source="pdr",
                              progress=False).track
        out.append(waypoint_errors(track, session.waypoints, frame)[scored])
    return np.concatenate(out)


def _score(job: tuple[str, dict, str, int, list[str]]) -> dict:
    which, params, mode, seed, trials = job
    err = _errors(params, mode, seed, trials)
    err = err[np.isfinite(err)]
    return {"which": which, **params, "mode": mode, "seed": seed, "waypoints": len(err),
            "median_m": np.median(err), "p90_m": np.percentile(err, 90), "mean_m": err.mean()}


def _run(jobs: list, h5: str, trials: list[str], workers: int, label: str) -> pd.DataFrame:
    with ProcessPoolExecutor(workers, initializer=_load, initargs=(h5, trials)) as pool:
        rows = list(tqdm(pool.map(_score, jobs), total=len(jobs), desc=label, unit="run", file=sys.stderr))
    keys = ["which", *GRID, "mode"]
    return (pd.DataFrame(rows).groupby(keys, sort=False)[["waypoints", "median_m", "p90_m", "mean_m"]]
            .mean().reset_index())


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("h5", help="ipin2023-t3.h5")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1])
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--csv", help="write the training grid here")
    args = parser.parse_args(argv)

    trials = list_trials(args.h5)
    train = [t for t in trials if HELD_OUT not in t]
    held_out = [t for t in trials if HELD_OUT in t]
    grid = [dict(zip(GRID, values, strict=True)) for values in itertools.product(*GRID.values())]
    jobs = [("grid", params, "fused", seed, train) for params in grid for seed in args.seeds]
    table = _run(jobs, args.h5, train, args.workers, "training grid")
    if args.csv:
        table.to_csv(args.csv, index=False)
    pd.set_option("display.width", 200)
    print(f"Training: {len(train)} trials, ~{table['waypoints'].iloc[0]:.0f} waypoints, PDR, fused, N=500, "
          f"seeds {args.seeds}; error at surveyed waypoints (m), mean over seeds, sorted by mean")
    shown = table.drop(columns=["which", "mode", "waypoints"]).sort_values("mean_m")
    print(shown.round(2).to_string(index=False))
    best = table.loc[table["mean_m"].idxmin(), list(GRID)].to_dict()
    print("\nChosen:", ", ".join(f"{k} = {v}" for k, v in best.items()))

    check = [("chosen", best, "fused"), ("previous", PREVIOUS, "fused"),
             ("inertial only", PREVIOUS, "inertial")]
    jobs = [(which, params, mode, seed, held_out) for which, params, mode in check for seed in args.seeds]
    confirm = _run(jobs, args.h5, held_out, args.workers, "held out")
    print(f"\nHeld out ({HELD_OUT}): {len(held_out)} trials, ~{confirm['waypoints'].iloc[0]:.0f} waypoints")
    print(confirm.drop(columns=["waypoints"]).round(2).to_string(index=False))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
