"""The cheaper per-request streaming path gives the numbers the earlier one gave, at every batch size.

``tests/data/stream_reference.npz`` holds what the streaming stages produced on the bundled IPIN walk
*before* their per-call overheads were cut (``benchmarks/bench_stream_rows.py`` measures the cost):
every footstep, every RoNIN window (its centre and a SHA-256 of its bytes), the velocities, the track
of a :class:`~curbside.localize.live.LiveSession`, and what each push returned and declared final,
for 1, 10 and 50 rows per push. The code of today must reproduce them bit for bit.

Regenerate only on purpose (a change of the method, not of its speed)::

    python tests/test_stream_cost.py --write
"""

from __future__ import annotations

import hashlib
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from curbside.localize.engine import StartPose
from curbside.localize.live import GNSS_COLUMNS, IMU_QUAT_COLUMNS, InferenceQueue, LiveSession
from curbside.localize.ronin.stream import RoninStream
from curbside.localize.runconfig import RunConfig
from curbside.localize.session import Session
from curbside.localize.steps import StepDetector

REFERENCE = Path(__file__).parent / "data" / "stream_reference.npz"
BATCH_ROWS = (1, 10, 50)
#: Windows of a partial RoNIN batch that make the test's inference run (the service waits 0.25 s).
INFER_EVERY = 5


def _stages(imu: np.ndarray, rows: int, held: bool = False) -> dict[str, np.ndarray]:
    """The footstep detector and the RoNIN stream fed ``rows`` rows per push, directly; ``held``: the
    RoNIN stream through :meth:`RoninStream.push_rows` (as a live session), else :meth:`RoninStream.push`."""
    detector, ronin = StepDetector(), RoninStream()
    steps, t_mid, windows, per_push = [], [], [], []
    for k in range(0, len(imu), rows):
        batch = imu[k : k + rows]
        found = detector.push(batch[:, 0], batch[:, 1:4], batch[:, 4:7])
        if held:
            ronin.push_rows(batch, IMU_QUAT_COLUMNS)
        else:
            ronin.push(pd.DataFrame(batch, columns=list(IMU_QUAT_COLUMNS)))
        t, w = ronin.take_windows()
        steps.append(found)
        t_mid.append(t)
        windows.append(w)
        per_push.append([len(found), detector.complete_until, len(t), ronin.complete_until])
    steps.append(detector.finish())
    ronin.finish()
    t, w = ronin.take_windows()
    t_mid.append(t)
    windows.append(w)
    all_windows = np.concatenate(windows)
    return {
        "steps": np.concatenate(steps),
        "t_mid": np.concatenate(t_mid),
        "windows_sha256": np.array(hashlib.sha256(np.ascontiguousarray(all_windows).tobytes()).hexdigest()),
        "per_push": np.array(per_push, float),
    }


def _live(walk: Session, imu: np.ndarray, rows: int, model) -> dict[str, np.ndarray]:
    """A live session fed ``rows`` IMU rows per request (each fix with the rows of its time)."""
    gnss = walk.gnss[list(GNSS_COLUMNS)].to_numpy(float)
    live = LiveSession(RunConfig.for_mode("fused", seed=3), start=StartPose(**walk.meta["start"]))
    queue = InferenceQueue(model)
    t_mid, velocity, updates = [], [], []
    fix_lo = 0
    for k in range(0, len(imu), rows):
        batch = imu[k : k + rows]
        last = k + rows >= len(imu)
        fix_hi = len(gnss) if last else int(np.searchsorted(gnss[:, 0], batch[-1, 0], side="right"))
        live.push(batch, gnss[fix_lo:fix_hi], IMU_QUAT_COLUMNS)
        fix_lo = fix_hi
        queue.collect(live)
        if queue.pending >= INFER_EVERY:
            taken = queue.take()
            v = queue.infer(taken)
            queue.deliver(taken, v)
            t_mid.extend(t for _, t, _ in taken)
            velocity.append(v)
        live.advance()
        updates.append(len(live.rows))
    live.finish_streams()
    queue.collect(live)
    taken = queue.take()
    if taken:
        v = queue.infer(taken)
        queue.deliver(taken, v)
        t_mid.extend(t for _, t, _ in taken)
        velocity.append(v)
    live.advance()
    track = live.result().track
    return {
        "velocity_t": np.concatenate(t_mid),
        "velocity": np.concatenate(velocity),
        "updates": np.array(updates),
        "track_csv": np.array(track.to_csv(index=False, float_format="%.17g")),
    }


def stream_outputs(walk: Session, model) -> dict[str, np.ndarray]:
    """Everything the reference holds, keyed ``"{rows}/{name}"``."""
    imu = walk.imu[list(IMU_QUAT_COLUMNS)].to_numpy(float)
    out = {}
    for rows in BATCH_ROWS:
        for name, value in {**_stages(imu, rows), **_live(walk, imu, rows, model)}.items():
            out[f"{rows}/{name}"] = value
    return out


@pytest.fixture(scope="module")
def outputs(ipin_walk, ronin_model) -> dict[str, np.ndarray]:
    import torch

    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # as the service runs it; more threads only spin on a busy 2-core machine
    try:
        return stream_outputs(ipin_walk, ronin_model)
    finally:
        torch.set_num_threads(threads)


@pytest.fixture(scope="module")
def reference() -> dict[str, np.ndarray]:
    with np.load(REFERENCE) as data:
        return dict(data)


