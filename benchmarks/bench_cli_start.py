"""Start-up time of the console commands against a bare ``python -c pass``, measured in the same run.

``localize --help`` should cost no more than a few bare interpreter starts: building the parsers
imports no heavy library (the sub-commands import theirs when they run; see
``tests/test_cli_startup.py``). The script runs each command ``--runs`` times (after one warm-up run
each, so that the file cache is warm), prints the median wall time and its ratio to the median of
``python -c pass``, and exits 1 when ``localize --help`` takes more than ``--max-ratio`` times that.

Usage::

    python benchmarks/bench_cli_start.py [--runs 5] [--max-ratio 10]
"""

from __future__ import annotations

import argparse
import logging
import shutil
import statistics
import subprocess
import sys
import time
from pathlib import Path

logger = logging.getLogger("bench_cli_start")

COMMANDS = (["localize", "--help"], ["osmseg", "--help"], ["localize", "run", "--help"],
            ["osmseg", "build", "--help"])


def command_line(words: list[str]) -> list[str]:
    """The console script beside this interpreter (as installed), else ``python -m curbside.cli.PROG``."""
    script = Path(sys.executable).with_name(words[0])
    found = str(script) if script.is_file() else shutil.which(words[0])
    return [found, *words[1:]] if found else [sys.executable, "-m", f"curbside.cli.{words[0]}", *words[1:]]


def median_wall_s(argv: list[str], runs: int) -> float:
    """Median wall time of ``argv`` over ``runs`` runs, after one warm-up run."""
    times = []
    for _ in range(runs + 1):
        start = time.perf_counter()
        subprocess.run(argv, capture_output=True, check=True)
        times.append(time.perf_counter() - start)
    return statistics.median(times[1:])


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=5, help="runs per command (default 5)")
    parser.add_argument("--max-ratio", type=float, default=10.0,
                        help="fail when localize --help takes more than this many bare starts (default 10)")
    args = parser.parse_args()
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    bare_s = median_wall_s([sys.executable, "-c", "pass"], args.runs)
    logger.info("%-28s median %6.3f s", "python -c pass", bare_s)
    ratios = {}
    for words in COMMANDS:
        wall_s = median_wall_s(command_line(words), args.runs)
        ratios[" ".join(words)] = wall_s / bare_s
        logger.info("%-28s median %6.3f s  %5.1fx python -c pass", " ".join(words), wall_s, wall_s / bare_s)
    if ratios["localize --help"] > args.max_ratio:
        logger.error("localize --help: %.1fx a bare start, more than %g", ratios["localize --help"],
                     args.max_ratio)
        return 1
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
