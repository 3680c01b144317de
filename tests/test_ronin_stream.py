"""Streaming RoNIN: chunk invariance of the windows, batch invariance of inference, the timing contract."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from conftest import TEST_DATA
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st
from test_imu import synthetic_imu

from curbside.errors import CurbsideInputError
from curbside.localize.imu import world_frame_segments
from curbside.localize.readers.ipin import read_trial
from curbside.localize.ronin.data import Recording
from curbside.localize.ronin.evaluate import ronin_trajectory
from curbside.localize.ronin.infer import infer_windows, load_model, ronin_velocity
from curbside.localize.ronin.stream import RoninStream, RoninStreamConfig

CUT = "ipin2023-cut.h5"
TRIALS = ("IPIN2023_T3_TrainingTrial01_repetition01", "IPIN2023_T3_TrainingTrial23_repetition03")


def real_imu(test_data, trial: str = TRIALS[0]) -> pd.DataFrame:
    """12 s of a real phone walk (standing, then walking) with a 0.3 s hole, a 0.8 s gap and NaN rows."""
    imu = read_trial(test_data / "sessions" / CUT, trial).imu
    t = imu["t"]
    imu = imu[(t > 58.0) & (t < 70.0) & ~((t > 62.0) & (t < 62.3)) & ~((t > 65.0) & (t < 65.8))].copy()
    imu.iloc[100:102, 1] = np.nan
    return imu.reset_index(drop=True)


def stream_in_chunks(table: pd.DataFrame, sizes: list[int]) -> tuple[np.ndarray, np.ndarray]:
    """Push ``table`` in chunks of ``sizes`` (cycled), take windows after every push."""
    stream = RoninStream()
    t_parts, w_parts = [], []
    lo, k = 0, 0
    while lo < len(table):
        hi = lo + sizes[k % len(sizes)]
        stream.push(table.iloc[lo:hi])
        t_mid, windows = stream.take_windows()
        t_parts.append(t_mid)
        w_parts.append(windows)
        lo, k = hi, k + 1
    stream.finish()
    assert stream.complete_until == np.inf
    t_mid, windows = stream.take_windows()
    return np.concatenate([*t_parts, t_mid]), np.concatenate([*w_parts, windows])


def whole(table: pd.DataFrame) -> tuple[np.ndarray, np.ndarray]:
    stream = RoninStream()
    stream.push(table)
    stream.finish()
    return stream.take_windows()


@pytest.fixture(scope="module")
def real_tables() -> dict[str, pd.DataFrame]:
    with_q = real_imu(TEST_DATA)
    return {"quaternion": with_q, "gyroscope": with_q.drop(columns=["qx", "qy", "qz", "qw"])}


@pytest.fixture(scope="module")
def reference(real_tables) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    return {name: whole(table) for name, table in real_tables.items()}


@settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(orientation=st.sampled_from(["quaternion", "gyroscope"]),
       sizes=st.lists(st.integers(min_value=1, max_value=80), min_size=1, max_size=12))
@example(orientation="quaternion", sizes=[1])
@example(orientation="gyroscope", sizes=[1])
def test_windows_are_bit_identical_whatever_the_chunking(real_tables, reference, orientation, sizes):
    t_mid, windows = stream_in_chunks(real_tables[orientation], sizes)
    ref_t, ref_w = reference[orientation]
    assert len(ref_t) > 50
    assert np.array_equal(t_mid, ref_t)
    assert np.array_equal(windows, ref_w)


def test_complete_until_and_latency_contract(real_tables, reference):
    """After every push: exactly the windows centred at or before ``complete_until`` exist, and every
    window whose centre is ``latency_s`` before the last pushed sample (after start-up) exists."""
    table = real_tables["quaternion"]
    ref_t, _ = reference["quaternion"]
    stream = RoninStream()
    produced: list[np.ndarray] = []
    for lo in range(0, len(table), 9):
        stream.push(table.iloc[lo : lo + 9])
        produced.append(stream.take_windows()[0])
        done = np.concatenate(produced)
        assert np.array_equal(done, ref_t[ref_t <= stream.complete_until])
        last_t = table["t"].iloc[: lo + 9].dropna().iat[-1]
        if last_t > table["t"].iat[0] + stream.config.imu.decision_s + 0.1:
            due = ref_t[ref_t + stream.latency_s <= last_t - 1e-9]
            assert np.isin(due, done).all()
    assert stream.latency_s == pytest.approx(199 / 400)


def test_windows_sit_on_a_uniform_grid_anchored_at_each_segment(real_tables, reference):
    table = real_tables["quaternion"]
    t_mid, windows = reference["quaternion"]
    config = RoninStreamConfig()
    segments = world_frame_segments(table, min_duration_s=0.0)
    assert len(segments) == 2  # the 0.8 s gap splits, the 0.3 s hole does not
    for seg in segments:
        t0 = seg["t"].iat[0]
        mine = (t_mid > t0) & (t_mid < seg["t"].iat[-1])
        first = np.flatnonzero(mine)[0]
        assert t_mid[first] == pytest.approx(t0 + 199 / 400)
        assert np.allclose(np.diff(t_mid[mine]), config.stride / 200)
        grid = t0 + np.arange(200) / 200.0
        expected = np.column_stack([np.interp(grid, seg["t"], seg[c]) for c in seg.columns[1:]])
        assert np.allclose(windows[first].T, expected, atol=1e-5)


def test_inference_is_bit_identical_whatever_shares_the_batch(test_data):
    """Windows of two sessions mixed in one call, in any order and position, give each window the
    velocity it gets alone; so does a lone window padded to the batch shape."""
    model = load_model()
    sessions = [whole(real_imu(test_data, trial))[1] for trial in TRIALS]
    alone = [infer_windows(model, w) for w in sessions]
    mixed = np.concatenate(sessions)
    order = np.random.default_rng(0).permutation(len(mixed))
    velocity = np.empty((len(mixed), 2))
    velocity[order] = infer_windows(model, mixed[order])
    assert np.array_equal(velocity, np.concatenate(alone))
    assert np.array_equal(infer_windows(model, sessions[1][7:8]), alone[1][7:8])
    assert np.array_equal(infer_windows(model, sessions[0][:100], batch_size=32), alone[0][:100])


def test_infer_windows_rejects_other_shapes():
    with pytest.raises(ValueError, match="windows must be"):
        infer_windows(load_model(), np.zeros((3, 6, 100), np.float32))


def test_streamed_session_gives_the_batch_command_velocities(real_tables):
    table = real_tables["quaternion"]
    model = load_model()
    t_mid, windows = stream_in_chunks(table, [25])
    batch = ronin_velocity(table, model)
    assert np.array_equal(batch["t"], t_mid)
    assert np.array_equal(batch[["ve", "vn"]].to_numpy(), infer_windows(model, windows))


def test_config_is_checked():
    with pytest.raises(ValueError, match="stride"):
        RoninStreamConfig(stride=0)
    table, _ = synthetic_imu(duration_s=5.0)
    with pytest.raises(CurbsideInputError, match="stream cuts 100"):
        ronin_velocity(table, load_model(), RoninStreamConfig(window=100))


def test_trajectory_uses_the_stream_and_keeps_windows_inside_the_ground_truth():
    rng = np.random.default_rng(0)
    t = np.arange(0.0, 30.0, 0.02)
    features = np.column_stack([rng.normal(0, 0.3, (len(t), 5)), 9.81 + rng.normal(0, 1, len(t))])
    positions = np.array([[5.0, 0.0, 0.0], [25.0, 20.0, 0.0]])
    rec = Recording("r", "ms", t, features.astype(np.float32), positions)
    config = RoninStreamConfig(stride=40)
    t_c, estimate, truth = ronin_trajectory(load_model(), rec, config)
    assert t_c[0] - config.half_window_s >= 5.0 and t_c[-1] + config.half_window_s <= 25.0
    assert np.allclose(np.diff(t_c), 0.2)
    assert np.allclose(truth[:, 0], t_c - 5.0) and np.array_equal(estimate[0], truth[0])
