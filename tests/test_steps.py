"""Footstep detection against counts a person made, synthetic gaits, and standing still."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from curbside.localize.readers import read_any
from curbside.localize.readers.ipin import read_trial
from curbside.localize.steps import detect_steps

H5 = Path(__file__).parent / "data" / "sessions" / "ipin2023-cut.h5"

# Reference counts, made by eye before running the detector on these windows: the raw |a| was plotted
# in 5 s panels on a 0.25 s grid and each heel-strike hump (a rise of 1.5-4 m/s^2 above the
# trough before it) was marked as one step. Window edges avoid the stops at surveyed waypoints, where
# shuffling makes the count ambiguous. Full procedure in docs/sessions.md.
REFERENCE = [
    ("TrainingTrial01_repetition01", 61.5, 76.0, 20),  # phone SM-A520F, floor 0
    ("TrainingTrial01_repetition01", 77.0, 81.3, 7),
    ("TrainingTrial23_repetition03", 61.0, 76.0, 24),  # phone SM-G930F, floor -2
]
STANDING = [("TrainingTrial01_repetition01", 50.0, 61.0), ("TrainingTrial23_repetition03", 56.0, 61.0)]


@pytest.fixture(scope="module")
def detected() -> dict[str, np.ndarray]:
    return {trial: detect_steps(read_trial(H5, trial).imu) for trial, *_ in REFERENCE}


@pytest.mark.parametrize(("trial", "t0", "t1", "count"), REFERENCE)
def test_counts_match_a_person_per_window(detected, trial, t0, t1, count):
    steps = detected[trial]
    assert abs(int(((steps >= t0) & (steps < t1)).sum()) - count) <= 1


def test_total_count_within_five_percent(detected):
    total = sum(int(((detected[tr] >= a) & (detected[tr] < b)).sum()) for tr, a, b, _ in REFERENCE)
    reference = sum(c for *_, c in REFERENCE)
    assert abs(total - reference) <= 0.05 * reference


@pytest.mark.parametrize(("trial", "t0", "t1"), STANDING)
def test_no_steps_while_standing(detected, trial, t0, t1):
    steps = detected[trial]
    assert not ((steps >= t0) & (steps < t1)).any()


def _gait(cadence_hz: float, seconds: float, amplitude: float, seed: int) -> pd.DataFrame:
    """A phone held upright (gravity on +y) bobbing at the cadence, sampled at 50 Hz with jitter."""
    rng = np.random.default_rng(seed)
    t = np.cumsum(rng.uniform(0.8, 1.2, int(seconds * 50)) / 50)
    vertical = 9.81 + amplitude * np.sin(2 * np.pi * cadence_hz * t) + rng.normal(0, 0.15, t.size)
    side = rng.normal(0, 0.1, (2, t.size))
    return pd.DataFrame({"t": t, "ax": side[0], "ay": vertical, "az": side[1]})


@pytest.mark.parametrize(("cadence_hz", "amplitude"), [(1.4, 1.0), (1.8, 2.0), (2.3, 3.5)])
def test_synthetic_gait_gives_one_step_per_cycle(cadence_hz, amplitude):
    imu = _gait(cadence_hz, 30.0, amplitude, seed=7)
    steps = detect_steps(imu)
    span = imu["t"].iat[-1] - imu["t"].iat[0]
    assert abs(len(steps) - cadence_hz * span) <= 2
    assert np.diff(steps).min() >= 0.3


def test_quiet_phone_makes_no_steps():
    assert len(detect_steps(_gait(1.8, 20.0, 0.0, seed=3))) == 0


def test_minimum_interval_is_respected():
    imu = _gait(4.0, 10.0, 2.0, seed=1)  # faster than any walk: at most one step per 0.3 s
    steps = detect_steps(imu, lowpass_hz=6.0)
    assert len(steps) > 0
    assert np.diff(steps).min() >= 0.3 - 0.021


def test_sensorlogger_and_ipin_give_the_same_steps():
    """The same motion through two readers (Sensor Logger fixture = IPIN t_s 62-67 s shifted by 60 s)."""
    sensorlogger = detect_steps(read_any(H5.parent / "sensorlogger-ios.zip").imu)
    ipin = detect_steps(read_trial(H5, "TrainingTrial01_repetition01").imu)
    ipin = ipin[(ipin > 62.5) & (ipin < 66.5)] - 60.0
    inner = sensorlogger[(sensorlogger > 2.5) & (sensorlogger < 6.5)]
    np.testing.assert_allclose(inner, ipin, atol=0.05)
