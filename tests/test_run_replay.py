"""``localize run --config run.json``: a replay notices changed inputs, keeps the velocity source the run
resolved and its ``--save-particles``, refuses another mode, and names a moved session."""

from __future__ import annotations

import json
import logging
import shutil
from pathlib import Path

import pandas as pd
import pytest
from test_run import block_layers, write_walk

from curbside import settings
from curbside.cli.localize import main
from curbside.osmseg.mapio import write_map


@pytest.fixture
def recorded(tmp_path, monkeypatch):
    """A walk on the block map and its fused run, with particles saved."""
    monkeypatch.setattr(settings, "cache_dir", tmp_path / "cache")
    walk = write_walk(tmp_path / "walk", duration_s=40.0)
    map_path = write_map(block_layers(), tmp_path / "block.geojson")
    argv = ["run", str(walk), "--map", str(map_path), "--particles", "200", "--save-particles"]
    assert main([*argv, "-o", str(tmp_path / "run")]) == 0
    return tmp_path, walk, map_path, tmp_path / "run" / "run.json"


def _changed_warnings(caplog) -> list[str]:
    return [r.getMessage() for r in caplog.records if "changed since the run" in r.getMessage()]


def test_run_json_records_its_inputs_and_a_replay_on_them_is_silent_and_identical(recorded, caplog):
    tmp, _, _, run_json = recorded
    info = json.loads(run_json.read_text())
    assert set(info["inputs"]["session_sha256"]) == {"steps.csv", "velocity.csv", "gnss.csv", "meta.json"}
    assert len(info["inputs"]["map_sha256"]) == 64 and info["save_particles"] is True
    with caplog.at_level(logging.WARNING):
        assert main(["run", "--config", str(run_json), "-o", str(tmp / "again")]) == 0
    assert not _changed_warnings(caplog)
    assert (tmp / "again" / "track.csv").read_bytes() == (tmp / "run" / "track.csv").read_bytes()
    assert (tmp / "again" / "particles.npz").is_file()  # --save-particles is part of the run


def test_a_replay_on_changed_fixes_or_map_says_which(recorded, caplog):
    tmp, walk, map_path, run_json = recorded
    fixes = pd.read_csv(walk / "gnss.csv")
    fixes.loc[5, "lat"] += 1e-5
    fixes.to_csv(walk / "gnss.csv", index=False)
    doc = json.loads(map_path.read_text())
    doc["features"] = doc["features"][:-1]
    map_path.write_text(json.dumps(doc))
    with caplog.at_level(logging.WARNING):
        assert main(["run", "--config", str(run_json), "-o", str(tmp / "changed")]) == 0
    [line] = _changed_warnings(caplog)
    assert "gnss.csv" in line and str(map_path) in line and "velocity.csv" not in line


def test_a_replay_keeps_the_velocity_source_the_run_resolved(recorded, capsys):
    tmp, walk, _, run_json = recorded
    assert json.loads(run_json.read_text())["velocity_source"] == "file"
    (walk / "velocity.csv").unlink()  # under auto, a replay would quietly fall back to RoNIN or PDR
    capsys.readouterr()
    assert main(["run", "--config", str(run_json), "-o", str(tmp / "nov")]) == 2
    assert "velocity.csv: no velocity.csv in the session" in capsys.readouterr().err


def test_another_mode_with_a_config_is_refused(recorded, capsys):
    tmp, _, _, run_json = recorded
    assert main(["run", "--config", str(run_json), "--mode", "paper", "-o", str(tmp / "paper")]) == 2
    err = capsys.readouterr().err
    assert "holds a fused run's parameters" in err and not (tmp / "paper").exists()


def test_a_moved_session_is_named_with_the_way_out(recorded, capsys):
    tmp, walk, _, run_json = recorded
    shutil.move(walk, tmp / "moved")
    assert main(["run", "--config", str(run_json), "-o", str(tmp / "lost")]) == 2
    err = capsys.readouterr().err
    assert "no such file or folder (the session" in err and "give where it is now: SESSION" in err
    assert main(["run", str(tmp / "moved"), "--config", str(run_json), "-o", str(tmp / "found")]) == 0
    assert (tmp / "found" / "track.csv").read_bytes() == (tmp / "run" / "track.csv").read_bytes()


def test_a_sensor_logger_folder_is_fingerprinted_by_its_own_files(tmp_path):
    from curbside.cli.run_replay import changed_inputs, input_record

    export = tmp_path / "export"
    shutil.copytree(Path(__file__).parent / "data" / "sessions" / "sensorlogger-android", export)
    before = input_record(str(export), None)
    assert {"TotalAcceleration.csv", "Gyroscope.csv", "Location.csv"} <= set(before["session_sha256"])
    (export / "Location.csv").write_text((export / "Location.csv").read_text().replace(",7.0,", ",8.0,", 1))
    assert changed_inputs(before, input_record(str(export), None), None) == ["Location.csv"]
