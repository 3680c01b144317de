"""How sure a benchmark figure is: session-bootstrap intervals, paired between methods.

A pooled figure (CSA, median, p90 over every footstep of a subset) comes from a handful of sessions,
and the footsteps of one session are strongly correlated: a cloud on the wrong sidewalk stays there
for a block. So the unit of resampling is the session (a cluster bootstrap; Davison & Hinkley 1997,
section 3.8): each resample draws the subset's sessions with replacement and pools their footsteps
again. Every method is scored on the *same* resampled sessions, so the interval of a difference
("fused minus the paper's method") is paired and much narrower than the two intervals side by side.

The quantiles of a resample are computed on the footsteps sorted once, each counted as many times as
its session was drawn (numpy's linear interpolation on that repeated sample, as the pooled tables
use), so 1,000 resamples of a 20,000-footstep subset take well under a second. Intervals are
percentile intervals; the point figures stay those of the pooled table.

With fewer than :data:`MIN_BOOTSTRAP_UNITS` sessions (trials) there is no interval: one session
resampled is always itself (a zero-width interval, "100 %" better), and two or three give only a
handful of distinct resamples. Such rows keep their point figure, ``lo``, ``hi`` and ``better_share``
are NaN (``null`` in ``metrics.json``) and ``reason`` says why.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import pandas as pd

from curbside.evaluate.runner import subset_of

#: Metrics given an interval, and whether a larger value is better.
INTERVAL_METRICS: dict[str, bool] = {
    "csa": True, "euclid_median_m": False, "euclid_p90_m": False, "across_median_m": False
}
#: Methods compared with curbside fused (the issue's two baselines).
BASELINES = ("paper", "gnss")
#: The fewest sessions (or trials) resampled for an interval. Below it the resamples are too few and too
#: alike for a percentile interval to mean anything (one session: always itself, a zero-width interval).
MIN_BOOTSTRAP_UNITS = 5


def unit_count(n: int, unit: str) -> str:
    """``"1 session"``, ``"3 sessions"``: a count of the resampled units (``unit`` in the plural)."""
    return f"{n} {unit[:-1] if n == 1 and unit.endswith('s') else unit}"


@dataclass(frozen=True)
class SessionSamples:
    """One method's scored points grouped by the unit resampled: footsteps by session, or IPIN
    waypoints by trial (rows follow ``sessions``).

    Attributes
    ----------
    sessions
        Session (or trial) names, in the order shared by every method compared.
    correct, steps
        Per session: footsteps on the correct sidewalk, and all footsteps (missing ones count as
        incorrect, as in :func:`curbside.evaluate.metrics.summarize`).
    values
        Per metric name: ``(sorted values, session index of each)`` over the footsteps with an estimate.
    """

    sessions: tuple[str, ...]
    correct: np.ndarray
    steps: np.ndarray
    values: dict[str, tuple[np.ndarray, np.ndarray]]

    @classmethod
    def from_runs(cls, runs: list[dict[str, Any]], sessions: tuple[str, ...]) -> SessionSamples:
        """Group :func:`curbside.evaluate.runner.run_one` outputs (several seeds of a session pool)."""
        order = {name: k for k, name in enumerate(sessions)}
        correct = np.zeros(len(sessions))
        steps = np.zeros(len(sessions))
        columns: dict[str, list[np.ndarray]] = {"euclid_m": [], "across_m": []}
        owners: list[np.ndarray] = []
        for run in runs:
            k = order[run["session"]]
            errors = run["errors"]
            correct[k] += float(errors["correct"].sum()) if "correct" in errors else np.nan
            steps[k] += len(errors)
            ok = ~errors["missing"].to_numpy(bool)
            for name, parts in columns.items():
                column = errors[name] if name in errors else pd.Series(np.nan, index=errors.index)
                parts.append(column.to_numpy(float)[ok])
            owners.append(np.full(int(ok.sum()), k))
        owner = np.concatenate(owners) if owners else np.zeros(0, int)
        values = {}
        for name, parts in columns.items():
            v = np.concatenate(parts) if parts else np.zeros(0)
            order_v = np.argsort(v, kind="stable")
            values[name] = (v[order_v], owner[order_v])
        return cls(sessions, correct, steps, values)

    @classmethod
    def from_errors(
        cls, errors_m: np.ndarray, owner: np.ndarray, clusters: tuple[str, ...]
    ) -> SessionSamples:
        """Distances only (no sidewalks, e.g. IPIN waypoints), ``owner[i]`` the cluster of ``errors_m[i]``."""
        order_v = np.argsort(errors_m, kind="stable")
        no_sidewalks = np.full(len(clusters), np.nan)
        return cls(clusters, no_sidewalks, no_sidewalks, {"euclid_m": (errors_m[order_v], owner[order_v])})

    def point(self) -> dict[str, float]:
        """The metrics of :meth:`statistics` on the sample itself (every session drawn once): the
        pooled tables' figures, since the resampled quantile is numpy's on unit counts."""
        once = np.ones((1, len(self.sessions)), dtype=np.int64)
        return {metric: float(value[0]) for metric, value in self.statistics(once).items()}

    def statistics(self, counts: np.ndarray) -> dict[str, np.ndarray]:
        """The interval metrics it has, for each row of ``counts`` (``(R, sessions)`` draws per session)."""
        out = {}
        if not np.isnan(self.correct).any():
            with np.errstate(invalid="ignore", divide="ignore"):
                out["csa"] = (counts @ self.correct) / (counts @ self.steps)
        out["euclid_median_m"] = weighted_quantile(*self.values["euclid_m"], counts, 0.5)
        out["euclid_p90_m"] = weighted_quantile(*self.values["euclid_m"], counts, 0.9)
        if "across_m" in self.values and not np.isnan(self.values["across_m"][0]).all():
            out["across_median_m"] = weighted_quantile(*self.values["across_m"], counts, 0.5)
        return out


def weighted_quantile(
    sorted_values: np.ndarray, owner: np.ndarray, counts: np.ndarray, q: float, chunk: int = 200
) -> np.ndarray:
    """The ``q`` quantile of ``sorted_values``, each repeated ``counts[:, owner]`` times, per row.

    The quantile is numpy's default (linear interpolation between order statistics) of that repeated
    sample, so unit counts give :func:`numpy.percentile` exactly and a resample's figure is computed
    as the pooled table's is.

    Parameters
    ----------
    sorted_values
        Values in ascending order (NaN-free; NaN values give a NaN result).
    owner
        Session index of each value.
    counts
        ``(R, sessions)`` non-negative integer draws per session.
    q
        Quantile in [0, 1].
    chunk
        Rows at a time (memory: ``chunk x len(values)`` integers).
    """
    out = np.full(len(counts), np.nan)
    if len(sorted_values) == 0 or np.isnan(sorted_values).any():
        return out
    for start in range(0, len(counts), chunk):
        cum = np.cumsum(counts[start:start + chunk, owner], axis=1)
        total = cum[:, -1]
        rank = np.maximum(total - 1, 0) * q  # 0-based position in the repeated, sorted sample
        below = np.floor(rank)
        # the value at repeated position k is the first sorted value whose cumulative count exceeds k
        i0 = (cum <= below[:, None]).sum(axis=1)
        i1 = (cum <= np.minimum(below + 1, np.maximum(total - 1, 0))[:, None]).sum(axis=1)
        last = len(sorted_values) - 1
        v0, v1 = sorted_values[np.minimum(i0, last)], sorted_values[np.minimum(i1, last)]
        out[start:start + chunk] = np.where(total > 0, v0 + (rank - below) * (v1 - v0), np.nan)
    return out


def session_draws(n_sessions: int, n_resamples: int, seed: int) -> np.ndarray:
    """``(n_resamples, n_sessions)`` multinomial counts: sessions drawn with replacement."""
    rng = np.random.default_rng(seed)
    return rng.multinomial(n_sessions, np.full(n_sessions, 1.0 / n_sessions), size=n_resamples)


def bootstrap_intervals(
    runs_by_method: dict[str, list[dict[str, Any]]],
    n_resamples: int = 1000,
    level: float = 0.95,
    seed: int = 0,
    reference: str = "fused",
    baselines: tuple[str, ...] = BASELINES,
    min_units: int = MIN_BOOTSTRAP_UNITS,
) -> pd.DataFrame:
    """Percentile intervals of each method's metrics and of ``reference`` minus each baseline, paired.

    Parameters
    ----------
    runs_by_method
        One subset's runs per method (same sessions for every method).
    n_resamples, level, seed
        Bootstrap resamples, interval coverage, and the seed of the draws.
    reference, baselines
        ``reference`` is compared with each of ``baselines`` that is present.
    min_units
        The fewest sessions given an interval (see :func:`interval_rows`).

    Returns
    -------
    pandas.DataFrame
        One row per (``method``, ``metric``): ``value`` (the pooled figure), ``lo``, ``hi``, ``n_units``,
        ``unit`` and ``reason``; difference rows have ``method`` like ``"fused - paper"`` and also
        ``better_share``, the share of resamples where ``reference`` is better.
    """
    sessions = tuple(sorted({r["session"] for runs in runs_by_method.values() for r in runs}))
    samples = {method: SessionSamples.from_runs(runs, sessions) for method, runs in runs_by_method.items()}
    counts = session_draws(len(sessions), n_resamples, seed)
    return interval_rows(samples, counts, reference, baselines, level, min_units=min_units)


def waypoint_intervals(
    errors: dict[str, np.ndarray],
    rows: list[dict[str, Any]],
    reference: str,
    baselines: tuple[str, ...],
    n_resamples: int = 1000,
    seed: int = 0,
    min_units: int = MIN_BOOTSTRAP_UNITS,
) -> pd.DataFrame:
    """:func:`bootstrap_intervals` for errors at surveyed waypoints, resampling whole trials.

    ``errors`` and ``rows`` are :func:`curbside.evaluate.benchmark.ipin_errors`' outputs (or several
    seeds' of them, concatenated in the same order): each method's errors trial by trial at the same
    waypoints, and one row per trial and method. ``min_units``: the fewest trials given an interval.
    """
    trials = tuple(dict.fromkeys(r["trial"] for r in rows))
    index = {t: k for k, t in enumerate(trials)}
    # the errors follow the reference's rows (a trial appears once per filter seed pooled)
    scored = [r for r in rows if r["method"] == reference]
    owner = np.repeat([index[r["trial"]] for r in scored], [r["n_waypoints"] for r in scored])
    samples = {
        method: SessionSamples.from_errors(np.asarray(e, float), owner, trials)
        for method, e in errors.items() if len(e) == len(owner)
    }
    counts = session_draws(len(trials), n_resamples, seed)
    return interval_rows(samples, counts, reference, baselines, unit="trials", min_units=min_units)


def interval_rows(
    samples: dict[str, SessionSamples],
    counts: np.ndarray,
    reference: str,
    baselines: tuple[str, ...],
    level: float = 0.95,
    unit: str = "sessions",
    min_units: int = MIN_BOOTSTRAP_UNITS,
) -> pd.DataFrame:
    """Point figure and percentile interval per method and metric, then ``reference`` minus each
    baseline (paired: every method on the same resampled ``counts``).

    With fewer than ``min_units`` units (``counts.shape[1]``, named ``unit``) a row keeps its point
    figure but ``lo``, ``hi`` and ``better_share`` are NaN and ``reason`` says why (else ``None``);
    ``n_units`` and ``unit`` say what was resampled.
    """
    tail = 100 * (1 - level) / 2
    n_units = counts.shape[1]
    reason = None
    if n_units < min_units:
        reason = f"{unit_count(n_units, unit)}: an interval needs at least {min_units} {unit} to resample"
    if reason is not None:
        counts = counts[:0]  # nothing to resample: the point figures alone
    stats = {method: sample.statistics(counts) for method, sample in samples.items()}
    points = {method: sample.point() for method, sample in samples.items()}
    rows = []
    for method, by_metric in stats.items():
        for metric, draws in by_metric.items():
            lo, hi = _interval(draws, tail) if reason is None else (np.nan, np.nan)
            rows.append({"method": method, "metric": metric, "value": points[method][metric],
                         "lo": lo, "hi": hi})
    for base in (b for b in baselines if b in stats and reference in stats):
        for metric in (m for m in stats[reference] if m in stats[base]):
            diff = stats[reference][metric] - stats[base][metric]
            lo, hi = _interval(diff, tail) if reason is None else (np.nan, np.nan)
            better = np.nan
            if reason is None:
                better = float(np.mean(diff > 0) if INTERVAL_METRICS[metric] else np.mean(diff < 0))
            rows.append({"method": f"{reference} - {base}", "metric": metric,
                         "value": points[reference][metric] - points[base][metric], "lo": lo, "hi": hi,
                         "better_share": better})
    return pd.DataFrame(rows).assign(n_units=n_units, unit=unit, reason=reason)


def _interval(draws: np.ndarray, tail: float) -> tuple[float, float]:
    """The ``tail`` and ``100 - tail`` percentiles of the finite draws (NaN, NaN when there are none)."""
    finite = draws[np.isfinite(draws)]
    if not len(finite):
        return np.nan, np.nan
    lo, hi = np.percentile(finite, [tail, 100 - tail])
    return float(lo), float(hi)


def subset_intervals(
    results: list[dict[str, Any]],
    base: dict[str, Any],
    n_resamples: int = 1000,
    seed: int = 0,
) -> pd.DataFrame:
    """:func:`bootstrap_intervals` of GNSS, the paper's method and fused on every subset of a benchmark.

    ``base`` picks the runs as the reports' tables do: ``map`` (the map's name) and any of
    ``jaywalk_weight``, ``particles``, ``gnss_sigma_factor`` (GNSS alone has none of those three).
    Returns the rows of :func:`bootstrap_intervals` with a ``subset`` column first.
    """
    methods = ("gnss", *(b for b in BASELINES if b != "gnss"), "fused")
    frames = []
    for subset in dict.fromkeys(subset_of(r) for r in results):
        runs_by_method = {}
        for method in methods:
            runs = [r for r in results
                    if subset_of(r) == subset and r["spec"]["method"] == method and _at_base(r["spec"], base)]
            if runs:
                runs_by_method[method] = runs
        if runs_by_method:
            part = bootstrap_intervals(runs_by_method, n_resamples, seed=seed)
            part.insert(0, "subset", subset)
            frames.append(part)
    return pd.concat(frames, ignore_index=True) if frames else pd.DataFrame()


def _at_base(spec: dict[str, Any], base: dict[str, Any]) -> bool:
    """Whether a run's spec has the base parameters (GNSS alone: only the map counts)."""
    if spec["map_name"] != base["map"]:
        return False
    keys = () if spec["method"] == "gnss" else ("jaywalk_weight", "particles", "gnss_sigma_factor")
    return all(spec[k] == base[k] for k in keys if k in base)


