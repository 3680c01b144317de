"""``localize convert``: every source format to a SPEC folder, --all, --list, and bad input."""

from __future__ import annotations

import shutil
from pathlib import Path

import pandas as pd
import pytest

from curbside.cli.localize import main
from curbside.io import read_marker
from curbside.localize.session import read_session

SESSIONS = Path(__file__).parent / "data" / "sessions"
H5 = SESSIONS / "ipin2023-cut.h5"


def test_convert_ipin_trial_with_steps_and_pdr(tmp_path, capsys):
    dst = tmp_path / "trial"
    assert main(["convert", f"{H5}::TrainingTrial01_repetition01", str(dst), "--steps", "--pdr"]) == 0
    session = read_session(dst)
    assert {"imu", "gnss", "waypoints", "steps", "velocity"} == set(session.tables())
    assert session.meta["start"]["t"] == session.waypoints["t"].iat[0]
    assert len(session.velocity) == len(session.steps)
    out = capsys.readouterr().out
    rows = {line.split()[0]: int(line.split()[1]) for line in out.splitlines() if ".csv" in line}
    assert rows == {f"{kind}.csv": len(table) for kind, table in session.tables().items()}


def test_convert_all_trials_and_list(tmp_path, capsys):
    assert main(["convert", str(H5), "--list"]) == 0
    names = capsys.readouterr().out.split()
    assert names == ["IPIN2023_T3_TrainingTrial01_repetition01", "IPIN2023_T3_TrainingTrial23_repetition03"]
    dst = tmp_path / "all"
    assert main(["convert", str(H5), str(dst), "--all"]) == 0
    expected = ["TrainingTrial01_repetition01", "TrainingTrial23_repetition03"]
    assert sorted(p.name for p in dst.iterdir() if p.name != ".curbside-output") == expected
    assert read_session(dst / "TrainingTrial23_repetition03").imu is not None


@pytest.mark.parametrize(
    "src",
    ["sensorlogger-ios.zip", "sensorlogger-android", "sensorlogger-android-v2.zip",
     "sensorlogger-android-1.12.zip", "sensorlogger-ios-standardised.zip", "walk.gpx"],
)
def test_convert_foreign_formats(tmp_path, src):
    dst = tmp_path / "out"
    assert main(["convert", str(SESSIONS / src), str(dst)]) == 0
    session = read_session(dst)
    raw_gnss = pd.read_csv(dst / "gnss.csv")
    assert len(raw_gnss) == len(session.gnss) > 3
    assert session.meta["source"]["file"] == src
    assert read_marker(dst)["command"] == "localize convert"


def test_convert_picks_one_recording_of_several(tmp_path, capsys):
    tree = tmp_path / "walks"
    shutil.copytree(SESSIONS / "sensorlogger-android", tree / "monday")
    shutil.copytree(SESSIONS / "sensorlogger-android", tree / "tuesday")
    assert main(["convert", str(tree), str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert "holds 2 recordings (monday, tuesday); pick one as" in err and len(err.splitlines()) == 1
    assert main(["convert", str(tree), "--list"]) == 0
    assert capsys.readouterr().out.split() == ["monday", "tuesday"]
    assert main(["convert", f"{tree}::tuesday", str(tmp_path / "out")]) == 0
    assert read_session(tmp_path / "out").meta["source"]["recording"] == "tuesday"


# --- the destination folder ---------------------------------------------------------------------------


def _files(folder: Path) -> set[str]:
    return {p.relative_to(folder).as_posix() for p in folder.rglob("*") if p.is_file()}


def test_convert_refuses_a_users_folder_and_overwrite_keeps_its_files(tmp_path, capsys):
    dst = tmp_path / "mine"
    dst.mkdir()
    (dst / "map.geojson").write_text("my map")
    argv = ["convert", str(SESSIONS / "sensorlogger-android"), str(dst)]
    assert main(argv) == 2
    assert "pass --overwrite" in capsys.readouterr().err
    assert _files(dst) == {"map.geojson"}
    assert main([*argv, "--overwrite"]) == 0
    assert _files(dst) == {"map.geojson", ".curbside-output", "imu.csv", "gnss.csv", "waypoints.csv",
                           "meta.json"}
    assert (dst / "map.geojson").read_text() == "my map"


def test_convert_again_into_its_own_output_replaces_stale_files(tmp_path):
    dst = tmp_path / "trial"
    src = f"{H5}::TrainingTrial01_repetition01"
    assert main(["convert", src, str(dst), "--steps"]) == 0
    (dst / "notes.md").write_text("mine")
    assert main(["convert", src, str(dst)]) == 0  # no --overwrite needed, no --steps this time
    assert "steps.csv" not in _files(dst) and "notes.md" in _files(dst)


def test_convert_into_dot(tmp_path, monkeypatch):
    here = tmp_path / "here"
    here.mkdir()
    monkeypatch.chdir(here)
    assert main(["convert", str(SESSIONS / "walk.gpx"), "."]) == 0
    assert read_session(here).gnss is not None
    assert main(["convert", str(SESSIONS / "walk.gpx"), "."]) == 0


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["{data}/walk.gpx", "{dst}", "--steps"], "need IMU data"),
        (["{data}/nothing.zip", "{dst}"], "no such file"),
        (["{data}/ipin2023-cut.h5", "{dst}"], "holds 2 trials"),
        (["{data}/ipin2023-cut.h5::Nope", "{dst}"], "no such trial"),
        (["{data}/ipin2023-cut.h5::TrainingTrial01_repetition01", "{dst}", "--all"], "drop the ::TRIAL"),
        (["{data}/make_fixtures.py", "{dst}"], "unknown format"),
        (["{data}/sensorlogger-android::monday", "{dst}"], "no such recording"),
        (["{data}/sensorlogger-android", "{dst}", "--route", "{data}/nope.csv"], "unreadable route CSV"),
        (["{data}/sensorlogger-android", "{dst}", "--route", "{data}/sensorlogger-android/Metadata.csv"],
         "route needs columns lat,lon"),
        (["{data}/sensorlogger-android", "/proc/curbside-test/out"], "cannot write here"),
        (["{data}/sensorlogger-android", "{data}/walk.gpx"], "exists and is not a folder"),
        (["{data}/walk.gpx", "--list"], "--list needs an IPIN .h5 file or Sensor Logger exports"),
        (["{data}/walk.gpx", "{dst}", "--all"], "--all converts every trial of an IPIN .h5 file"),
    ],
)
def test_bad_input_exits_2_and_writes_nothing(tmp_path, capsys, args, message):
    dst = tmp_path / "out"
    argv = ["convert", *(a.format(data=SESSIONS, dst=dst) for a in args)]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert message in err and len(err.splitlines()) == 1 and "Traceback" not in err
    assert not dst.exists()
    assert list(tmp_path.iterdir()) == []
