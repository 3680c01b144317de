"""``--save-particles`` keeps the clouds on disk as the walk goes: the memory held is one chunk however long
the walk, ``particles.npz`` is the file that holding them all in memory wrote, and nothing is left behind
(no temporary file, no half-written output) on success, error or Ctrl-C."""

from __future__ import annotations

import errno
import tempfile
import tracemalloc

import numpy as np
import pytest
from test_particle_recorder import UTM10N, npz_bytes, packed_at_the_end, recorded, walk_clouds
from test_run import block_layers, run_cli, write_walk

from curbside.localize import particle_recorder, particle_spill
from curbside.localize.particle_recorder import CHUNK_BYTES, CloudRecorder
from curbside.localize.particle_spill import WRITE_BYTES, SpilledClouds
from curbside.localize.particle_store import read_particles, write_particles
from curbside.osmseg.mapio import write_map

#: The system's, before a test puts a spy in its place.
TEMPORARY_FILE = tempfile.TemporaryFile
#: Bytes a footstep takes at N = 2000: 9 a particle, and its time and estimate.
FOOTSTEP_BYTES = 9 * 2000 + 24


@pytest.fixture
def map_file(tmp_path):
    return write_map(block_layers(), tmp_path / "block.geojson")


def test_the_memory_held_stays_one_chunk_however_long_the_walk(tmp_path):
    rng = np.random.default_rng(0)
    n_steps = 1500  # 27 MB packed: a quarter of an hour of walk at N = 2000
    tracemalloc.start()
    try:
        recorder = CloudRecorder(UTM10N, spill_dir=tmp_path)
        for k in range(n_steps):
            x = 552_000.0 + k + rng.normal(0.0, 3.0, 2000)
            y = 4_182_000.0 + rng.normal(0.0, 3.0, 2000)
            recorder.add(0.5 * k, 552_000.0 + k, 4_182_000.0, x, y, rng.uniform(-1, 1, 2000),
                         rng.uniform(0.8, 1.2, 2000), rng.dirichlet(np.ones(2000)))
            assert recorder.buffer_bytes <= CHUNK_BYTES
        packed = recorder.packed()
        del recorder  # as a run's engine goes once the walk is over
        written = write_particles(packed, tmp_path / "particles.npz")
        _, peak_b = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert n_steps * FOOTSTEP_BYTES > 6 * CHUNK_BYTES
    assert peak_b < CHUNK_BYTES + 4 * WRITE_BYTES  # a chunk held while walking, a block while writing
    clouds = read_particles(written)
    assert clouds.x.shape == (n_steps, 2000) and clouds.weight is not None


def test_a_file_streamed_in_many_blocks_is_the_file_written_from_memory(tmp_path, monkeypatch):
    monkeypatch.setattr(particle_spill, "WRITE_BYTES", 1000)  # blocks of 2 footsteps at N = 200
    t, ref_x, ref_y, clouds = walk_clouds(41, 200, uniform=False)
    spilled = recorded(t, ref_x, ref_y, clouds, chunk_bytes=5000, spill_dir=tmp_path).packed()
    before = packed_at_the_end(clouds, t, ref_x, ref_y, UTM10N)
    assert isinstance(spilled, SpilledClouds) and list(spilled) == list(before)
    assert npz_bytes(spilled, tmp_path / "now.npz") == npz_bytes(before, tmp_path / "before.npz")
    with np.load(tmp_path / "now.npz") as npz:
        for name in before:
            np.testing.assert_array_equal(npz[name], before[name], err_msg=name)


def test_the_clouds_on_disk_have_no_name_there(tmp_path):
    t, ref_x, ref_y, clouds = walk_clouds(30, 100, uniform=True)
    recorder = recorded(t, ref_x, ref_y, clouds, chunk_bytes=1, spill_dir=tmp_path)
    packed = recorder.packed()
    assert len(packed["t"]) == 30 and list(tmp_path.iterdir()) == []
    del recorder, packed
    assert list(tmp_path.iterdir()) == []


