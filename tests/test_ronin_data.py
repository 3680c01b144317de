"""RoNIN training data: the RoNIN HDF5 layout, weak labels, plan rotation, splits, windows, caches."""

from __future__ import annotations

import h5py
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from curbside.errors import CurbsideInputError
from curbside.localize.ronin import data
from curbside.localize.ronin.data import Recording, WindowSet

G = 9.81


def write_ronin_sequence(folder, speed=1.2, heading=0.4, game_yaw_offset=0.9, duration_s=12.0, seed=0,
                         gap_s=0.0):
    """A tiny sequence in the official RoNIN layout: a straight walk at ``speed`` along ``heading``
    (Tango frame); the game rotation vector's yaw is off by ``game_yaw_offset``; with ``gap_s``, the
    recording stops that long half-way."""
    rng = np.random.default_rng(seed)
    t = np.arange(int(duration_s * 200)) / 200.0
    t[len(t) // 2:] += gap_s
    yaw = heading + 0.05 * np.sin(2 * np.pi * 0.2 * t)
    tango = Rotation.from_euler("ZX", np.column_stack([yaw - np.pi / 2, np.full_like(t, 0.1)]))
    game = Rotation.from_euler("z", -game_yaw_offset) * tango
    acc = tango.inv().apply(np.column_stack([np.zeros((len(t), 2)), G + np.sin(2 * np.pi * 2 * t)]))
    gyro = rng.normal(0, 0.01, (len(t), 3))
    pos = np.column_stack([speed * t * np.cos(heading), speed * t * np.sin(heading), np.zeros_like(t)])
    folder.mkdir(parents=True)
    with h5py.File(folder / "data.hdf5", "w") as f:
        f["synced/time"] = t
        f["synced/gyro"] = gyro
        f["synced/acce"] = acc
        f["synced/game_rv"] = game.as_quat()[:, [3, 0, 1, 2]]  # w, x, y, z
        f["pose/tango_pos"] = pos
        f["pose/tango_ori"] = tango.as_quat()[:, [3, 0, 1, 2]]
    return folder


def test_ronin_layout_labels_are_in_the_game_rotation_frame(tmp_path):
    write_ronin_sequence(tmp_path / "seq_a", speed=1.2, heading=0.4, game_yaw_offset=0.9)
    (rec,) = data.read_ronin_dir(tmp_path, progress=False)
    assert rec.source == "ronin" and rec.name == "ronin/seq_a"
    windows = WindowSet.build([rec], window=200, stride=10, rate_hz=200.0)
    v = windows.targets.astype(float)
    assert np.allclose(np.linalg.norm(v, axis=1), 1.2, atol=0.01)
    assert np.allclose(np.arctan2(v[:, 1], v[:, 0]), 0.4 - 0.9, atol=0.01)
    # the inputs are in the same (game) frame: gravity on +z
    assert np.median(rec.features[:, 5]) == pytest.approx(G, abs=0.05)


def test_a_ronin_sequence_with_a_gap_gives_every_stretch(tmp_path):
    write_ronin_sequence(tmp_path / "seq_g", duration_s=16.0, gap_s=3.0)
    recs = data.read_ronin_dir(tmp_path, progress=False)
    assert [r.name for r in recs] == ["ronin/seq_g", "ronin/seq_g#1"]
    assert recs[0].split == recs[1].split  # one sequence, one split: no stretch of it leaks into another
    assert recs[0].t[-1] < 8.0 < 11.0 <= recs[1].t[0]
    assert sum(len(r.t) for r in recs) >= 0.95 * 16 * 200


def test_ronin_layout_missing_dataset_is_an_input_error(tmp_path):
    folder = tmp_path / "seq"
    folder.mkdir()
    with h5py.File(folder / "data.hdf5", "w") as f:
        f["synced/time"] = np.arange(10.0)
    with pytest.raises(CurbsideInputError, match="missing dataset"):
        data.read_ronin_sequence(folder)
    with pytest.raises(CurbsideInputError, match="no such folder"):
        data.read_ronin_dir(tmp_path / "empty_dir_that_is_absent")
    (tmp_path / "empty").mkdir()
    with pytest.raises(CurbsideInputError, match="no \\*/data.hdf5"):
        data.read_ronin_dir(tmp_path / "empty")


def test_plan_rotation_recovers_the_floor_frame_rotation():
    rng = np.random.default_rng(1)
    true_angle = np.radians(35.0)
    wp_world = np.cumsum(rng.uniform(-10, 10, (6, 2)), axis=0)
    wp_t = np.arange(6) * 8.0
    t = np.linspace(0, wp_t[-1], 2000)
    seg = np.clip(np.searchsorted(wp_t, t, side="right") - 1, 0, 4)
    direction = wp_world[seg + 1] - wp_world[seg]
    forward = direction / np.linalg.norm(direction, axis=1, keepdims=True)
    c, s = np.cos(-true_angle), np.sin(-true_angle)
    wp_plan = wp_world @ np.array([[c, s], [-s, c]])  # the plan is the world turned by -35 degrees
    angle, consistency = data.plan_rotation(t, forward, np.column_stack([wp_t, wp_plan]))
    assert np.degrees(angle) == pytest.approx(35.0, abs=0.5)
    assert consistency > 0.99


def test_splits_are_by_recording_and_reproducible():
    names = [f"{i:024x}" for i in range(3000)]
    splits = [data.split_of(f"ms/site1/F1/{n}", "ms") for n in names]
    assert splits == [data.split_of(f"ms/site2/B1/{n}", "ms") for n in names]  # by path id only
    share = {k: splits.count(k) / len(splits) for k in ("test", "val", "train")}
    assert 0.12 < share["test"] < 0.18 and 0.05 < share["val"] < 0.09
    assert data.split_of("ipin/TrainingTrial03_repetition04", "ipin") == "test"
    assert data.split_of("ipin/TrainingTrial03_repetition03", "ipin") == "train"


def _recording(name, n=1000, rate=50.0, speed=1.0):
    t = np.arange(n) / rate
    feats = np.tile(np.arange(6, dtype=np.float32), (n, 1))
    pos = np.array([[t[0], 0.0, 0.0], [t[-1], speed * (t[-1] - t[0]), 0.0]])
    return Recording(name, "ms", t, feats, pos, "train")


def test_windows_never_straddle_recordings_and_labels_are_mean_velocity():
    recs = [_recording("a", n=500, speed=1.0), _recording("b", n=300, speed=2.0)]
    ws = WindowSet.build(recs, window=200, stride=10, rate_hz=200.0)
    boundary = len(recs[0].on_grid(200.0)[0])
    ends = ws.starts + ws.window - 1
    assert not np.any((ws.starts < boundary) & (ends >= boundary))
    assert np.allclose(ws.targets[ws.recording == 0], [1.0, 0.0], atol=1e-5)
    assert np.allclose(ws.targets[ws.recording == 1], [2.0, 0.0], atol=1e-5)


def test_prepared_recordings_round_trip(tmp_path):
    recs = [_recording("a"), _recording("b", n=700)]
    path = data.save_recordings(recs, tmp_path / "prep.npz")
    back = data.load_recordings(path)
    assert [r.name for r in back] == ["a", "b"]
    assert np.array_equal(back[1].features, recs[1].features)
    assert np.array_equal(back[0].positions, recs[0].positions)
    (tmp_path / "bad.npz").write_bytes(b"nope")
    with pytest.raises(CurbsideInputError, match="prepared"):
        data.load_recordings(tmp_path / "bad.npz")


def test_prepare_without_sources_is_an_input_error():
    with pytest.raises(CurbsideInputError, match="no recordings given"):
        data.prepare_recordings()


def test_missing_ms_file_is_an_input_error(tmp_path):
    with pytest.raises(CurbsideInputError, match="no such file"):
        data.read_ms_indoor(tmp_path / "absent.h5")
