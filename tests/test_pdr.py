"""PDR: heading from the rotation vector, Weinberg step length, velocity, and the real fixture."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from scipy.spatial.transform import Rotation

from curbside.errors import CurbsideInputError
from curbside.localize.pdr import (
    PdrConfig,
    heading_deg,
    integrate_velocity,
    pdr_velocity,
    step_lengths,
    step_velocity,
    waypoint_errors,
)
from curbside.localize.readers.ipin import read_trial
from curbside.localize.steps import detect_steps, lowpass_taps
from curbside.projection import LocalFrame

H5 = Path(__file__).parent / "data" / "sessions" / "ipin2023-cut.h5"


def _pose(heading: float, pitch: float) -> Rotation:
    """Device-to-ENU rotation of a phone whose top edge points along ``heading`` (deg from north,
    clockwise), tilted up by ``pitch`` (0 = flat, screen up; 90 = upright, screen facing the walker)."""
    return Rotation.from_euler("z", -heading, degrees=True) * Rotation.from_euler("x", pitch, degrees=True)


@pytest.mark.parametrize("pitch", [0.0, 30.0, 60.0, 90.0, 110.0])
@pytest.mark.parametrize("heading", [0.0, 45.0, 90.0, 200.0, 315.0])
def test_heading_holds_from_flat_to_upright(heading, pitch):
    q = _pose(heading, pitch).as_quat()
    imu = pd.DataFrame([q], columns=["qx", "qy", "qz", "qw"])
    got = heading_deg(imu)[0]
    assert abs((got - heading + 180) % 360 - 180) < 1e-6


def _walk(heading: float, amplitude: float, cadence_hz: float = 2.0, seconds: float = 20.0) -> pd.DataFrame:
    t = np.arange(0, seconds, 0.02)
    magnitude = 9.81 + amplitude * np.sin(2 * np.pi * cadence_hz * t)
    rot = _pose(heading, 50.0)
    gravity_dir = rot.inv().apply([0.0, 0.0, 1.0])  # device-frame "up"
    acc = magnitude[:, None] * gravity_dir[None, :]
    q = np.repeat(rot.as_quat()[None, :], t.size, axis=0)
    return pd.DataFrame(np.column_stack([t, acc, np.zeros_like(acc), q]),
                        columns=["t", "ax", "ay", "az", "gx", "gy", "gz", "qx", "qy", "qz", "qw"])


def test_velocity_follows_weinberg_and_heading():
    amplitude, cadence = 2.0, 2.0
    imu = _walk(heading=120.0, amplitude=amplitude, cadence_hz=cadence)
    steps = detect_steps(imu)
    velocity = pdr_velocity(imu, steps)
    assert len(velocity) == len(steps)
    assert velocity[["ve", "vn"]].iloc[0].tolist() == [0.0, 0.0]
    inner = velocity.iloc[3:-3]
    config = PdrConfig()
    # The FIR low-pass passes the 2 Hz gait with the gain of its frequency response there.
    taps = lowpass_taps(config.steps)
    gain = abs(np.sum(taps * np.exp(-2j * np.pi * cadence / config.steps.rate_hz * np.arange(len(taps)))))
    expected_speed = config.weinberg_k * (2 * amplitude * gain) ** 0.25 * cadence
    np.testing.assert_allclose(np.hypot(inner["ve"], inner["vn"]), expected_speed, rtol=0.02)
    np.testing.assert_allclose(np.degrees(np.arctan2(inner["ve"], inner["vn"])) % 360, 120.0, atol=1e-6)


def test_integrated_velocity_is_the_sum_of_step_lengths():
    imu = _walk(heading=0.0, amplitude=1.5)
    velocity = pdr_velocity(imu, config=PdrConfig(weinberg_k=0.5))
    t = velocity["t"].to_numpy()
    lengths = np.hypot(velocity["ve"], velocity["vn"]).to_numpy()[1:] * np.diff(t)
    displacement = integrate_velocity(velocity, t[0], np.array([t[-1], t[0] + 0.5 * (t[1] - t[0])]))
    assert displacement[0, 1] == pytest.approx(lengths.sum(), rel=1e-12)
    assert displacement[1, 1] == pytest.approx(0.5 * lengths[0], rel=1e-12)


def test_no_steps_no_velocity_and_quaternion_required():
    imu = _walk(heading=0.0, amplitude=0.0)
    assert pdr_velocity(imu).empty
    with pytest.raises(CurbsideInputError, match="quaternion"):
        pdr_velocity(imu.drop(columns=["qx", "qy", "qz", "qw"]))


def test_step_by_step_with_a_rolling_buffer_gives_the_batch_rows_exactly():
    """The engine's way: each new footstep with only the rows around it, as in a live service."""
    imu = read_trial(H5, "TrainingTrial01_repetition01").imu
    steps = detect_steps(imu)
    batch = pdr_velocity(imu, steps)
    margin = PdrConfig().margin_s + 0.05
    rows, previous = [], None
    for step in steps:
        start = step - PdrConfig().max_step_interval_s if previous is None else previous
        buffer = imu[(imu["t"] >= start - margin) & (imu["t"] <= step + margin)]
        rows.append(step_velocity(buffer, np.array([step]), previous))
        previous = step
    pd.testing.assert_frame_equal(pd.concat(rows, ignore_index=True), batch, check_exact=True)


