"""Review s50: a conversion keeps localize ronin's velocity.csv while the IMU is unchanged and says so when
it removes it; a non-numeric value is named with its column and data row; a map may be named .geojson or
.json wherever one is written."""

from __future__ import annotations

import logging
import shutil
from pathlib import Path

import pandas as pd
import pytest

from curbside.cli.localize import main as localize_main
from curbside.cli.osmseg import main as osmseg_main
from curbside.errors import CurbsideInputError
from curbside.io import MARKER, note_written_by, output_folder, read_marker, writer_of
from curbside.localize.readers import read_any
from curbside.localize.readers.sensorlogger import read_sensorlogger
from curbside.localize.session import write_session
from curbside.osmseg.inputs import check_map_file

DATA = Path(__file__).parent / "data"
H5 = DATA / "sessions" / "ipin2023-cut.h5"
TRIAL = f"{H5}::TrainingTrial01_repetition01"
OTHER_TRIAL = f"{H5}::TrainingTrial23_repetition03"
OSM = DATA / "osm" / "crossroads-crossing-nodes.osm"
RONIN = "localize ronin"


@pytest.fixture(autouse=True)
def _cache_in_tmp(tmp_path, monkeypatch):
    monkeypatch.setenv("CURBSIDE_CACHE_DIR", str(tmp_path / "cache"))


def _write(folder_ctx, files: dict[str, str]) -> None:
    with folder_ctx as tmp:
        for rel, text in files.items():
            (tmp / rel).parent.mkdir(parents=True, exist_ok=True)
            (tmp / rel).write_text(text)


def _ronin_wrote(folder: Path, text: str = "t,ve,vn\n0,1,0\n") -> Path:
    """What localize ronin leaves behind: velocity.csv, noted with the imu.csv it was computed from."""
    velocity = folder / "velocity.csv"
    velocity.write_text(text)
    note_written_by(velocity, RONIN, inputs=(folder / "imu.csv",))
    return velocity


def _warnings(caplog) -> list[str]:
    return [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]


def test_velocity_stays_while_the_imu_is_byte_identical_and_goes_with_a_warning_when_it_changed(
    tmp_path, caplog, monkeypatch
):
    monkeypatch.chdir(tmp_path)
    folder = Path("t5")
    _write(output_folder(folder, "localize convert"), {"imu.csv": "i", "gnss.csv": "g"})
    velocity = _ronin_wrote(folder)
    _write(output_folder(folder, "localize convert"), {"imu.csv": "i", "gnss.csv": "g", "steps.csv": "s"})
    assert velocity.read_text() == "t,ve,vn\n0,1,0\n" and writer_of(velocity) == RONIN
    doc = read_marker(folder)
    assert "velocity.csv" in doc["files"] and doc["writers"]["velocity.csv"]["command"] == RONIN
    assert not _warnings(caplog)
    _write(output_folder(folder, "localize convert"), {"imu.csv": "another walk", "gnss.csv": "g"})
    assert not velocity.exists()
    assert _warnings(caplog) == [
        "t5/velocity.csv (written by localize ronin from the previous imu.csv) removed: imu.csv changed; run "
        "localize ronin again"
    ]
    doc = read_marker(folder)
    assert "velocity.csv" not in doc["files"] and "velocity.csv" not in doc.get("writers", {})


def test_convert_all_keeps_or_removes_a_trials_velocity_the_same_way(tmp_path, caplog):
    def convert_all(imu: str) -> None:
        with output_folder(tmp_path / "all", "localize convert --all") as tmp:
            _write(output_folder(tmp / "trial", "localize convert"), {"imu.csv": imu})

    convert_all("i")
    velocity = _ronin_wrote(tmp_path / "all" / "trial")
    convert_all("i")
    assert velocity.exists() and writer_of(velocity) == RONIN
    assert read_marker(velocity.parent)["files"] == ["imu.csv", "velocity.csv"]
    convert_all("new imu")
    assert not velocity.exists() and read_marker(velocity.parent)["files"] == ["imu.csv"]
    assert len(_warnings(caplog)) == 1 and "imu.csv changed; run localize ronin again" in _warnings(caplog)[0]


