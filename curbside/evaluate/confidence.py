"""How far to trust the filter's confidence in its sidewalk: ``segment_prob`` against the truth.

At every footstep the filter reports the sidewalk segment holding most of the posterior mass and that
mass (``segment_prob`` in ``track.csv`` and in the service's estimates; docs/filter.md, "Sidewalk
assignment"). An app for blind travellers would announce "you are on the north side" only above a
threshold, so what it needs to know is, for each threshold, how many footsteps reach it (coverage)
and how often the sidewalk is then right (the CSA of the posterior-mode estimate over those
footsteps). The calibration error says how far the probability is from a frequency: the footstep-
weighted mean gap between the mean probability and the share right over :data:`RELIABILITY_BINS`
(0 when a footstep at 0.9 is right 90 % of the time).

Footsteps on a crossing are left out: there the metric accepts either sidewalk the crossing joins, and
the filter's confidence is not a claim about a side of the street.

The filter's other claim is ``accuracy_m``, the radius around its position that should hold the walker
68 % of the time (as a phone reports a fix's accuracy): :func:`accuracy_coverage` says how often it did,
and :func:`accuracy_curve` how often the radius scaled to other shares did (with the heavy tail of
:func:`~curbside.localize.filter.calibration.radius_at_share_m`).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
import pandas as pd

from curbside.evaluate.figures import is_base
from curbside.localize.filter.calibration import TAIL_DOF, radius_at_share_m

#: The methods that name a sidewalk with a probability (GNSS alone names none).
FILTERS = ("inertial", "paper", "fused")
#: Thresholds an app might announce a side at.
THRESHOLDS = (0.5, 0.9, 0.99)
#: Bin edges of the calibration error (the last bin holds probabilities from 0.999 to 1).
RELIABILITY_BINS = (0.0, 0.5, 0.7, 0.8, 0.9, 0.95, 0.99, 0.999, 1.0)
#: Shares an app might want a radius for (``accuracy_m`` is the 68 % one).
RADIUS_SHARES = (0.5, 0.68, 0.8, 0.9, 0.95)


def scored_footsteps(errors: pd.DataFrame) -> pd.DataFrame:
    """The footsteps whose confidence can be scored: ``segment_prob`` finite, an estimate, off crossings.

    Parameters
    ----------
    errors
        Per-footstep errors of the posterior-mode estimate (:func:`curbside.evaluate.metrics.step_errors`)
        with the run's ``segment_prob`` beside them.

    Returns
    -------
    pandas.DataFrame
        ``prob`` and ``correct`` (bool), one row per scored footstep.
    """
    if "segment_prob" not in errors or "correct" not in errors:
        return pd.DataFrame({"prob": pd.Series(dtype=float), "correct": pd.Series(dtype=bool)})
    prob = errors["segment_prob"].to_numpy(float)
    keep = np.isfinite(prob) & ~errors["missing"].to_numpy(bool)
    if "on_crossing" in errors:
        keep &= ~errors["on_crossing"].to_numpy(bool)
    return pd.DataFrame({"prob": prob[keep], "correct": errors["correct"].to_numpy(bool)[keep]})


def reliability_curve(prob: np.ndarray, correct: np.ndarray) -> pd.DataFrame:
    """Per non-empty bin of :data:`RELIABILITY_BINS`: ``lo, hi, footsteps, mean_prob, share_right``."""
    prob, correct = np.asarray(prob, float), np.asarray(correct, float)
    edges = np.asarray(RELIABILITY_BINS)
    k = len(edges) - 1
    which = np.clip(np.searchsorted(edges, prob, side="right") - 1, 0, k - 1)
    count = np.bincount(which, minlength=k)
    keep = count > 0
    return pd.DataFrame({
        "lo": edges[:-1][keep],
        "hi": edges[1:][keep],
        "footsteps": count[keep],
        "mean_prob": np.bincount(which, prob, minlength=k)[keep] / count[keep],
        "share_right": np.bincount(which, correct, minlength=k)[keep] / count[keep],
    })


def calibration_error(prob: np.ndarray, correct: np.ndarray) -> float:
    """Footstep-weighted mean ``|mean probability - share right|`` over :data:`RELIABILITY_BINS` (NaN
    without footsteps)."""
    return _error_of(reliability_curve(prob, correct))


def _error_of(curve: pd.DataFrame) -> float:
    """The calibration error of a :func:`reliability_curve` (NaN for an empty one)."""
    n = int(curve["footsteps"].sum())
    if n == 0:
        return float("nan")
    return float(np.sum(curve["footsteps"] * np.abs(curve["mean_prob"] - curve["share_right"])) / n)


def confidence_summary(errors: pd.DataFrame, thresholds: tuple[float, ...] = THRESHOLDS) -> dict[str, Any]:
    """Coverage and CSA at each threshold, the calibration error and the footstep count.

    Parameters
    ----------
    errors
        As for :func:`scored_footsteps` (several runs concatenated pool their footsteps).
    thresholds
        Probabilities an app might announce a side at.

    Returns
    -------
    dict
        ``footsteps``, ``calibration_error``, ``brier`` (mean squared gap between probability and
        outcome), per threshold ``p`` ``coverage_p`` (share of the footsteps at or above it) and
        ``csa_p`` (share of those on the correct sidewalk; NaN where none reaches it), and ``bins``
        (:func:`reliability_curve` as a list of dicts).
    """
    scored = scored_footsteps(errors)
    prob, correct = scored["prob"].to_numpy(), scored["correct"].to_numpy(bool)
    n = len(prob)
    curve = reliability_curve(prob, correct)
    out: dict[str, Any] = {
        "footsteps": n,
        "calibration_error": _error_of(curve),
        "brier": float(np.mean((prob - correct) ** 2)) if n else float("nan"),
    }
    for p in thresholds:
        above = prob >= p
        out[f"coverage_{p:g}"] = float(above.mean()) if n else float("nan")
        out[f"csa_{p:g}"] = float(correct[above].mean()) if above.any() else float("nan")
    out["bins"] = curve.to_dict("records")
    return out


def _errors_and_radii(errors: pd.DataFrame) -> tuple[np.ndarray, np.ndarray]:
    """The errors and ``accuracy_m`` of the footsteps with an estimate and a finite radius."""
    if "accuracy_m" not in errors:
        return np.empty(0), np.empty(0)
    radius = errors["accuracy_m"].to_numpy(float)
    keep = np.isfinite(radius) & ~errors["missing"].to_numpy(bool)
    return errors["euclid_m"].to_numpy(float)[keep], radius[keep]


def accuracy_coverage(errors: pd.DataFrame) -> tuple[float, float]:
    """How often ``accuracy_m`` held the walker, and its median (NaN, NaN without it).

    Parameters
    ----------
    errors
        Per-footstep errors of the estimate that ``accuracy_m`` is centred on (the weighted mean,
        :func:`curbside.evaluate.metrics.step_errors`) with the run's ``accuracy_m`` beside them.

    Returns
    -------
    tuple of float
        The share of footsteps with an estimate and a finite ``accuracy_m`` whose error is at most
        ``accuracy_m`` (0.68 when the radius is what it claims), and the median ``accuracy_m``.
    """
    error, radius = _errors_and_radii(errors)
    if not len(error):
        return float("nan"), float("nan")
    return float(np.mean(error <= radius)), float(np.median(radius))


def accuracy_curve(
    errors: pd.DataFrame, shares: tuple[float, ...] = RADIUS_SHARES, tail_dof: float = TAIL_DOF
) -> list[dict[str, float]]:
    """How often ``accuracy_m`` scaled to each claimed share held the walker.

    Each radius is :func:`~curbside.localize.filter.calibration.radius_at_share_m` of ``accuracy_m``,
    scaled with a Student-t tail of ``tail_dof`` degrees of freedom (``math.inf``: as for a Gaussian);
    where the errors' tail is heavier than that, the share held falls below the claim far out.

    Returns
    -------
    list of dict
        ``claimed`` and ``held``, one per share; empty without ``accuracy_m``.
    """
    error, radius = _errors_and_radii(errors)
    if not len(error):
        return []
    return [{"claimed": q, "held": float(np.mean(error <= radius_at_share_m(radius, q, tail_dof)))}
            for q in shares]


def reliability_rows(
    results: list[dict[str, Any]], base: dict[str, Any], group_of: Callable[[dict], str] | None = None
) -> list[dict[str, Any]]:
    """:func:`confidence_summary` of each filter's runs at the base configuration, every seed pooled.

    Parameters
    ----------
    results
        :func:`curbside.evaluate.runner.run_one` outputs (their ``errors_mode`` carry ``segment_prob``,
        their ``errors`` ``accuracy_m``).
    base
        The base configuration (:func:`curbside.evaluate.figures.is_base`).
    group_of
        A run's group (a benchmark subset); ``None``: every run in one group.

    Returns
    -------
    list of dict
        One row per group and filter, groups in the order of their first run, filters in
        :data:`FILTERS` order: ``subset`` (the group, ``None`` without ``group_of``), ``method``,
        the summary, ``accuracy_coverage`` and ``accuracy_median_m`` (:func:`accuracy_coverage`) and
        ``accuracy_curve`` (:func:`accuracy_curve`);
        groups and filters without a scored footstep are left out.
    """
    pooled: dict[tuple[str | None, str], list[dict[str, Any]]] = {}
    for r in results:
        method = r["spec"]["method"]
        if method in FILTERS and is_base(r, base) and "segment_prob" in r["errors_mode"]:
            pooled.setdefault((group_of(r) if group_of else None, method), []).append(r)
    groups = list(dict.fromkeys(group for group, _ in pooled))
    rows = []
    for group, method in sorted(pooled, key=lambda k: (groups.index(k[0]), FILTERS.index(k[1]))):
        runs = pooled[group, method]
        summary = confidence_summary(pd.concat([r["errors_mode"] for r in runs], ignore_index=True))
        if summary["footsteps"]:
            errors = [r["errors"] for r in runs if "errors" in r]
            steps = pd.concat(errors) if errors else pd.DataFrame()
            held, median = accuracy_coverage(steps)
            rows.append({"subset": group, "method": method, **summary, "accuracy_coverage": held,
                         "accuracy_median_m": median, "accuracy_curve": accuracy_curve(steps)})
    return rows
