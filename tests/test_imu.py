"""IMU preprocessing: world frame, start-up decision, gaps, saturation, gyroscope integration, bad input."""

from __future__ import annotations

import logging

import numpy as np
import pandas as pd
import pytest
from scipy.spatial.transform import Rotation

from curbside.errors import CurbsideInputError
from curbside.localize.gyro import SCAN_BLOCK, GyroscopeIntegrator, block_prefix_products, integrate_gyroscope
from curbside.localize.imu import (
    ImuConfig,
    WorldFrameStream,
    detect_quaternion_order,
    saturation_mask,
    world_frame_segments,
)

G = 9.81


def synthetic_imu(duration_s: float = 20.0, rate_hz: float = 50.0, seed: int = 0, jitter: float = 0.1,
                  yaw_rate: float = 0.2, quaternion: bool = True) -> tuple[pd.DataFrame, Rotation]:
    """A phone carried roughly flat, turning slowly, with a walking bounce; exact gyro and quaternion.

    Returns the ``imu.csv`` table and the true device-to-world rotations at its rows.
    """
    rng = np.random.default_rng(seed)
    n = int(duration_s * rate_hz)
    t = np.arange(n) / rate_hz + rng.uniform(-jitter, jitter, n) / rate_hz
    t.sort()
    yaw = 0.7 + yaw_rate * t
    roll = 0.08 * np.sin(2 * np.pi * 0.5 * t)
    pitch = 0.1 + 0.05 * np.sin(2 * np.pi * 0.3 * t)
    rot = Rotation.from_euler("ZXY", np.column_stack([yaw, pitch, roll]))
    a_world = np.column_stack([0.3 * np.sin(2 * np.pi * 2 * t), 0.2 * np.cos(2 * np.pi * 2 * t),
                               1.5 * np.sin(2 * np.pi * 2 * t)])
    acc = rot.inv().apply(a_world + [0.0, 0.0, G])
    # body rate such that R_k = R_{k-1} exp(w_k dt_k)
    rel = (rot[:-1].inv() * rot[1:]).as_rotvec() / np.diff(t)[:, None]
    gyro = np.vstack([rel[:1], rel])
    table = pd.DataFrame(np.column_stack([t, acc, gyro]), columns=["t", "ax", "ay", "az", "gx", "gy", "gz"])
    if quaternion:
        table[["qx", "qy", "qz", "qw"]] = rot.as_quat()
    return table, rot


def world_values(table: pd.DataFrame, **kwargs) -> np.ndarray:
    (seg,) = world_frame_segments(table, **kwargs)
    return seg[["wgx", "wgy", "wgz", "wax", "way", "waz"]].to_numpy()


def test_quaternion_puts_gravity_on_z_at_the_input_times():
    table, rot = synthetic_imu(rate_hz=47.3, jitter=0.3)
    (seg,) = world_frame_segments(table)
    assert np.array_equal(seg["t"], table["t"])
    assert np.median(seg["waz"]) == pytest.approx(G, abs=0.2)
    assert np.abs(seg[["wax", "way"]].to_numpy()).max() < 0.6
    assert np.allclose(seg[["wgx", "wgy", "wgz"]], rot.apply(np.array(table[["gx", "gy", "gz"]])))


def test_w_first_quaternion_is_detected_and_reordered(caplog):
    table, _ = synthetic_imu()
    reference = world_values(table)
    w_first = table.copy()
    q = table[["qx", "qy", "qz", "qw"]].to_numpy()
    w_first[["qx", "qy", "qz", "qw"]] = q[:, [3, 0, 1, 2]]  # columns hold w,x,y,z
    assert detect_quaternion_order(table[["ax", "ay", "az"]].to_numpy(), q) == "xyzw"
    with caplog.at_level(logging.WARNING):
        fixed = world_values(w_first)
    assert "wxyz" in caplog.text
    assert np.allclose(fixed, reference, atol=1e-9)


def test_world_to_device_quaternion_is_inverted():
    table, rot = synthetic_imu()
    inv = table.copy()
    inv[["qx", "qy", "qz", "qw"]] = rot.inv().as_quat()
    acc = inv[["ax", "ay", "az"]].to_numpy()
    assert detect_quaternion_order(acc, inv[["qx", "qy", "qz", "qw"]].to_numpy()) == "xyzw-inverse"
    assert np.allclose(world_values(inv), world_values(table), atol=1e-9)


