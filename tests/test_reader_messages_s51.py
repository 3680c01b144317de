"""Reader errors speak of the user's file: its name, its own column header, its data row, the cell.

Each case copies a fixture export (Android 1.28 folder, iOS 1.11 zip, format-2 zip, standardised iOS,
Android 1.12, the real 1.12 export, the GPX walk, the IPIN cut), corrupts one thing as a user or a
spreadsheet would, and runs ``localize convert`` on it. Before, a cell was named by the column of
curbside's own ``imu.csv`` (``gy`` for ``Gyroscope.csv``'s ``y``), and text in a Sensor Logger time or
position column (``N/A``, ``abc``) was read as a blank and the row dropped without a word.
"""

from __future__ import annotations

import shutil
import zipfile
from pathlib import Path

import h5py
import numpy as np
import pytest

from curbside.cli.localize import main

SESSIONS = Path(__file__).parent / "data" / "sessions"
REAL = "real/sensorlogger-android-1.12.0-ethz"


def _export(tmp_path: Path, fixture: str) -> Path:
    """A copy of a fixture export as a folder of CSVs (a zip's recording folder: where its CSVs are)."""
    src = SESSIONS / fixture
    folder = tmp_path / "unpacked"
    if src.is_dir():
        shutil.copytree(src, folder)
        return folder
    with zipfile.ZipFile(src) as zf:
        zf.extractall(folder)
    return next(p.parent for p in folder.rglob("*.csv") if "__MACOSX" not in p.parts)


def _rezip(folder: Path, tmp_path: Path) -> Path:
    """The unpacked export zipped again, as the app hands it over."""
    root = tmp_path / "unpacked"
    path = tmp_path / "export.zip"
    with zipfile.ZipFile(path, "w") as zf:
        for p in sorted(root.rglob("*")):
            if p.is_file():
                zf.write(p, p.relative_to(root).as_posix())
    return path


def _set(path: Path, column: str, row: int, value: str) -> None:
    """Write ``value`` into ``column`` of data row ``row`` (1 = the first row after the header), as text."""
    lines = path.read_text().splitlines()
    header = lines[0].split(",")
    cells = lines[row].split(",")
    cells[header.index(column)] = value
    lines[row] = ",".join(cells)
    path.write_text("\n".join(lines) + "\n")


def _source(tmp_path: Path, fixture: str, file: str, edit) -> tuple[Path, str]:
    """The corrupted export (zipped again when the fixture is a zip) and how messages name ``file``."""
    folder = _export(tmp_path, fixture)
    edit(folder / file)
    if fixture.endswith(".zip"):
        src = _rezip(folder, tmp_path)
        return src, f"{src}/{(folder / file).relative_to(tmp_path / 'unpacked').as_posix()}"
    return folder, str(folder / file)


def _refused(capsys, tmp_path: Path, src: Path) -> str:
    """``localize convert``'s refusal: exit 2, one error line and no traceback, nothing written."""
    out = tmp_path / "out"
    assert main(["convert", str(src), str(out)]) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err
    last = err.strip().splitlines()[-1]
    assert last.startswith("localize: error: ")
    assert not out.exists()
    return last.removeprefix("localize: error: ")


# -- a cell that is not a number: the file's own column ---------------------------------------------------

@pytest.mark.parametrize(
    ("fixture", "file", "column", "row", "value"),
    [
        ("sensorlogger-android", "Gyroscope.csv", "y", 3, "abc"),
        ("sensorlogger-ios.zip", "Accelerometer.csv", "x", 5, "abc"),
        ("sensorlogger-android-v2.zip", "Gravity.csv", "z", 4, "#REF!"),
        ("sensorlogger-ios-standardised.zip", "Magnetometer.csv", "y", 2, "n/a"),
        ("sensorlogger-android-1.12.zip", "TotalAcceleration.csv", "x", 7, "1.2.3"),
        (REAL, "Location.csv", "horizontalAccuracy", 1, "unknown"),
        ("sensorlogger-android", "Orientation.csv", "qw", 2, "abc"),
    ],
    ids=["android-gyro", "ios-zip-acc", "v2-gravity", "std-ios-magnetometer", "1.12-total", "real-accuracy",
         "quaternion"],
)
def test_a_cell_that_is_not_a_number_is_named_by_the_files_own_column(tmp_path, capsys, fixture, file,
                                                                      column, row, value):
    src, name = _source(tmp_path, fixture, file, lambda p: _set(p, column, row, value))
    message = _refused(capsys, tmp_path, src)
    assert message == f"{name}: non-numeric value {value!r} in column {column!r} at data row {row}"


# -- text in a time or position column: refused, not dropped as a blank -----------------------------------