class SpillSpy:
    """``tempfile.TemporaryFile`` that notes the folder of each file, and fails on write from ``fail_on``."""

    def __init__(self, fail_on: int | None = None) -> None:
        self.folders: list[str] = []
        self.fail_on = fail_on
        self.writes = 0

    def __call__(self, *args, dir=None, **kwargs):  # noqa: A002 (tempfile's name)
        self.folders.append(str(dir))
        file, spy = TEMPORARY_FILE(*args, dir=dir, **kwargs), self  # noqa: SIM115

        class Full:
            def __getattr__(self, name):
                return getattr(file, name)

            def write(self, data):
                spy.writes += 1
                if spy.fail_on is not None and spy.writes >= spy.fail_on:
                    raise OSError(errno.ENOSPC, "No space left on device")
                return file.write(data)

        return Full()


def test_a_run_spills_beside_its_output_and_writes_the_old_file(tmp_path, map_file, monkeypatch):
    session = write_walk(tmp_path / "walk", duration_s=60.0)
    assert run_cli(session, "--map", map_file, "--particles", 200, "--seed", 4, "--save-particles",
                   "-o", tmp_path / "held") == 0
    spy = SpillSpy()
    monkeypatch.setattr(particle_recorder, "CHUNK_BYTES", 5 * (9 * 200 + 24))  # 5 footsteps
    monkeypatch.setattr(particle_spill.tempfile, "TemporaryFile", spy)
    out = tmp_path / "runs" / "spilled"
    assert run_cli(session, "--map", map_file, "--particles", 200, "--seed", 4, "--save-particles",
                   "-o", out) == 0
    assert spy.folders and set(spy.folders) == {str(tmp_path)}  # the nearest folder of the output
    assert spy.writes > 8 * 10  # the 8 members, chunk after chunk
    assert sorted(p.name for p in tmp_path.iterdir()) == ["block.geojson", "held", "runs", "walk"]
    with np.load(tmp_path / "held" / "particles.npz") as held, np.load(out / "particles.npz") as spilled:
        assert held.files == spilled.files
        for name in held.files:
            np.testing.assert_array_equal(held[name], spilled[name], err_msg=name)


@pytest.mark.parametrize("when", ["walking", "writing"])
def test_ctrl_c_leaves_no_output_and_no_temporary_file(tmp_path, map_file, monkeypatch, when):
    session = write_walk(tmp_path / "walk", duration_s=40.0)
    calls = []

    def interrupted(*args, **kwargs):
        calls.append(1)
        raise KeyboardInterrupt

    if when == "walking":
        original = CloudRecorder.add

        def add(self, *args):
            if len(self) == 30:
                interrupted()
            original(self, *args)

        monkeypatch.setattr(CloudRecorder, "add", add)
    else:
        monkeypatch.setattr(SpilledClouds, "write_npz", interrupted)
    out = tmp_path / "out"
    assert run_cli(session, "--map", map_file, "--particles", 100, "--save-particles", "-o", out) == 130
    assert calls and not out.exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["block.geojson", "walk"]


def test_a_full_disk_while_walking_is_named_in_one_line(tmp_path, map_file, monkeypatch, capsys):
    session = write_walk(tmp_path / "walk", duration_s=40.0)
    monkeypatch.setattr(particle_recorder, "CHUNK_BYTES", 10 * (9 * 100 + 24))
    monkeypatch.setattr(particle_spill.tempfile, "TemporaryFile", SpillSpy(fail_on=12))  # the 2nd chunk
    out = tmp_path / "out"
    assert run_cli(session, "--map", map_file, "--particles", 100, "--save-particles", "-o", out) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err
    assert str(tmp_path) in err and "No space left on device" in err and "particle clouds" in err
    assert not out.exists() and sorted(p.name for p in tmp_path.iterdir()) == ["block.geojson", "walk"]