def test_convention_is_decided_on_the_first_seconds_and_then_held():
    table, _ = synthetic_imu(duration_s=10.0)
    late = table["t"] > table["t"].iat[0] + 5.0
    q = table[["qx", "qy", "qz", "qw"]].to_numpy()
    table.loc[late, ["qx", "qy", "qz", "qw"]] = q[late.to_numpy()][:, [3, 0, 1, 2]]  # later rows w first
    stream = WorldFrameStream(ImuConfig(decision_s=2.0))
    stream.push(table[table["t"] < table["t"].iat[0] + 1.9])
    assert stream.quaternion_order is None and len(stream.take().t) == 0  # nothing before the decision
    stream.push(table[table["t"] >= table["t"].iat[0] + 1.9])
    assert stream.quaternion_order == "xyzw"
    out = stream.take()
    assert len(out.t) == len(table)
    assert np.abs(out.values[late.to_numpy(), 5] - G).max() > 3.0  # the late rows are misread, as decided


def test_non_unit_quaternion_is_an_error():
    table, _ = synthetic_imu()
    table[["qx", "qy", "qz", "qw"]] *= 3.0
    with pytest.raises(CurbsideInputError, match="unit quaternions"):
        world_frame_segments(table)


def test_missing_gyroscope_is_an_error():
    table, _ = synthetic_imu()
    with pytest.raises(CurbsideInputError, match="no gyroscope"):
        world_frame_segments(table.drop(columns=["gx", "gy", "gz"]))


def test_partial_quaternion_and_non_numeric_values_are_errors():
    table, _ = synthetic_imu()
    with pytest.raises(CurbsideInputError, match="partial quaternion"):
        world_frame_segments(table.drop(columns=["qw"]))
    table["ax"] = table["ax"].astype(object)
    table.loc[5, "ax"] = "n/a"
    with pytest.raises(CurbsideInputError, match="non-numeric"):
        world_frame_segments(table)


def test_all_zero_gyroscope_is_an_error():
    table, _ = synthetic_imu()
    table[["gx", "gy", "gz"]] = 0.0
    with pytest.raises(CurbsideInputError, match="all zero"):
        world_frame_segments(table)


def test_rate_too_low_is_an_error():
    table, _ = synthetic_imu(rate_hz=10.0)
    with pytest.raises(CurbsideInputError, match="below"):
        world_frame_segments(table)


def test_non_increasing_timestamps_are_an_error():
    table, _ = synthetic_imu()
    table.loc[10, "t"] = table.loc[9, "t"]
    with pytest.raises(CurbsideInputError, match="row 11"):
        world_frame_segments(table)


def test_rejected_chunks_leave_the_stream_as_it_was():
    table, _ = synthetic_imu(duration_s=6.0)
    reference = WorldFrameStream()
    reference.push(table)
    reference.finish()
    stream = WorldFrameStream()
    stream.push(table.iloc[:100])
    with pytest.raises(CurbsideInputError, match="row 101"):
        stream.push(table.iloc[99:150])  # overlaps the previous chunk
    with pytest.raises(CurbsideInputError, match="columns changed"):
        stream.push(table.iloc[100:150].drop(columns=["qx", "qy", "qz", "qw"]))
    stream.push(table.iloc[100:])
    stream.finish()
    ours, theirs = stream.take(), reference.take()
    assert np.array_equal(ours.t, theirs.t) and np.array_equal(ours.values, theirs.values)
    with pytest.raises(RuntimeError):
        stream.push(table.iloc[:1])


def test_short_gap_is_bridged_and_long_gap_splits(caplog):
    table, _ = synthetic_imu(duration_s=30.0)
    short = table[(table["t"] < 10.0) | (table["t"] > 10.3)]
    assert len(world_frame_segments(short)) == 1
    long = table[(table["t"] < 10.0) | (table["t"] > 11.5)]
    with caplog.at_level(logging.WARNING):
        segments = world_frame_segments(long)
    assert len(segments) == 2
    assert segments[0]["t"].iat[-1] < 10.0 < 11.5 < segments[1]["t"].iat[0]
    assert "splits" in caplog.text