def map_intervals(
    results: list[dict[str, Any]],
    base: dict[str, Any],
    method: str = "fused",
    n_resamples: int = 1000,
    seed: int = 0,
) -> pd.DataFrame:
    """One method on each map source, and each other map minus the base map (``base["map"]``), paired.

    The maps' runs must share their sessions (as ``localize evaluate --maps`` and the benchmark's
    DataSF runs do); ``better_share`` is then the share of resamples in which the other map does
    better. Returns rows like :func:`subset_intervals`' (``method`` holds the map names).
    """
    params = {k: v for k, v in base.items() if k != "map"}
    at_base = [r for r in results if r["spec"]["method"] == method
               and _at_base(r["spec"], {**params, "map": r["spec"]["map_name"]})]
    others = [m for m in dict.fromkeys(r["spec"]["map_name"] for r in at_base) if m != base["map"]]
    frames = []
    for subset in dict.fromkeys(subset_of(r) for r in at_base):
        in_subset = [r for r in at_base if subset_of(r) == subset]
        runs_by_map = {name: [r for r in in_subset if r["spec"]["map_name"] == name]
                       for name in (base["map"], *others)}
        first = base["map"]
        for k, other in enumerate(o for o in others if runs_by_map[o] and runs_by_map[first]):
            pair = {first: runs_by_map[first], other: runs_by_map[other]}
            part = bootstrap_intervals(pair, n_resamples, seed=seed, reference=other, baselines=(first,))
            if k:
                part = part[part["method"] != first]  # the base map's rows once
            frames.append(part.assign(subset=subset))
    if not frames:
        return pd.DataFrame()
    out = pd.concat(frames, ignore_index=True)
    return out[["subset", *(c for c in out.columns if c != "subset")]]
