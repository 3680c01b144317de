"""``--save-particles`` packs each footstep's cloud as it is taken: compact while the walk runs (and on disk
a chunk at a time: ``test_particle_spill.py``), and the same ``particles.npz``, byte for byte, as packing
the float32 snapshots of the whole walk at its end."""

from __future__ import annotations

import numpy as np
import pytest
from test_run import KeepsTheFloats, block_layers, write_walk
from viewer_fixtures import CROSSROADS, write_session

from curbside.localize.engine import SessionEngine
from curbside.localize.particle_recorder import CHUNK_BYTES, CloudRecorder
from curbside.localize.particle_store import (
    pack_particles,
    pack_snapshots,
    read_particles,
    select_footsteps,
    unpack_particles,
    write_particles,
)
from curbside.localize.pipeline import _frame_for, _start_of
from curbside.localize.raster import rasterize_map
from curbside.localize.runconfig import RunConfig
from curbside.localize.session import read_session

UTM10N = "EPSG:32610"
#: Bytes a recorder may hold per particle and footstep: int16 x, y, heading, uint16 scale, uint8 weight.
PACKED_BYTES = 9


def packed_at_the_end(clouds: list[np.ndarray], t, ref_x_m, ref_y_m, crs: str) -> dict[str, np.ndarray]:
    """How a run packed its clouds before: float32 snapshots relative to the first estimate, all packed
    once the walk was over. ``clouds``: one ``(5, N)`` array (x, y, theta, scale, weight) per footstep."""
    snapshots = float32_snapshots(clouds, t, ref_x_m, ref_y_m, crs)
    return pack_snapshots(snapshots, np.asarray(ref_x_m, np.float64), np.asarray(ref_y_m, np.float64))


def float32_snapshots(clouds: list[np.ndarray], t, ref_x_m, ref_y_m, crs: str) -> dict[str, np.ndarray]:
    """The float32 snapshots that runs held, and wrote as ``particles.npz``, before :data:`FORMAT`."""
    stack = np.stack(clouds)
    origin = np.array([ref_x_m[0], ref_y_m[0]])
    snapshots = {
        "t": np.asarray(t, np.float64),
        "x": (stack[:, 0] - origin[0]).astype(np.float32),
        "y": (stack[:, 1] - origin[1]).astype(np.float32),
        "theta": stack[:, 2].astype(np.float32),
        "scale": stack[:, 3].astype(np.float32),
        "origin": origin,
        "crs": np.array(crs),
    }
    weight = stack[:, 4]
    if not np.allclose(weight, weight[:, :1], rtol=0, atol=1e-12):
        snapshots["weight"] = weight
    return snapshots


