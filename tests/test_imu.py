"""IMU preprocessing: world frame, resampling, quaternion order, gyroscope integration, bad input."""

from __future__ import annotations

import logging

import numpy as np
import pandas as pd
import pytest
from scipy.spatial.transform import Rotation

from curbside.errors import CurbsideInputError
from curbside.localize import imu as imu_mod
from curbside.localize.imu import (
    detect_quaternion_order,
    integrate_gyroscope,
    preprocess,
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


def test_resamples_irregular_rate_onto_uniform_grid_in_world_frame():
    table, _ = synthetic_imu(rate_hz=47.3, jitter=0.3)
    (seg,) = preprocess(table, rate_hz=200.0)
    assert np.allclose(np.diff(seg.t), 1 / 200.0)
    assert seg.t[0] == pytest.approx(table["t"].iat[0])
    # gravity ends up on +z and the horizontal walking oscillation stays small
    assert np.median(seg.acc[:, 2]) == pytest.approx(G, abs=0.2)
    assert np.abs(seg.acc[:, :2]).max() < 0.6
    assert seg.features.shape == (len(seg.t), 6) and seg.features.dtype == np.float32


def test_w_first_quaternion_is_detected_and_reordered(caplog):
    table, _ = synthetic_imu()
    reference = world_frame_segments(table)[0]
    w_first = table.copy()
    q = table[["qx", "qy", "qz", "qw"]].to_numpy()
    w_first[["qx", "qy", "qz", "qw"]] = q[:, [3, 0, 1, 2]]  # columns hold w,x,y,z
    assert detect_quaternion_order(table[["ax", "ay", "az"]].to_numpy(), q) == "xyzw"
    with caplog.at_level(logging.WARNING):
        fixed = world_frame_segments(w_first)[0]
    assert "wxyz" in caplog.text
    assert np.allclose(fixed[["wax", "way", "waz"]], reference[["wax", "way", "waz"]], atol=1e-9)


def test_world_to_device_quaternion_is_inverted():
    table, rot = synthetic_imu()
    inv = table.copy()
    inv[["qx", "qy", "qz", "qw"]] = rot.inv().as_quat()
    acc = inv[["ax", "ay", "az"]].to_numpy()
    assert detect_quaternion_order(acc, inv[["qx", "qy", "qz", "qw"]].to_numpy()) == "xyzw-inverse"


def test_non_unit_quaternion_is_an_error():
    table, _ = synthetic_imu()
    table[["qx", "qy", "qz", "qw"]] *= 3.0
    with pytest.raises(CurbsideInputError, match="unit quaternions"):
        preprocess(table)


def test_missing_gyroscope_is_an_error():
    table, _ = synthetic_imu()
    with pytest.raises(CurbsideInputError, match="no gyroscope"):
        preprocess(table.drop(columns=["gx", "gy", "gz"]))


def test_all_zero_gyroscope_is_an_error():
    table, _ = synthetic_imu()
    table[["gx", "gy", "gz"]] = 0.0
    with pytest.raises(CurbsideInputError, match="all zero"):
        preprocess(table)


def test_rate_too_low_is_an_error():
    table, _ = synthetic_imu(rate_hz=10.0)
    with pytest.raises(CurbsideInputError, match="below"):
        preprocess(table)


def test_non_increasing_timestamps_are_an_error():
    table, _ = synthetic_imu()
    table.loc[10, "t"] = table.loc[9, "t"]
    with pytest.raises(CurbsideInputError, match="row 11"):
        preprocess(table)


def test_short_gap_is_interpolated_and_long_gap_splits(caplog):
    table, _ = synthetic_imu(duration_s=30.0)
    short = table[(table["t"] < 10.0) | (table["t"] > 10.3)]
    assert len(preprocess(short)) == 1
    long = table[(table["t"] < 10.0) | (table["t"] > 11.5)]
    with caplog.at_level(logging.WARNING):
        segments = preprocess(long)
    assert len(segments) == 2
    assert segments[0].t[-1] < 10.0 < 11.5 < segments[1].t[0]
    assert "split" in caplog.text


def test_nan_rows_are_dropped_and_handled_as_gaps(caplog):
    table, _ = synthetic_imu()
    table.loc[100:102, "ax"] = np.nan
    with caplog.at_level(logging.WARNING):
        (seg,) = preprocess(table)
    assert "3 row(s) with NaN" in caplog.text
    assert np.isfinite(seg.acc).all()


def test_saturated_samples_are_flagged_with_a_warning(caplog):
    table, _ = synthetic_imu()
    table.loc[200:205, "az"] = 39.2  # a +-4 g accelerometer pinned at its limit
    with caplog.at_level(logging.WARNING):
        (seg,) = preprocess(table)
    assert "saturation" in caplog.text
    hit = (seg.t > table["t"].iat[199]) & (seg.t < table["t"].iat[206])
    assert seg.saturated[hit].all() and not seg.saturated[~hit].any()


def test_saturation_needs_a_flat_top_above_the_floor():
    values = np.zeros((100, 2))
    values[:, 0] = np.linspace(-1, 1, 100)  # unique extreme: not clipped
    values[:3, 1] = 0.5  # repeated extreme but below the floor
    assert not saturation_mask(values, np.array([0.1, 1.0])).any()


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


def test_prefix_product_equals_sequential_integration():
    rng = np.random.default_rng(3)
    n = 257
    t = np.cumsum(rng.uniform(0.009, 0.011, n))
    gyro = rng.normal(0, 1.0, (n, 3))
    dt = np.diff(t, prepend=t[0])
    omega = np.vstack([gyro[:1], 0.5 * (gyro[1:] + gyro[:-1])])
    sequential = [Rotation.identity()]
    for k in range(1, n):
        sequential.append(sequential[-1] * Rotation.from_rotvec(omega[k] * dt[k]))
    prefix = Rotation.from_rotvec(omega * dt[:, None]).as_quat()
    d = 1
    while d < n:
        prefix[d:] = imu_mod._quat_mul(prefix[:-d], prefix[d:])
        d *= 2
    ref = Rotation.concatenate(sequential)
    dots = np.einsum("ij,ij->i", Rotation.from_quat(prefix).as_quat(), ref.as_quat())
    assert np.allclose(np.abs(dots), 1.0)


def test_without_quaternion_the_gyroscope_is_integrated():
    table, _ = synthetic_imu(quaternion=False)
    (seg,) = preprocess(table)
    assert np.median(seg.acc[:, 2]) == pytest.approx(G, abs=0.2)
    # the yaw rate shows up on the world z gyroscope channel
    assert np.median(seg.gyro[:, 2]) == pytest.approx(0.2, abs=0.02)