@pytest.mark.parametrize(
    ("fixture", "file", "column", "row", "value"),
    [
        ("sensorlogger-android", "Location.csv", "latitude", 3, "N/A"),
        ("sensorlogger-ios.zip", "Location.csv", "longitude", 3, "abc"),
        ("sensorlogger-ios.zip", "Location.csv", "time", 3, "abc"),
        ("sensorlogger-android", "Location.csv", "seconds_elapsed", 4, "later"),
        ("sensorlogger-android-v2.zip", "Location.csv", "time", 2, "abc"),
        ("sensorlogger-android-v2.zip", "Gyroscope.csv", "time", 7, "x"),
        ("sensorlogger-android", "Gyroscope.csv", "seconds_elapsed", 7, "x"),
        ("sensorlogger-ios-standardised.zip", "Orientation.csv", "time", 9, "NA"),
        (REAL, "Location.csv", "latitude", 2, "null"),
        ("sensorlogger-android", "Annotation.csv", "seconds_elapsed", 1, "abc"),
    ],
    ids=["latitude-N/A", "ios-longitude", "ios-location-time", "location-elapsed", "v2-location-time",
         "v2-gyro-time", "gyro-elapsed", "std-ios-orientation-time", "real-latitude-null", "tap-time"],
)
def test_text_in_a_time_or_position_column_is_refused(tmp_path, capsys, fixture, file, column, row, value):
    src, name = _source(tmp_path, fixture, file, lambda p: _set(p, column, row, value))
    message = _refused(capsys, tmp_path, src)
    assert message == f"{name}: non-numeric value {value!r} in column {column!r} at data row {row}"


@pytest.mark.parametrize("blank", ["", "NaN"])
def test_a_blank_position_is_still_skipped(tmp_path, blank):
    src, _ = _source(tmp_path, "sensorlogger-android", "Location.csv",
                     lambda p: _set(p, "latitude", 3, blank))
    assert main(["convert", str(src), str(tmp_path / "out")]) == 0
    assert main(["convert", str(SESSIONS / "sensorlogger-android"), str(tmp_path / "whole")]) == 0
    rows = [len((tmp_path / d / "gnss.csv").read_text().splitlines()) for d in ("out", "whole")]
    assert rows[0] == rows[1] - 1


def test_a_route_point_that_is_text_is_refused(tmp_path, capsys):
    route = tmp_path / "route.csv"
    route.write_text("lat,lon\n49.4612756,11.11098835\nN/A,11.1111\n")
    argv = ["convert", str(SESSIONS / "sensorlogger-android"), str(tmp_path / "out"), "--route", str(route)]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert err.endswith(f"{route}: non-numeric value 'N/A' in column 'lat' at data row 2")


def test_a_decimal_comma_file_names_its_text_cell_not_its_first_number(tmp_path, capsys):
    def spreadsheet(path: Path) -> None:
        lines = path.read_text().splitlines()
        lines = [lines[0].replace(",", ";")] + [row.replace(",", ";").replace(".", ",") for row in lines[1:]]
        cells = lines[5].split(";")
        cells[3] = "abc"  # y
        lines[5] = ";".join(cells)
        path.write_text("\n".join(lines) + "\n")

    src, name = _source(tmp_path, "sensorlogger-android", "Gyroscope.csv", spreadsheet)
    assert _refused(capsys, tmp_path, src) == f"{name}: non-numeric value 'abc' in column 'y' at data row 5"


# -- missing columns, values out of range, conflicting rows, clock steps: the file's words ----------------

@pytest.mark.parametrize(
    ("file", "column"),
    [("Gyroscope.csv", "y"), ("Location.csv", "longitude"), ("TotalAcceleration.csv", "z")],
)
def test_a_missing_column_is_named_as_the_export_names_it(tmp_path, capsys, file, column):
    def rename(path: Path) -> None:
        lines = path.read_text().splitlines()
        lines[0] = ",".join(f"{c}_" if c == column else c for c in lines[0].split(","))
        path.write_text("\n".join(lines) + "\n")

    src, name = _source(tmp_path, "sensorlogger-android", file, rename)
    assert _refused(capsys, tmp_path, src) == f"{name}: missing column(s) [{column!r}]"


def test_a_latitude_out_of_range_names_its_cell(tmp_path, capsys):
    src, name = _source(tmp_path, "sensorlogger-android", "Location.csv",
                        lambda p: _set(p, "latitude", 3, "95.0"))
    message = _refused(capsys, tmp_path, src)
    assert message == f"{name}: 'latitude' = 95.0 at data row 3 is outside -90..90 (degrees of latitude)"


def test_a_gyroscope_in_degrees_names_the_first_cell_beyond_35_rad_s(tmp_path, capsys):
    def degrees(path: Path) -> None:
        lines = path.read_text().splitlines()
        header = lines[0].split(",")
        axes = [header.index(c) for c in ("x", "y", "z")]
        for i in range(1, len(lines)):
            cells = lines[i].split(",")
            for k in axes:
                cells[k] = repr(round(float(cells[k]) * 57.29578, 4))
            lines[i] = ",".join(cells)
        path.write_text("\n".join(lines) + "\n")

    src, name = _source(tmp_path, "sensorlogger-ios.zip", "Gyroscope.csv", degrees)
    message = _refused(capsys, tmp_path, src)
    assert message == (f"{name}: 'y' = -40.425 at data row 231 is outside -35..35 rad/s: rotation rates must "
                       "be in rad/s (deg/s?)")


