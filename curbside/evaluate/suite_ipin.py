"""The IPIN 2023 trials scored beside a benchmark (``localize benchmark --ipin``, ``--ipin-ronin``).

Real phones, no map: every method, and the runs of :func:`ipin_runs` (version 0.1's fused filter, the
``--familiar-velocity`` and ``--unseen-velocity`` presets), at the trials' surveyed waypoints, pooled over
the filter seeds (:func:`ipin_summary`): first the held-out trials with the bundled RoNIN, then every
trial with a RoNIN that never saw the venue (:func:`ipin_scorings`). The figures go into the report of
:func:`curbside.evaluate.suite.run_suite` and are judged by :mod:`curbside.evaluate.criteria`.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from curbside.evaluate import criteria
from curbside.evaluate.benchmark import IpinScores
from curbside.localize.runconfig import RunConfig

if TYPE_CHECKING:
    from curbside.evaluate.suite import SuiteConfig


#: curbside fused with ``--unseen-velocity on`` (:class:`~curbside.localize.runconfig.UnseenVelocityConfig`;
#: docs/filter.md), run beside the defaults on the IPIN trials: the preset for a velocity model that has
#: not seen the place.
UNSEEN_VELOCITY_RUN = "curbside fused, --unseen-velocity"
#: curbside fused with ``--familiar-velocity auto`` (:class:`~curbside.localize.runconfig.
#: FamiliarVelocityConfig`), run beside the defaults on the IPIN trials: the opt-in calm motion model for a
#: velocity model fitted to the walker, where the walk's smooth speed says so.
FAMILIAR_VELOCITY_RUN = "curbside fused, --familiar-velocity"


def ipin_runs(config: SuiteConfig) -> dict[str, RunConfig]:
    """The IPIN runs beside the methods: version 0.1's fused filter, ``--familiar-velocity auto``, and
    ``--unseen-velocity on`` (as curbside fused itself when the suite runs with it; curbside fused with
    another mode when asked).

    Parameters
    ----------
    config
        The benchmark's configuration (its ``unseen_velocity`` mode).

    Returns
    -------
    dict
        Run configurations by the name the report gives them.
    """
    fused = RunConfig.for_mode("fused")
    preset = fused.with_overrides({"unseen_velocity.mode": "on"})
    runs = {criteria.IPIN_BASELINE_RUN: fused.with_overrides(criteria.FUSED_0_1_OVERRIDES),
            FAMILIAR_VELOCITY_RUN: fused.with_overrides({"familiar_velocity.mode": "auto"})}
    runs["fused" if config.unseen_velocity == "on" else UNSEEN_VELOCITY_RUN] = preset
    if config.unseen_velocity not in ("on", fused.unseen_velocity.mode):
        runs["fused"] = fused.with_overrides({"unseen_velocity.mode": config.unseen_velocity})
    return runs


def ipin_summary(
    h5: str | Path, seeds: range, extra_runs: dict[str, RunConfig], ronin_weights: str | Path | None = None
) -> IpinScores:
    """Every method and ``extra_runs`` on the IPIN trials, at the same waypoints, pooled over the filter
    ``seeds``: pooled figures, their table, and trial-bootstrap intervals (fused against 0.1 and the
    baselines).

    Parameters
    ----------
    h5
        ``ipin2023-t3.h5``.
    seeds
        Filter seeds.
    extra_runs
        Runs beside the methods (:func:`ipin_runs`).
    ronin_weights
        ``None``: the bundled RoNIN, on the held-out trials; else weights of a model that never saw the
        venue, on every trial.

    Returns
    -------
    curbside.evaluate.benchmark.IpinScores
    """
    from curbside.evaluate.benchmark import accuracy_held, ipin_errors, ipin_errors_table, trials_above_gnss
    from curbside.evaluate.uncertainty import waypoint_intervals

    errors: dict[str, list[np.ndarray]] = {}
    rows: list[dict] = []
    for seed in seeds:
        by_method, seed_rows, n_trials = ipin_errors(
            h5, seed=seed, held_out=ronin_weights is None, ronin_weights=ronin_weights, extra_runs=extra_runs
        )
        for method, e in by_method.items():
            errors.setdefault(method, []).append(e)
        rows += seed_rows
    errors = {method: np.concatenate(parts) for method, parts in errors.items()}
    summary = {
        m: {"n": len(e), "median_m": float(np.median(e)), "p90_m": float(np.percentile(e, 90))}
        for m, e in errors.items()
        if len(e)
    }
    for m, (above, scored) in trials_above_gnss(rows).items():
        if m in summary:
            summary[m] |= {"trials_above_gnss": above, "trials_scored": scored}
    for m, share in accuracy_held(rows).items():
        if m in summary:
            summary[m]["accuracy_held"] = share
    baselines = (criteria.IPIN_BASELINE_RUN, "paper", "gnss")
    intervals = waypoint_intervals(errors, rows, "fused", baselines, seed=seeds[0])
    table = ipin_errors_table(errors, n_trials, ronin_weights is None, len(seeds), ronin_weights, rows)
    if ronin_weights is None:
        title = "IPIN 2023 held-out: how sure (m)"
        return IpinScores("ipin_held_out", "ipin_intervals_95", summary, table, intervals, title)
    title = f"IPIN 2023, RoNIN {Path(ronin_weights).name}: how sure (m)"
    return IpinScores("ipin_unseen_ronin", "ipin_unseen_ronin_intervals_95", summary, table, intervals, title)


def ipin_scorings(
    ipin: str | Path, ipin_ronin: str | Path | None, config: SuiteConfig
) -> list[IpinScores]:
    """The held-out IPIN trials with the bundled RoNIN, then (with ``ipin_ronin``) all of them with it.

    Parameters
    ----------
    ipin
        ``ipin2023-t3.h5``.
    ipin_ronin
        RoNIN weights never trained on IPIN, or ``None``.
    config
        The benchmark's configuration (its filter seeds, its ``unseen_velocity`` mode).

    Returns
    -------
    list of curbside.evaluate.benchmark.IpinScores
    """
    seeds = range(config.filter_seed, config.filter_seed + config.filter_seeds)
    runs = ipin_runs(config)
    scorings = [ipin_summary(ipin, seeds, runs)]
    if ipin_ronin:
        scorings.append(ipin_summary(ipin, seeds, runs, ipin_ronin))
    return scorings


def ipin_info(ipin: str | Path | None, ipin_ronin: str | Path | None) -> dict[str, Any]:
    """``run.json``'s IPIN entries.

    Parameters
    ----------
    ipin, ipin_ronin
        As :func:`ipin_scorings` takes them (``None`` without IPIN).

    Returns
    -------
    dict
        ``ipin``, ``ipin_baseline_overrides``, ``ipin_ronin``.
    """
    return {
        "ipin": str(ipin) if ipin else None,
        "ipin_baseline_overrides": criteria.FUSED_0_1_OVERRIDES if ipin else None,
        "ipin_ronin": str(ipin_ronin) if ipin and ipin_ronin else None,
    }
