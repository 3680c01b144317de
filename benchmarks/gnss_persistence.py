"""Do the simulated fixes' errors last as long as a real phone's? Window by window, walk by walk.

Each fix's error against the surveyed (or simulated) waypoints, cut into windows of ``--window-s``
seconds (:mod:`curbside.evaluate.gnss_persistence`): the share of the error still there 5, 10, 20
and 30 s later, and the share a single offset per window explains. The script prints the median
over the windows, with the number of windows, for:

- the IPIN 2023 trials (``--ipin``: two Android phones, surveyed waypoints, no model involved, so
  every trial is read);
- simulated sessions (``--sessions``: folders of ``gnss.csv`` and ``waypoints.csv``, e.g. the tune
  split that ``benchmarks/tune_fusion.py`` writes);
- Gauss-Markov references at the time constants of ``--tau-s`` (what a pure AR(1) error reads over
  the same windows).

Usage::

    python benchmarks/gnss_persistence.py --ipin ../shared/data/ipin2023/ipin2023-t3.h5 \\
        --sessions TUNE/tune/paper6 TUNE/tune/downtown TUNE/tune/open [--plot FIG.png]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import pandas as pd

from curbside.evaluate.gnss_persistence import ar1_reference, fix_errors, window_persistence
from curbside.localize.session import read_session


def summary_row(source: str, windows: list[pd.DataFrame]) -> dict:
    """Median of every column over the windows of all walks of ``source``."""
    table = pd.concat([w for w in windows if len(w)], ignore_index=True) if windows else pd.DataFrame()
    medians = table.drop(columns="t0").median().to_dict() if len(table) else {}
    return {"source": source, "windows": len(table), **medians}


def simulated_windows(folder: Path, window_s: float) -> list[pd.DataFrame]:
    """The windows of every simulated session under ``folder``."""
    sessions = (read_session(p) for p in sorted(folder.iterdir()) if (p / "gnss.csv").exists())
    return [window_persistence(fix_errors(s.gnss, s.waypoints), window_s) for s in sessions]


def ipin_windows(h5: str, window_s: float) -> list[pd.DataFrame]:
    """The windows of every IPIN trial with at least two waypoints."""
    from curbside.localize.readers.ipin import list_trials, read_trial

    trials = (read_trial(h5, name) for name in list_trials(h5))
    return [window_persistence(fix_errors(trial.gnss, trial.waypoints), window_s)
            for trial in trials if trial.waypoints is not None and len(trial.waypoints) >= 2]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sessions", nargs="*", default=[], help="folders of simulated sessions")
    parser.add_argument("--ipin", help="ipin2023-t3.h5")
    parser.add_argument("--window-s", type=float, default=90.0,
                        help="window length (s; default 90: most IPIN trials hold one or two)")
    parser.add_argument("--tau-s", type=float, nargs="*", default=[3.0, 10.0, 30.0],
                        help="Gauss-Markov references (default: 3 10 30)")
    parser.add_argument("--plot", metavar="PNG", help="also draw the persistence against the lag")
    args = parser.parse_args(argv)
    if not args.sessions and not args.ipin:
        parser.error("nothing to measure: give --sessions, --ipin or both")
    if args.window_s <= 30:
        parser.error(f"--window-s must be longer than the longest lag (30 s), got {args.window_s:g}")
    for path in [*args.sessions, args.ipin or "."]:
        if not Path(path).exists():
            parser.error(f"{path}: no such file or folder")
    rows = []
    if args.ipin:
        rows.append(summary_row("IPIN 2023, real phones", ipin_windows(args.ipin, args.window_s)))
    for folder in map(Path, args.sessions):
        label = f"simulated {folder.parent.name}/{folder.name}"
        rows.append(summary_row(label, simulated_windows(folder, args.window_s)))
    rows += [{"source": f"AR(1), tau {tau:g} s", "windows": 400, **ar1_reference(tau, args.window_s)}
             for tau in args.tau_s]
    table = pd.DataFrame(rows)
    print(table.round(2).to_string(index=False))
    if args.plot:
        plot(table, args.plot, args.window_s)
        print(f"{args.plot}: the figure")
    return 0


#: Colour by where the fixes come from (Okabe-Ito: apart under every common colour blindness), marker
#: by subset: a source reads by its colour and its shape, not by colour alone.
_FAMILY_COLOURS = {"IPIN": "#000000", "simulated tune/": "#0072b2", "simulated tune-persistent/": "#d55e00"}
_SUBSET_MARKERS = {"paper6": "o", "downtown": "^", "open": "s"}


def _line_style(source: str, dashes) -> dict:
    """How one source's line is drawn: grey dashes for the AR(1) references."""
    if source.startswith("AR(1)"):
        return {"ls": next(dashes), "lw": 1.2, "color": "0.45"}
    colour = next((c for prefix, c in _FAMILY_COLOURS.items() if source.startswith(prefix)), "#cc79a7")
    marker = _SUBSET_MARKERS.get(source.rsplit("/", 1)[-1], "D")
    return {"marker": marker, "lw": 2, "color": colour, "ls": "--" if "open" in source else "-"}


def plot(table: pd.DataFrame, path: str, window_s: float) -> None:
    """Each source's median persistence against the lag; references dashed (written atomically)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from curbside.io import atomic_path

    lags = [c for c in table.columns if c.startswith("lag_")]
    x = [0.0] + [float(c[4:-1]) for c in lags]
    fig, ax = plt.subplots(figsize=(9.5, 4.2))
    dashes = iter([":", "--", "-.", (0, (5, 1, 1, 1, 1, 1))] * len(table))
    for _, row in table.iterrows():
        style = _line_style(str(row["source"]), dashes)
        ax.plot(x, [1.0] + [row[c] for c in lags], label=row["source"], **style)
    ax.set(xlabel="lag (s)", ylabel="share of a fix's error still there",
           title=f"How long a GNSS fix's error lasts ({window_s:g} s windows, medians)", ylim=(-0.05, 1.02))
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="center left", bbox_to_anchor=(1.01, 0.5))
    fig.tight_layout()
    with atomic_path(Path(path)) as tmp:
        fig.savefig(tmp, dpi=110, format="png")
    plt.close(fig)


if __name__ == "__main__":
    raise SystemExit(main())