def walk_clouds(n_steps: int, n: int, uniform: bool, seed: int = 0):
    """A 3 km walk's clouds, some offsets on the half-decimetre ties that float32 rounding decides."""
    rng = np.random.default_rng(seed)
    t = 0.5 * np.arange(n_steps)
    ref_x = 552_000.0 + np.linspace(0.0, 3000.0, n_steps)
    ref_y = 4_182_000.0 + 40.0 * np.sin(np.arange(n_steps) / 7.0)
    clouds = []
    for k in range(n_steps):
        dx = rng.normal(0.0, 3.0, n)
        dx[: n // 4] = (rng.integers(-30, 30, n // 4) + 0.5) * 0.1  # ties
        theta = rng.uniform(-4.0, 4.0, n)  # wraps
        scale = rng.uniform(0.7, 1.3, n)
        weight = np.full(n, 1.0 / n) if uniform else rng.dirichlet(np.ones(n)) * (rng.random(n) > 0.2)
        clouds.append(np.vstack([ref_x[k] + dx, ref_y[k] + rng.normal(0.0, 2.0, n), theta, scale, weight]))
    return t, ref_x, ref_y, clouds


def recorded(t, ref_x, ref_y, clouds, **kwargs) -> CloudRecorder:
    recorder = CloudRecorder(UTM10N, **kwargs)
    for k, cloud in enumerate(clouds):
        recorder.add(t[k], ref_x[k], ref_y[k], *cloud)
    return recorder


def npz_bytes(packed: dict[str, np.ndarray], path) -> bytes:
    return write_particles(packed, path).read_bytes()


@pytest.mark.parametrize("chunk_bytes", [1, 7 * PACKED_BYTES * 200, CHUNK_BYTES])  # 1, 6 footsteps; all
@pytest.mark.parametrize("uniform", [True, False])
def test_packing_each_footstep_writes_the_file_that_packing_at_the_end_wrote(tmp_path, uniform, chunk_bytes):
    t, ref_x, ref_y, clouds = walk_clouds(40, 200, uniform)
    before = packed_at_the_end(clouds, t, ref_x, ref_y, UTM10N)
    now = recorded(t, ref_x, ref_y, clouds, chunk_bytes=chunk_bytes, spill_dir=tmp_path).packed()
    assert list(now) == list(before) and ("weight_u8" in now) is not uniform
    for name in before:
        assert now[name].dtype == before[name].dtype and now[name].shape == before[name].shape, name
        np.testing.assert_array_equal(now[name], before[name], err_msg=name)
    assert npz_bytes(now, tmp_path / "now.npz") == npz_bytes(before, tmp_path / "before.npz")
    # The ties make the float32 detour matter: packing the float64 positions directly differs.
    stack = np.stack(clouds)
    direct = pack_particles(t, stack[:, 0], stack[:, 1], ref_x, ref_y, UTM10N)
    assert not np.array_equal(direct["dx_dm"], before["dx_dm"])


def test_the_recorder_holds_integers_only_and_nothing_of_the_floats_it_was_given():
    t, ref_x, ref_y, clouds = walk_clouds(300, 500, uniform=False)
    chunk_bytes = 64 * (PACKED_BYTES * 500 + 24)  # 64 footsteps: 4 chunks on disk, 44 footsteps held
    recorder = recorded(t, ref_x, ref_y, clouds, chunk_bytes=chunk_bytes)
    expected = packed_at_the_end(clouds, t, ref_x, ref_y, UTM10N)
    for cloud in clouds:
        cloud[:] = np.nan  # the caller's particles move on
    per_particle = [values for name, values in recorder._buffer.items() if values.ndim == 2]
    assert len(per_particle) == 5 and all(values.dtype.kind in "iu" for values in per_particle)
    assert len(recorder) == 300 and sum(values[0].nbytes for values in per_particle) == PACKED_BYTES * 500
    assert recorder.buffer_bytes == chunk_bytes
    packed = recorder.packed()
    for name in expected:
        np.testing.assert_array_equal(packed[name], expected[name], err_msg=name)


def test_packing_twice_or_adding_after_packing_still_gives_the_whole_walk():
    t, ref_x, ref_y, clouds = walk_clouds(300, 50, uniform=False)
    expected = packed_at_the_end(clouds, t, ref_x, ref_y, UTM10N)
    recorder = recorded(t[:250], ref_x[:250], ref_y[:250], clouds[:250], chunk_bytes=40 * PACKED_BYTES * 50)
    first = recorder.packed()
    for k in range(250, 300):
        recorder.add(t[k], ref_x[k], ref_y[k], *clouds[k])
    for packed in (recorder.packed(), recorder.packed()):
        for name in expected:
            np.testing.assert_array_equal(packed[name], expected[name], err_msg=name)
    for name in first:  # the first views are left as they were
        want = expected[name][:250] if expected[name].ndim else expected[name]
        np.testing.assert_array_equal(first[name], want, err_msg=name)


def test_an_offset_out_of_range_warns_once_with_the_count(caplog):
    t, ref_x, ref_y, clouds = walk_clouds(5, 50, uniform=True)
    clouds[2][0, :3] = ref_x[2] + 4000.0
    clouds[4][0, :2] = ref_x[4] - 4000.0
    packed = recorded(t, ref_x, ref_y, clouds).packed()
    warnings = [r.getMessage() for r in caplog.records if "clipped" in r.getMessage()]
    assert warnings == ["5 particle x offset value(s) out of the stored range were clipped"]
    assert packed["dx_dm"][2, :3].tolist() == [32767] * 3


def test_a_recorder_without_footsteps_says_so():
    with pytest.raises(ValueError, match="no particle cloud"):
        CloudRecorder(UTM10N).packed()


@pytest.mark.parametrize("mode", ["fused", "paper"])
def test_a_run_packs_its_clouds_as_it_walks_into_the_old_bytes(tmp_path, mode):
    session = read_session(write_walk(tmp_path / "walk", duration_s=20.0))
    start, t_begin = _start_of(session)
    frame = _frame_for(session, block_layers())
    config = RunConfig.for_mode(mode, seed=2).with_overrides({"filter.n_particles": 300})
    engine = SessionEngine(config, frame, rasterize_map(block_layers(), 0.5), start=start, t_begin=t_begin,
                           save_particles=True, spill_dir=tmp_path / "spill")
    assert isinstance(engine.snapshots, CloudRecorder) and engine.snapshots.spill_dir == tmp_path / "spill"
    spy = engine.snapshots = KeepsTheFloats(engine.snapshots.crs, chunk_bytes=10 * PACKED_BYTES * 300)
    engine.push_velocity(session.velocity["t"].to_numpy(), session.velocity[["ve", "vn"]].to_numpy())
    engine.push_steps(session.steps["t"].to_numpy(), float(session.steps["t"].iat[-1]))
    engine.push_gnss(session.gnss)
    engine.finish()
    k = len(engine.rows)
    assert len(spy) == k > 20 and spy.buffer_bytes <= 10 * PACKED_BYTES * 300  # a chunk is held, not k
    t = np.array([r.t for r in engine.rows])
    ref_x, ref_y = np.array([r.x for r in engine.rows]), np.array([r.y for r in engine.rows])
    before = packed_at_the_end(spy.floats, t, ref_x, ref_y, frame.crs.to_wkt())
    now = spy.packed()
    assert npz_bytes(now, tmp_path / "now.npz") == npz_bytes(before, tmp_path / "before.npz")
    clouds = read_particles(tmp_path / "now.npz")
    assert clouds.x.shape == (k, 300)
    x, y, theta_rad, scale, _ = spy.floats[-1]
    assert np.abs(clouds.x[-1] - x).max() <= 0.05 + 1e-6 and np.abs(clouds.y[-1] - y).max() <= 0.05 + 1e-6
    assert clouds.scale is not None and np.abs(clouds.scale[-1] - scale).max() <= 5e-5 + 1e-9
    turn_deg = (clouds.theta_deg[-1] - np.degrees(theta_rad) + 180.0) % 360.0 - 180.0
    assert np.abs(turn_deg).max() <= 0.05 + 1e-6


@pytest.mark.parametrize("form", ["uniform", "weighted", "float32 snapshots"])
def test_the_footsteps_selected_unpack_as_those_of_the_whole_walk(form):
    t, ref_x, ref_y, clouds = walk_clouds(30, 100, uniform=form == "uniform")
    if form == "float32 snapshots":
        packed = float32_snapshots(clouds, t, ref_x, ref_y, UTM10N)
    else:
        packed = recorded(t, ref_x, ref_y, clouds).packed()
    rows = [29, 3, 3, 0]
    every, selected = unpack_particles(packed), unpack_particles(select_footsteps(packed, rows))
    assert selected.crs == every.crs and (selected.weight is None) is (form == "uniform")
    for name in ("t", "x", "y", "theta_deg", "scale", "weight"):
        if getattr(every, name) is not None:
            np.testing.assert_array_equal(getattr(selected, name), getattr(every, name)[rows], err_msg=name)
    with pytest.raises(IndexError):
        select_footsteps(packed, [30])


def test_the_evaluation_keeps_the_clouds_nearest_the_asked_times(tmp_path, monkeypatch):
    from curbside.evaluate import runner
    from curbside.evaluate.runner import RunSpec, run_one

    unpacked_footsteps = []

    def unpack_spy(packed, *args):
        unpacked_footsteps.append(len(packed["t"]))
        return unpack_particles(packed, *args)

    monkeypatch.setattr(runner, "unpack_particles", unpack_spy)
    session = write_session(tmp_path / "walk")
    spec = RunSpec(str(session), "fused", str(CROSSROADS), "osm", str(CROSSROADS), particles=100,
                   snapshot_times=(10.0, 40.2))
    result = run_one(spec)
    assert unpacked_footsteps == [2]  # those two, not the walk's 147: a long walk's take seconds and GBs
    track = result["track"].set_index("t")
    assert [c["t"] for c in result["snapshots"]] == pytest.approx([9.9, 40.15])  # footsteps every 0.55 s
    for cloud in result["snapshots"]:
        assert cloud["x"].dtype == np.float32 and cloud["x"].shape == cloud["y"].shape == (100,)
        # the metrics frame is the map's: the cloud lies around the scored estimate
        est = track.loc[cloud["t"]]
        assert abs(np.median(cloud["x"]) - est["x_m"]) < 3.0 and abs(np.median(cloud["y"]) - est["y_m"]) < 3.0