def test_nan_rows_are_dropped_and_handled_as_gaps(caplog):
    table, _ = synthetic_imu()
    table.loc[100:102, "ax"] = np.nan
    with caplog.at_level(logging.WARNING):
        (seg,) = world_frame_segments(table)
    assert "3 row(s) with NaN" in caplog.text
    assert len(seg) == len(table) - 3 and np.isfinite(seg.to_numpy()).all()


def test_saturated_samples_are_counted_with_a_warning(caplog):
    table, _ = synthetic_imu()
    table.loc[200:205, "az"] = 39.2  # a +-4 g accelerometer pinned at its limit
    stream = WorldFrameStream()
    with caplog.at_level(logging.WARNING):
        for lo in range(0, len(table), 7):
            stream.push(table.iloc[lo : lo + 7])
        stream.finish()
    assert "saturation" in caplog.text
    assert stream.saturated_samples == 6


def test_saturation_needs_a_flat_top_above_the_floor():
    values = np.zeros((100, 2))
    values[:, 0] = np.linspace(-25, 25, 100)  # above the floor but never flat
    values[10:13, 1] = 0.5  # flat but below the floor
    floors = np.array([19.6, 1.0])
    assert not saturation_mask(values, floors).any()
    values[50:53, 1] = -4.0  # flat at -4 for 3 samples: clipped
    values[70:72, 1] = 4.0  # only 2 samples: not
    assert np.flatnonzero(saturation_mask(values, floors)).tolist() == [50, 51, 52]


def test_gyroscope_integration_matches_truth_up_to_a_constant_yaw():
    table, truth = synthetic_imu(duration_s=60.0, rate_hz=100.0, jitter=0.0)
    est = integrate_gyroscope(table["t"].to_numpy(), table[["gx", "gy", "gz"]].to_numpy(),
                              table[["ax", "ay", "az"]].to_numpy())
    diff = est * truth.inv()  # world-frame discrepancy: should be a fixed rotation about z
    rv = diff.as_rotvec()
    tilt_deg = np.degrees(np.linalg.norm(rv[:, :2], axis=1))
    yaw = np.unwrap(rv[:, 2])
    assert np.percentile(tilt_deg, 95) < 2.0
    assert np.ptp(yaw) < np.radians(2.0)


def test_gyroscope_integration_is_chunk_invariant():
    table, _ = synthetic_imu(duration_s=8.0, rate_hz=100.0, quaternion=False)
    cols = [table["t"].to_numpy(), table[["gx", "gy", "gz"]].to_numpy(), table[["ax", "ay", "az"]].to_numpy()]
    whole = integrate_gyroscope(*cols).as_quat()
    integrator = GyroscopeIntegrator()
    cuts = [0, 1, 2, SCAN_BLOCK - 1, SCAN_BLOCK + 5, 3 * SCAN_BLOCK, 3 * SCAN_BLOCK + 1, 500, len(table)]
    parts = [integrator.update(*(c[a:b] for c in cols)).as_quat()
             for a, b in zip(cuts[:-1], cuts[1:], strict=True)]
    assert np.array_equal(np.vstack(parts), whole)


def test_block_prefix_product_equals_sequential_integration():
    rng = np.random.default_rng(3)
    n = 2 * SCAN_BLOCK
    increments = Rotation.from_rotvec(rng.normal(0, 0.05, (n, 3))).as_quat()
    sequential = [Rotation.from_quat(increments[0])]
    for k in range(1, SCAN_BLOCK):
        sequential.append(sequential[-1] * Rotation.from_quat(increments[k]))
    prefix = block_prefix_products(increments.reshape(2, SCAN_BLOCK, 4))
    dots = np.einsum("ij,ij->i", prefix[0], Rotation.concatenate(sequential).as_quat())
    assert np.allclose(np.abs(dots), 1.0)
    # a row depends on the rows before it only: a padded partial block gives the same rows
    padded = np.tile([0.0, 0.0, 0.0, 1.0], (SCAN_BLOCK, 1))
    padded[:10] = increments[:10]
    assert np.array_equal(block_prefix_products(padded[None])[0, :10], prefix[0, :10])


def test_without_quaternion_the_gyroscope_is_integrated():
    table, _ = synthetic_imu(quaternion=False)
    values = world_values(table)
    assert np.median(values[:, 5]) == pytest.approx(G, abs=0.2)
    # the yaw rate shows up on the world z gyroscope channel
    assert np.median(values[:, 2]) == pytest.approx(0.2, abs=0.02)
