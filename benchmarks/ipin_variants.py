"""Compare fused-filter variants on the IPIN 2023 *training* trials (real phones, surveyed waypoints).

The IPIN criterion of issue 9 is scored on the held-out ``repetition04`` trials; parameters may only be
chosen on the others. This script runs curbside fused, version 0.1's fused filter
(:data:`curbside.evaluate.criteria.FUSED_0_1_OVERRIDES`) and each named variant -- ``--set``-style
overrides of the fused run configuration -- on the training trials (no map, RoNIN velocity, the start
pose of each trial), all scored at the same waypoints, and prints the pooled median and p90 per filter
seed. GNSS alone, RoNIN+PF and the paper's method run beside them.

Usage::

    python benchmarks/ipin_variants.py ../shared/data/ipin2023/ipin2023-t3.h5 --variants variants.json
        [--seeds 0 1]
    python benchmarks/ipin_variants.py ../shared/data/ipin2023/ipin2023-t3.h5 --held-out --seeds 0 1 2 3

``--held-out`` scores the held-out trials instead, to measure the defaults against 0.1 over several
filter seeds (the benchmark runs one); it takes no variants, since nothing may be chosen there.

``--ronin benchmarks/weights/ronin_ms_only.pt`` tracks with a RoNIN that never saw the venue (the
choice of ``--unseen-velocity``'s values, docs/filter.md).

``variants.json`` maps names to ``{"filter.gnss.sigma_factor": 1.5, ...}``.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from curbside.evaluate.benchmark import ipin_errors
from curbside.evaluate.criteria import FUSED_0_1_OVERRIDES
from curbside.localize.runconfig import RunConfig


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("h5", help="ipin2023-t3.h5")
    parser.add_argument("--variants", help="JSON file: name -> overrides of the fused run configuration")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1], help="filter seeds (default 0 1)")
    parser.add_argument("--held-out", action="store_true",
                        help="score the held-out trials (defaults and 0.1 only: nothing is chosen there)")
    parser.add_argument("--ronin", metavar="PT",
                        help="track with this RoNIN model's velocity instead of the bundled one (e.g. "
                        "benchmarks/weights/ronin_ms_only.pt, which never saw IPIN)")
    args = parser.parse_args(argv)
    if args.held_out and args.variants:
        parser.error("--held-out takes no --variants: parameters are chosen on the training trials only")
    variants = json.loads(Path(args.variants).read_text(encoding="utf-8")) if args.variants else {}
    fused = RunConfig.for_mode("fused")
    extra = {"fused 0.1": fused.with_overrides(FUSED_0_1_OVERRIDES)}
    extra |= {name: fused.with_overrides(overrides) for name, overrides in variants.items()}
    for seed in args.seeds:
        errors, _, n_trials = ipin_errors(args.h5, seed=seed, extra_runs=extra, training=not args.held_out,
                                          held_out=args.held_out, ronin_weights=args.ronin)
        print(f"filter seed {seed}: {n_trials} {'held-out' if args.held_out else 'training'} trials")
        for name, e in errors.items():
            print(f"  {name:<16} median {np.median(e):5.2f} m  p90 {np.percentile(e, 90):5.2f} m  "
                  f"({len(e)} waypoints)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