def test_a_step_after_a_stop_uses_the_last_interval_only():
    imu = _walk(heading=0.0, amplitude=2.0)
    config = PdrConfig()
    steps = detect_steps(imu)
    late = np.append(steps[steps < 8.0], 18.0)  # ten seconds and more without a footstep
    lengths = step_lengths(imu, late)
    start = 18.0 - config.max_step_interval_s - config.margin_s - 0.05
    recent = imu[(imu["t"] >= start) & (imu["t"] <= 18.0 + config.margin_s + 0.05)]
    assert lengths[-1] == step_lengths(recent, late[-2:])[0]
    velocity = pdr_velocity(imu, late)
    gap = late[-1] - late[-2]
    assert np.hypot(velocity["ve"].iat[-1], velocity["vn"].iat[-1]) * gap == pytest.approx(lengths[-1])


def test_real_walk_matches_surveyed_waypoints():
    """IPIN trial 01: from the first surveyed point, the PDR track passes near the next two."""
    session = read_trial(H5, "TrainingTrial01_repetition01")
    wp = session.waypoints
    velocity = pdr_velocity(session.imu)
    frame = LocalFrame.around(wp["lon"].iat[0], wp["lat"].iat[0])
    x, y = frame.to_xy(wp["lon"], wp["lat"])
    surveyed = np.hypot(np.diff(x), np.diff(y)).sum()
    moved = integrate_velocity(velocity, wp["t"].iat[0], wp["t"].to_numpy())
    walked = np.hypot(*np.diff(moved, axis=0).T).sum()
    assert walked == pytest.approx(surveyed, rel=0.15)
    assert waypoint_errors(velocity, wp).max() < 3.0


@pytest.mark.slow
def test_all_ipin_trials(shared_data):
    """Over the 38 single-floor IPIN trials: walked distance and waypoint error of the PDR baseline.

    (The 5 floor-changing trials walk detours by the stairs that the straight waypoint legs miss.)
    """
    from curbside.localize.pdr import evaluate_ipin

    table, scored = evaluate_ipin(str(shared_data / "ipin2023" / "ipin2023-t3.h5"))
    assert len(table) == 43
    single = table[~table["floors"].str.contains(",")]
    assert len(single) == 38
    assert single["ratio"].median() == pytest.approx(1.0, abs=0.05)
    assert single["ratio"].between(0.8, 1.2).all()
    errors = scored.loc[scored["trial"].isin(single["trial"]), "err_m"]
    assert np.median(errors) < 5.0 and np.percentile(errors, 90) < 10.0