def test_a_velocity_recorded_without_its_source_goes_with_a_warning_and_a_rewrite_drops_its_record(
    tmp_path, caplog
):
    folder = tmp_path / "s"
    _write(output_folder(folder, "localize convert"), {"imu.csv": "i"})
    (folder / "velocity.csv").write_text("v")
    note_written_by(folder / "velocity.csv", RONIN)  # as curbside recorded it before "from"
    _write(output_folder(folder, "localize convert"), {"imu.csv": "i"})
    assert not (folder / "velocity.csv").exists()
    [warning] = _warnings(caplog)
    assert warning.endswith("removed: what it was computed from is not recorded; run localize ronin again")
    _ronin_wrote(folder)
    _write(output_folder(folder, "localize convert"), {"imu.csv": "i", "velocity.csv": "pdr"})  # --pdr
    assert writer_of(folder / "velocity.csv") == "localize convert"
    assert "velocity.csv" not in read_marker(folder)["writers"]


def test_convert_ronin_convert_keeps_the_users_velocity(tmp_path, capsys, caplog):
    dst = tmp_path / "t5"
    assert localize_main(["convert", TRIAL, str(dst)]) == 0
    assert localize_main(["ronin", str(dst)]) == 0
    written = (dst / "velocity.csv").read_bytes()
    assert localize_main(["convert", TRIAL, str(dst), "--steps"]) == 0
    assert (dst / "velocity.csv").read_bytes() == written and (dst / "steps.csv").exists()
    assert localize_main(["ronin", str(dst)]) == 0  # still its own: replaced without --overwrite
    assert not _warnings(caplog)
    assert localize_main(["convert", OTHER_TRIAL, str(dst)]) == 0
    assert not (dst / "velocity.csv").exists()
    assert "velocity.csv" not in read_marker(dst)["files"]
    [warning] = _warnings(caplog)
    assert warning.endswith("t5/velocity.csv (written by localize ronin from the previous imu.csv) removed: "
                            "imu.csv changed; run localize ronin again")


def _session(tmp_path: Path) -> Path:
    return write_session(read_any(TRIAL), tmp_path / "s1")


def _set(path: Path, row: int, column: str, value: str) -> None:
    table = pd.read_csv(path, dtype=str)
    table.loc[row - 1, column] = value  # data row 1 is the first after the header
    table.to_csv(path, index=False)


@pytest.mark.parametrize(("file", "column", "row"), [("gnss.csv", "lon", 2), ("imu.csv", "gz", 3)])
def test_a_non_numeric_value_is_named_like_a_nan(tmp_path, capsys, file, column, row):
    folder = _session(tmp_path)
    _set(folder / file, row, column, "abc")
    assert localize_main(["convert", str(folder), str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert err.endswith(f"s1/{file}: non-numeric value 'abc' in column '{column}' at data row {row}\n")
    _set(folder / file, row, column, "nan")
    assert localize_main(["convert", str(folder), str(tmp_path / "out")]) == 2
    assert capsys.readouterr().err.endswith(f"s1/{file}: NaN or infinite '{column}' at data row {row}\n")


def test_a_sensor_logger_non_numeric_value_names_the_file_row(tmp_path):
    folder = tmp_path / "export"
    shutil.copytree(DATA / "sessions" / "sensorlogger-android", folder)
    _set(folder / "Location.csv", 3, "horizontalAccuracy", "abc")  # row 1, at (0, 0), is dropped first
    with pytest.raises(CurbsideInputError, match=r"Location.csv: non-numeric value 'abc' in column "
                                                 r"'horizontalAccuracy' at data row 3$"):
        read_sensorlogger(folder)
    shutil.copy(DATA / "sessions" / "sensorlogger-android" / "Location.csv", folder / "Location.csv")
    _set(folder / "Gyroscope.csv", 4, "y", "x1")
    with pytest.raises(CurbsideInputError, match=r"Gyroscope.csv: non-numeric value 'x1' in column 'y' at "
                                                 r"data row 4$"):
        read_sensorlogger(folder)


def test_a_map_is_written_as_geojson_or_json_and_read_by_either_name(tmp_path, capsys):
    assert osmseg_main(["build", "--osm", str(OSM), "-o", str(tmp_path / "x.txt")]) == 2
    assert capsys.readouterr().err.endswith("x.txt: the map is GeoJSON: name it .geojson or .json\n")
    assert osmseg_main(["import-datasf", "t.topojson", "-o", str(tmp_path / "x.txt")]) == 2
    assert capsys.readouterr().err.endswith("x.txt: the map is GeoJSON: name it .geojson or .json\n")
    built = tmp_path / "x.json"
    assert osmseg_main(["build", "--osm", str(OSM), "-o", str(built)]) == 0
    check_map_file(built)
    assert osmseg_main(["compare", str(built), str(built)]) == 0
    assert not (tmp_path / MARKER).exists()