@pytest.mark.parametrize("rows", BATCH_ROWS)
def test_footsteps_and_windows_are_bit_identical_to_the_reference(ipin_walk, outputs, reference, rows):
    held = _stages(ipin_walk.imu[list(IMU_QUAT_COLUMNS)].to_numpy(float), rows, held=True)
    for name in ("steps", "t_mid", "windows_sha256", "per_push"):
        np.testing.assert_array_equal(outputs[f"{rows}/{name}"], reference[f"{rows}/{name}"], err_msg=name)
        np.testing.assert_array_equal(held[name], reference[f"{rows}/{name}"], err_msg=f"{name}, push_rows")
    assert len(reference[f"{rows}/steps"]) > 20 and len(reference[f"{rows}/t_mid"]) > 250


@pytest.mark.parametrize("rows", BATCH_ROWS)
def test_live_velocities_updates_and_track_are_identical_to_the_reference(outputs, reference, rows):
    np.testing.assert_array_equal(outputs[f"{rows}/velocity_t"], reference[f"{rows}/velocity_t"])
    # torch's kernels are the one part that may round differently on another CPU: the windows above are
    # checked bit for bit, so a difference here can only be the model's, at float32 round-off
    if not np.array_equal(outputs[f"{rows}/velocity"], reference[f"{rows}/velocity"]):
        np.testing.assert_allclose(outputs[f"{rows}/velocity"], reference[f"{rows}/velocity"], atol=1e-5)
        pytest.skip("torch on this CPU rounds the model's velocities differently from the reference's")
    np.testing.assert_array_equal(outputs[f"{rows}/updates"], reference[f"{rows}/updates"])
    assert str(outputs[f"{rows}/track_csv"]) == str(reference[f"{rows}/track_csv"])  # %.17g: every bit


def _gapped_rows(imu: np.ndarray) -> np.ndarray:
    """The walk with holes: a 0.6 s gap (a new segment), a 0.4 s one (none), and a 0.5 s stretch between
    two gaps (shorter than a window)."""
    t = imu[:, 0]
    holes = [(60.0, 60.6), (70.0, 70.4), (74.0, 74.8), (75.3, 76.0)]
    keep = np.ones(len(t), bool)
    for lo, hi in holes:
        keep &= (t < lo) | (t >= hi)
    return imu[keep]


@pytest.mark.parametrize("rows", [1, 3, 7, 50])
def test_held_rows_give_the_windows_of_each_push_across_gaps_and_short_stretches(ipin_walk, rows):
    imu = _gapped_rows(ipin_walk.imu[list(IMU_QUAT_COLUMNS)].to_numpy(float))
    direct, held = RoninStream(), RoninStream()
    for k in range(0, len(imu), rows):
        batch = imu[k : k + rows]
        direct.push(pd.DataFrame(batch, columns=list(IMU_QUAT_COLUMNS)))
        held.push_rows(batch, IMU_QUAT_COLUMNS)
        (t_direct, w_direct), (t_held, w_held) = direct.take_windows(), held.take_windows()
        np.testing.assert_array_equal(t_held, t_direct)
        np.testing.assert_array_equal(w_held, w_direct)
        assert held.complete_until == direct.complete_until
    direct.finish()
    held.finish()
    (t_direct, w_direct), (t_held, w_held) = direct.take_windows(), held.take_windows()
    np.testing.assert_array_equal(t_held, t_direct)
    np.testing.assert_array_equal(w_held, w_direct)


def test_held_rows_go_through_the_world_frame_once_a_window_not_once_a_row(ipin_walk, monkeypatch):
    from curbside.localize.imu import WorldFrameStream

    calls = []
    push = WorldFrameStream.push
    monkeypatch.setattr(WorldFrameStream, "push", lambda self, imu: calls.append(len(imu)) or push(self, imu))
    imu = ipin_walk.imu[list(IMU_QUAT_COLUMNS)].to_numpy(float)
    stream, windows = RoninStream(), 0
    for row in imu:
        stream.push_rows(row[None, :], IMU_QUAT_COLUMNS)
        windows += len(stream.take_windows()[0])
    # one call per row until the start-up decision (2 s of rows), then one per window (every 5 rows)
    decision_rows = int(np.searchsorted(imu[:, 0], imu[0, 0] + stream.config.imu.decision_s))
    assert len(calls) <= decision_rows + windows < len(imu) / 3
    stream.finish()  # the last rows, held: they complete no window
    assert sum(calls) == len(imu)


def test_a_partial_batch_goes_through_the_model_in_a_small_shape_with_the_same_bits(ronin_model):
    from curbside.localize.ronin.infer import infer_windows
    from curbside.localize.ronin.stream import exact_partial_shapes

    queue = InferenceQueue(ronin_model)
    shapes = exact_partial_shapes(ronin_model, queue.batch_size)
    if not shapes:
        pytest.skip("no smaller batch shape gives the full shape's bits with torch on this CPU")
    seen = []
    hook = ronin_model.register_forward_pre_hook(lambda _, args: seen.append(len(args[0])))
    windows = np.random.default_rng(5).normal(0.0, 2.0, (queue.batch_size + 3, 6, 200)).astype(np.float32)
    try:
        for n in (1, 3, 17, queue.batch_size + 3):
            seen.clear()
            velocity = queue.infer([(None, np.zeros(n), windows[:n])])
            assert max(seen) < queue.batch_size or n > queue.batch_size
            assert seen[-1] == min(s for s in (*shapes, queue.batch_size) if s >= n % queue.batch_size)
            np.testing.assert_array_equal(velocity, infer_windows(ronin_model, windows[:n], queue.batch_size))
    finally:
        hook.remove()


if __name__ == "__main__" and sys.argv[1:] == ["--write"]:
    from serve_fixtures import TRIAL

    from curbside.localize.readers import read_any
    from curbside.localize.ronin.infer import load_model

    np.savez_compressed(REFERENCE, **stream_outputs(read_any(TRIAL), load_model()))
