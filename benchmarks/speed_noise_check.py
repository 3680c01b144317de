"""Is the simulator's speed noise as large as a real velocity model's? Window by window, walk by walk.

Over each ``--window-s`` window inside a straight leg, the path length the velocity integrates to is
divided by the surveyed one (:func:`curbside.evaluate.inertial_errors.window_speed_ratios`). Each walk's
ratios are divided by their median (the per-walk speed scale, which the filter's speed-scale state
learns), and their standard deviation is the along-track error the velocity adds over one window. The
script prints the median of that spread over the walks, with its 10th and 90th percentiles, for:

- simulated sessions (``--sessions``: folders of ``velocity.csv`` and ``waypoints.csv``, e.g. the tune
  split that ``benchmarks/tune_fusion.py`` writes);
- the IPIN 2023 trials (``--ipin``), with the bundled RoNIN on the held-out ``repetition04`` trials
  (the model on home ground) and, with ``--ronin PT``, a model that never saw the venue on every trial.

Usage::

    python benchmarks/speed_noise_check.py --sessions TUNE/tune/paper6 TUNE/tune/open \\
        --ipin ../shared/data/ipin2023/ipin2023-t3.h5 --ronin benchmarks/weights/ronin_ms_only.pt
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import pandas as pd

from curbside.evaluate.inertial_errors import window_speed_ratios
from curbside.localize.session import read_session

#: A walk with fewer windows than this gives no spread.
MIN_WINDOWS = 4


def walk_spread(ratios: np.ndarray) -> float:
    """Standard deviation of a walk's window ratios around their median (NaN with too few windows)."""
    if len(ratios) < MIN_WINDOWS:
        return float("nan")
    return float(np.std(ratios / np.median(ratios)))


def summary_row(source: str, spreads: list[float], window_s: float) -> dict:
    """Median and 10th / 90th percentiles of the walks' spreads."""
    s = np.array([x for x in spreads if np.isfinite(x)])
    q10, q50, q90 = np.percentile(s, [10, 50, 90]) if len(s) else (np.nan,) * 3
    return {"source": source, "window_s": window_s, "walks": len(s), "spread_median": q50,
            "spread_p10": q10, "spread_p90": q90}


Walk = tuple[pd.DataFrame, pd.DataFrame]  # velocity (t, ve, vn) and waypoints (t, lat, lon)


def simulated_walks(folder: Path) -> list[Walk]:
    """The velocity and waypoints of each simulated session under ``folder``."""
    sessions = (read_session(p) for p in sorted(folder.iterdir()) if (p / "velocity.csv").exists())
    return [(s.velocity, s.waypoints) for s in sessions]


def ipin_walks(h5: str, weights: str | None) -> list[Walk]:
    """RoNIN's velocity and the waypoints of each IPIN trial: the bundled model on the held-out trials,
    or ``weights`` on all."""
    from curbside.localize.readers.ipin import list_trials, read_trial
    from curbside.localize.ronin.infer import load_model, ronin_velocity

    model = load_model(weights)
    trials = (read_trial(h5, n) for n in list_trials(h5) if weights is not None or "repetition04" in n)
    return [(ronin_velocity(trial.imu, model), trial.waypoints) for trial in trials]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sessions", nargs="*", default=[], help="folders of simulated sessions")
    parser.add_argument("--ipin", help="ipin2023-t3.h5")
    parser.add_argument("--ronin", help="also a RoNIN model that never saw the venue (.pt), on every trial")
    parser.add_argument("--window-s", type=float, nargs="+", default=[5.0, 10.0], help="default: 5 10")
    args = parser.parse_args(argv)
    if not args.sessions and not args.ipin:
        parser.error("nothing to measure: give --sessions, --ipin or both")
    for path in [*args.sessions, args.ipin or "."]:
        if not Path(path).exists():
            parser.error(f"{path}: no such file or folder")
    sources = {f"simulated {Path(folder).name}": simulated_walks(Path(folder)) for folder in args.sessions}
    if args.ipin:
        sources["IPIN, bundled RoNIN (held-out)"] = ipin_walks(args.ipin, None)
        if args.ronin:
            sources[f"IPIN, {Path(args.ronin).name} (all trials)"] = ipin_walks(args.ipin, args.ronin)
    rows = [
        summary_row(source, [walk_spread(window_speed_ratios(v, wp, window_s)) for v, wp in walks], window_s)
        for window_s in args.window_s
        for source, walks in sources.items()
    ]
    print(pd.DataFrame(rows).round(3).to_string(index=False))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
