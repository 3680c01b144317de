"""How far to trust segment_prob: coverage, CSA above a threshold and the calibration error, on
footstep tables whose answers are known by construction."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from curbside.evaluate.confidence import (
    RADIUS_SHARES,
    accuracy_coverage,
    accuracy_curve,
    calibration_error,
    confidence_summary,
    reliability_curve,
    reliability_rows,
    scored_footsteps,
)
from curbside.localize.filter.calibration import TAIL_DOF

BASE = {"map": "osm", "jaywalk_weight": 0.4, "particles": {"inertial": 500, "paper": 500, "fused": 2000},
        "gnss_sigma_factor": None}


def _errors(prob, correct, on_crossing=None, missing=None) -> pd.DataFrame:
    n = len(prob)
    return pd.DataFrame({
        "segment_prob": np.asarray(prob, float),
        "correct": np.asarray(correct, bool),
        "on_crossing": np.zeros(n, bool) if on_crossing is None else np.asarray(on_crossing, bool),
        "missing": np.zeros(n, bool) if missing is None else np.asarray(missing, bool),
    })


def test_a_probability_that_is_a_frequency_has_no_calibration_error_and_an_overconfident_one_has():
    rng = np.random.default_rng(0)
    prob = rng.choice([0.6, 0.75, 0.85, 0.92, 0.97], size=200_000)
    calibrated = rng.random(len(prob)) < prob
    assert calibration_error(prob, calibrated) < 0.005
    # right only 80 % as often as it says: the gap is a fifth of the mean probability
    overconfident = rng.random(len(prob)) < 0.8 * prob
    assert calibration_error(prob, overconfident) == pytest.approx(0.2 * prob.mean(), abs=0.005)


def test_coverage_and_csa_above_each_threshold():
    # ten footsteps: four sure and right, two sure and wrong, four unsure (two right)
    prob = [0.999] * 6 + [0.6] * 4
    correct = [True] * 4 + [False] * 2 + [True, True, False, False]
    s = confidence_summary(_errors(prob, correct), thresholds=(0.5, 0.99))
    assert s["footsteps"] == 10
    assert s["coverage_0.5"] == 1.0 and s["csa_0.5"] == pytest.approx(0.6)
    assert s["coverage_0.99"] == pytest.approx(0.6) and s["csa_0.99"] == pytest.approx(4 / 6)
    assert s["brier"] == pytest.approx(np.mean((np.array(prob) - np.array(correct)) ** 2))
    # bins [0.5, 0.7) and [0.999, 1]: |0.6 - 0.5| * 4 and |0.999 - 4/6| * 6, over ten footsteps
    assert s["calibration_error"] == pytest.approx((0.1 * 4 + (0.999 - 4 / 6) * 6) / 10)


def test_the_reliability_curve_bins_every_footstep_once_and_its_gaps_make_the_calibration_error():
    rng = np.random.default_rng(1)
    prob = np.concatenate([rng.random(500), np.ones(50), np.zeros(5)])  # the bins' edges included
    correct = rng.random(len(prob)) < 0.7
    curve = reliability_curve(prob, correct)
    assert curve["footsteps"].sum() == len(prob) and (curve["lo"] < curve["hi"]).all()
    assert ((curve["mean_prob"] >= curve["lo"]) & (curve["mean_prob"] <= curve["hi"])).all()
    top = curve.iloc[-1]
    assert top["lo"] == 0.999 and top["footsteps"] >= 50  # a probability of 1 sits in the last bin
    gaps = curve["footsteps"] * (curve["mean_prob"] - curve["share_right"]).abs()
    assert calibration_error(prob, correct) == pytest.approx(gaps.sum() / len(prob))


def test_crossings_missing_estimates_and_runs_without_a_probability_are_not_scored():
    errors = _errors([0.9, 0.9, 0.9, np.nan], [True, False, False, False],
                     on_crossing=[False, True, False, False], missing=[False, False, True, False])
    assert scored_footsteps(errors).to_dict("list") == {"prob": [0.9], "correct": [True]}
    empty = confidence_summary(errors.drop(columns="segment_prob"))
    assert empty["footsteps"] == 0 and np.isnan(empty["calibration_error"]) and np.isnan(empty["csa_0.9"])


@settings(max_examples=60, deadline=None)
@given(st.lists(st.tuples(st.floats(0.0, 1.0), st.booleans()), min_size=1, max_size=60))
def test_coverage_falls_and_the_error_stays_in_range_whatever_the_footsteps(steps):
    prob, correct = zip(*steps, strict=True)
    s = confidence_summary(_errors(prob, correct), thresholds=(0.5, 0.9, 0.99))
    coverages = [s["coverage_0.5"], s["coverage_0.9"], s["coverage_0.99"]]
    assert coverages == sorted(coverages, reverse=True)
    assert 0.0 <= s["calibration_error"] <= 1.0 and 0.0 <= s["brier"] <= 1.0


def _run(method: str, subset: str, prob: float, correct: list[bool], **spec) -> dict:
    spec = {"method": method, "map_name": "osm", "jaywalk_weight": 0.4, "gnss_sigma_factor": None,
            "particles": BASE["particles"].get(method, 500), "session": f"/x/{subset}/s1"} | spec
    return {"spec": spec, "errors_mode": _errors([prob] * len(correct), correct)}


def test_reliability_rows_pool_each_filters_base_runs_per_group_and_leave_the_rest_out():
    results = [
        _run("fused", "open", 0.95, [True, True]),
        _run("paper", "paper6", 0.99, [False]),
        _run("fused", "paper6", 0.9, [True, False]),
        _run("fused", "paper6", 0.9, [True, True]),  # a second seed pools with the first
        _run("gnss", "paper6", 0.9, [False]),  # GNSS alone names no sidewalk
        _run("fused", "paper6", 0.1, [False] * 5, jaywalk_weight=0.0),  # off the base weight
        _run("inertial", "open", 0.9, [True], map_name="datasf+osm"),  # another map
    ]
    rows = reliability_rows(results, BASE, lambda r: r["spec"]["session"].split("/")[2])
    assert [(r["subset"], r["method"], r["footsteps"]) for r in rows] == [
        ("open", "fused", 2), ("paper6", "paper", 1), ("paper6", "fused", 4)]
    assert rows[2]["csa_0.9"] == pytest.approx(0.75) and rows[1]["csa_0.99"] == 0.0
    assert [r["subset"] for r in reliability_rows(results, BASE)] == [None, None]  # one group


def test_accuracy_coverage_counts_the_footsteps_inside_the_radius_and_leaves_the_rest_out():
    errors = pd.DataFrame({
        "euclid_m": [1.0, 2.0, 5.0, 9.0, 0.5, np.nan],
        "accuracy_m": [2.0, 2.0, 4.0, 6.0, np.nan, 3.0],  # the fifth has no radius (GNSS gap)
        "missing": [False, False, False, False, False, True],  # the last has no estimate
    })
    held, median = accuracy_coverage(errors)
    assert held == pytest.approx(0.5) and median == pytest.approx(3.0)  # 2 of the 4 scored: on and inside
    assert all(np.isnan(accuracy_coverage(errors.drop(columns="accuracy_m"))))
    rng = np.random.default_rng(3)  # a radius that is what it claims holds the walker 68 % of the time
    radius = rng.uniform(1, 10, 100_000)
    gaussian = pd.DataFrame({"accuracy_m": radius, "missing": False,
                             "euclid_m": radius / 1.0674 * np.sqrt(rng.exponential(1.0, len(radius)))})
    assert accuracy_coverage(gaussian)[0] == pytest.approx(0.68, abs=0.01)


def test_accuracy_curve_is_the_diagonal_for_errors_with_the_tail_it_assumes_and_below_it_for_a_heavier_one():
    rng = np.random.default_rng(4)
    radius = rng.uniform(1, 10, 100_000)
    sigma = radius / 1.5096  # the 68 % radius of a circular Gaussian is 1.5096 sigma
    gaussian = pd.DataFrame({"accuracy_m": radius, "missing": False,
                             "euclid_m": np.hypot(*(sigma * rng.standard_normal((2, len(radius)))))})
    curve = accuracy_curve(gaussian, tail_dof=math.inf)
    assert [c["claimed"] for c in curve] == list(RADIUS_SHARES)
    np.testing.assert_allclose([c["held"] for c in curve], RADIUS_SHARES, atol=0.01)
    # the default, heavier tail: Gaussian errors are held more often than claimed beyond 68 %
    held = {c["claimed"]: c["held"] for c in accuracy_curve(gaussian)}
    assert held[0.5] < 0.48 and held[0.95] > 0.99
    # bivariate t errors of the assumed degrees of freedom, with a radius right at 68 %: the diagonal
    scale = np.sqrt(rng.chisquare(TAIL_DOF, len(radius)) / TAIL_DOF)
    t_error = np.hypot(*rng.standard_normal((2, len(radius)))) / scale
    t_errors = gaussian.assign(euclid_m=radius * t_error / np.quantile(t_error, 0.68))
    np.testing.assert_allclose([c["held"] for c in accuracy_curve(t_errors)], RADIUS_SHARES, atol=0.01)
    # most footsteps a little nearer, 15 % of them 5 times as far off: above a Gaussian claim near the
    # middle, short of it far out
    tail = rng.random(len(radius)) < 0.15
    heavy = gaussian.assign(euclid_m=np.where(tail, 5.0, 0.8) * gaussian["euclid_m"])
    held = {c["claimed"]: c["held"] for c in accuracy_curve(heavy, tail_dof=math.inf)}
    assert held[0.5] > 0.53 and held[0.95] < 0.88
    assert accuracy_curve(gaussian.drop(columns="accuracy_m")) == []