@pytest.mark.parametrize(
    ("fixture", "expected"),
    [("sensorlogger-android", "seconds_elapsed=2.0733"),
     ("sensorlogger-android-v2.zip", "time=1610478711137000000")],
)
def test_rows_sharing_a_time_are_named_with_the_files_clock(tmp_path, capsys, fixture, expected):
    def repeat_time(path: Path) -> None:
        lines = path.read_text().splitlines()
        header = lines[0].split(",")
        above, cells = lines[7].split(","), lines[8].split(",")
        for clock in ("time", "seconds_elapsed"):
            if clock in header:
                cells[header.index(clock)] = above[header.index(clock)]
        lines[8] = ",".join(cells)
        path.write_text("\n".join(lines) + "\n")

    src, name = _source(tmp_path, fixture, "Gyroscope.csv", repeat_time)
    message = _refused(capsys, tmp_path, src)
    assert message == f"{name}: conflicting rows share timestamp {expected}: data row 7 and data row 8 " \
                      "hold different values"


def test_a_format_2_clock_step_quotes_the_time_column_in_nanoseconds(tmp_path, capsys):
    def step_back(path: Path) -> None:
        lines = path.read_text().splitlines()
        for i in range(40, len(lines)):
            cells = lines[i].split(",")
            cells[0] = str(int(cells[0]) - 2_000_000_000)
            lines[i] = ",".join(cells)
        path.write_text("\n".join(lines) + "\n")

    src, name = _source(tmp_path, "sensorlogger-android-v2.zip", "Gyroscope.csv", step_back)
    assert _refused(capsys, tmp_path, src).startswith(
        f"{name}: time goes back 1.99 s at data row 40 ('time' 1610478709790900000 after 1610478711780600000 "
        "at data row 39): the phone's clock was set back")


def test_a_quaternion_that_is_not_unit_names_its_row(tmp_path, capsys):
    src, name = _source(tmp_path, "sensorlogger-android", "Orientation.csv", lambda p: _set(p, "qw", 6, "3"))
    message = _refused(capsys, tmp_path, src)
    assert message == f"{name}: qx,qy,qz,qw are not unit quaternions: norm 3.16 at data row 6 " \
                      "(norms 1.00-3.16)"


def test_a_gpx_point_out_of_range_is_named_by_its_place_in_the_file(tmp_path, capsys):
    gpx = tmp_path / "walk.gpx"
    text = (SESSIONS / "walk.gpx").read_text()
    gpx.write_text(text.replace('<trkpt lat="37.78800"', '<trkpt lat="95.5"', 1))
    assert _refused(capsys, tmp_path, gpx) == f"{gpx}: 'lat' = 95.5 at point 2 is outside -90..90 " \
                                              "(degrees of latitude)"


def test_an_ipin_dataset_is_named_by_its_own_columns_and_rows(tmp_path, capsys):
    h5 = tmp_path / "cut.h5"
    shutil.copy(SESSIONS / "ipin2023-cut.h5", h5)
    with h5py.File(h5, "r+") as f:
        trial = next(iter(f))
        gyro = f[trial]["gyro"]
        values = gyro[:]
        values[4, 2] = np.float32(60.0)  # row 5, column y: deg/s, not rad/s
        gyro[...] = values
    src = f"{h5}::{trial}"
    message = _refused(capsys, tmp_path, src)
    assert message == f"cut.h5::{trial}/gyro: 'y' = 60.0 at row 5 is outside -35..35 rad/s: rotation rates " \
                      "must be in rad/s (deg/s?)"


@pytest.mark.parametrize(("fixture", "file", "column", "value"), [
    ("sensorlogger-android", "Gyroscope.csv", "z", "inf"),
    ("sensorlogger-ios.zip", "Location.csv", "horizontalAccuracy", "-inf"),
])
def test_an_infinite_value_is_refused_not_dropped_with_the_blank_rows(tmp_path, capsys, fixture, file, column,
                                                                      value):
    src, name = _source(tmp_path, fixture, file, lambda p: _set(p, column, 4, value))
    message = _refused(capsys, tmp_path, src)
    assert message == f"{name}: {column!r} = {value} at data row 4 is not a finite number"


def test_a_file_inside_a_zip_is_named_by_its_whole_path_there(tmp_path, capsys):
    # Sensor Logger zips its files in a folder named by the time; the user finds them there.
    folder = _export(tmp_path, "sensorlogger-android")
    _set(folder / "Gyroscope.csv", "y", 3, "abc")
    src = tmp_path / "export.zip"
    with zipfile.ZipFile(src, "w") as zf:
        for p in sorted(folder.iterdir()):
            zf.write(p, f"2023-11-14_22-13-20/{p.name}")
    message = _refused(capsys, tmp_path, src)
    member = "2023-11-14_22-13-20/Gyroscope.csv"
    assert message == f"{src}/{member}: non-numeric value 'abc' in column 'y' at data row 3"
