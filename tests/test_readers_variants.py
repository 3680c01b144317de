"""Export variants found by the readers audit, each made inside the test from the in-repo fixtures.

Short or gappy IMU streams, uncalibrated-only exports, whole-second and Latin-1 GPX, tap notes read as
far-away positions, IPIN trials without surveyed points, spreadsheet re-saves, a zip of zips, and
error messages that must name the recording the user gave.
"""

from __future__ import annotations

import logging
import shutil
import zipfile
from pathlib import Path

import h5py
import numpy as np
import pandas as pd
import pytest

from curbside.cli.localize import main
from curbside.errors import CurbsideInputError
from curbside.localize.readers import read_any
from curbside.localize.readers._resample import MAX_GAP_S
from curbside.localize.readers._tidy import STANDARD_GRAVITY
from curbside.localize.readers.gpx import _parse, read_gpx
from curbside.localize.readers.ipin import list_trials, read_trial
from curbside.localize.readers.sensorlogger import read_sensorlogger

SESSIONS = Path(__file__).parent / "data" / "sessions"
H5 = SESSIONS / "ipin2023-cut.h5"
A520 = "IPIN2023_T3_TrainingTrial01_repetition01"
ANDROID = SESSIONS / "sensorlogger-android"  # app 1.28, seconds_elapsed 2.0-7.0 s


def _android(tmp_path: Path, name: str = "export") -> Path:
    folder = tmp_path / name
    shutil.copytree(ANDROID, folder)
    return folder


def _edit(folder: Path, name: str, keep) -> None:
    table = pd.read_csv(folder / name)
    table[keep(table["seconds_elapsed"])].to_csv(folder / name, index=False)


def _warnings(caplog) -> list[str]:
    return [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING]


# --- 1, 2: short streams and gaps ------------------------------------------------------------------


def test_short_orientation_cut_is_a_warning_naming_the_stream_and_the_loss(tmp_path, caplog):
    folder = _android(tmp_path)
    _edit(folder, "Orientation.csv", lambda t: t < 4.5)
    with caplog.at_level(logging.WARNING):
        imu = read_sensorlogger(folder).imu
    assert imu["t"].max() < 4.5
    [line] = [m for m in _warnings(caplog) if "cut to" in m]
    assert f"{folder}/Orientation.csv ends 2.5 s before the accelerometer" in line
    assert "2.5 s of the 5.0 s accelerometer recording lost" in line


def test_a_trivial_cut_at_the_ends_stays_quiet(tmp_path, caplog):
    folder = _android(tmp_path)
    _edit(folder, "Orientation.csv", lambda t: t < 6.5)  # 0.5 s: below MAX_SILENT_CUT_S
    with caplog.at_level(logging.WARNING):
        read_sensorlogger(folder)
    assert not [m for m in _warnings(caplog) if "cut to" in m]


@pytest.mark.parametrize(
    ("name", "effect"),
    [("Gyroscope.csv", "filled by interpolation"), ("Orientation.csv", "filled by interpolation"),
     ("TotalAcceleration.csv", "imu.csv has no rows there")],
)
def test_gaps_in_an_imu_stream_are_reported(tmp_path, caplog, name, effect):
    folder = _android(tmp_path)
    _edit(folder, name, lambda t: (t < 3.5) | (t > 4.6))
    with caplog.at_level(logging.WARNING):
        session = read_sensorlogger(folder)
    assert session.imu["t"].max() > 6.5  # kept whole
    [line] = [m for m in _warnings(caplog) if "gap" in m]
    assert line.startswith(f"{folder}/{name}: 1 gap(s) longer than {MAX_GAP_S:.1f} s (1.1 s from t=3.5 s)")
    assert effect in line


def test_ipin_gap_names_the_dataset(tmp_path, caplog):
    path = tmp_path / "gap.h5"
    shutil.copy(H5, path)
    with h5py.File(path, "a") as f:
        gyro = f[A520]["gyro"][:]
        del f[A520]["gyro"]
        f[A520]["gyro"] = gyro[(gyro[:, 0] < 60) | (gyro[:, 0] > 62)]
    with caplog.at_level(logging.WARNING):
        read_trial(path, A520)
    assert any(m.startswith(f"gap.h5::{A520}/gyro: 1 gap(s)") for m in _warnings(caplog))


# --- 5: only uncalibrated sensors ------------------------------------------------------------------


def test_uncalibrated_only_android_export_is_read_with_a_warning(tmp_path, caplog):
    folder = _android(tmp_path)
    (folder / "TotalAcceleration.csv").rename(folder / "AccelerometerUncalibrated.csv")
    (folder / "Gyroscope.csv").rename(folder / "GyroscopeUncalibrated.csv")
    for name in ("Accelerometer.csv", "Orientation.csv"):
        (folder / name).unlink()
    with caplog.at_level(logging.WARNING):
        imu = read_sensorlogger(folder).imu
    calibrated = _android(tmp_path, "calibrated")
    (calibrated / "Orientation.csv").unlink()
    expected = read_sensorlogger(calibrated).imu
    pd.testing.assert_frame_equal(imu, expected)
    [line] = [m for m in _warnings(caplog) if "Uncalibrated" in m]
    assert "AccelerometerUncalibrated.csv, GyroscopeUncalibrated.csv" in line
    assert "keeps its bias" in line and "enable the calibrated sensors" in line and "Sensor Logger" in line


def test_uncalibrated_ios_accelerometer_in_g_is_converted(tmp_path):
    """iOS raw acceleration: in g, and with the iOS sign like the calibrated streams."""
    src = SESSIONS / "sensorlogger-ios.zip"
    with zipfile.ZipFile(src) as zf:
        folder = next(Path(n).parent.as_posix() for n in zf.namelist() if n.endswith("/Accelerometer.csv")
                      and not n.startswith("__MACOSX"))
        read = {n: pd.read_csv(zf.open(f"{folder}/{n}")) for n in
                ("Accelerometer.csv", "Gravity.csv", "Gyroscope.csv", "Metadata.csv", "Location.csv")}
    raw = read["Accelerometer.csv"].copy()
    for axis in "xyz":  # user acceleration + gravity on one clock in the fixture
        raw[axis] = (raw[axis] + read["Gravity.csv"][axis]) / STANDARD_GRAVITY
    out = tmp_path / "ios"
    out.mkdir()
    raw.to_csv(out / "AccelerometerUncalibrated.csv", index=False)
    read["Gyroscope.csv"].to_csv(out / "GyroscopeUncalibrated.csv", index=False)
    for name in ("Metadata.csv", "Location.csv"):
        read[name].to_csv(out / name, index=False)
    imu = read_sensorlogger(out).imu
    reference = read_sensorlogger(src).imu.set_index("t")
    common = reference.index.intersection(imu.set_index("t").index)
    assert len(common) > 200
    np.testing.assert_allclose(imu.set_index("t").loc[common, ["ax", "ay", "az"]],
                               reference.loc[common, ["ax", "ay", "az"]], atol=1e-5)


# --- 6, 7, 8: GPX ----------------------------------------------------------------------------------


def _gpx(points: list[tuple[str, float]], wpts: str = "", encoding: str = "UTF-8", name: str = "walk") -> str:
    pts = "".join(f'<trkpt lat="{37.7879 + i * 1e-4 + dlat:.7f}" lon="-122.4038"><time>{stamp}</time>'
                  f"<hdop>1.0</hdop></trkpt>\n" for i, (stamp, dlat) in enumerate(points))
    return (f'<?xml version="1.0" encoding="{encoding}"?>\n<gpx version="1.1" creator="t" '
            f'xmlns="http://www.topografix.com/GPX/1/1">{wpts}<trk><name>{name}</name><trkseg>\n{pts}'
            "</trkseg></trk></gpx>\n")


def test_whole_second_gpx_keeps_the_first_fix_of_each_second(tmp_path, caplog):
    seconds = [0, 1, 1, 2, 3, 4, 4, 5, 6, 7]  # 1 Hz fixes whose times were truncated to the second
    path = tmp_path / "wholesec.gpx"
    path.write_text(_gpx([(f"2026-03-01T18:00:{s:02d}Z", 0.0) for s in seconds]))
    with caplog.at_level(logging.WARNING):
        gnss = read_any(path).gnss
    np.testing.assert_array_equal(gnss["t"], np.arange(8.0))
    np.testing.assert_allclose(gnss["lat"].iat[1], 37.7879 + 1e-4)  # the first of second 1
    assert _warnings(caplog) == [f"{path}: 2 fix(es) share a whole-second <time> with an earlier one; "
                                 "kept the first fix of each second"]


@pytest.mark.parametrize(
    "stamps",
    [["18:00:00.5Z", "18:00:01.5Z", "18:00:01.5Z"],  # sub-second times that repeat
     ["18:00:00Z"] * 5 + ["18:00:01Z"]],  # most fixes share a second: the times are not the fixes'
)
def test_gpx_with_truly_conflicting_times_is_still_refused(tmp_path, stamps):
    path = tmp_path / "bad.gpx"
    path.write_text(_gpx([(f"2026-03-01T{s}", 0.0) for s in stamps]))
    with pytest.raises(CurbsideInputError, match="conflicting rows share timestamp"):
        read_gpx(path)


def test_gpx_encoding_declaration_is_honoured(tmp_path):
    path = tmp_path / "latin1.gpx"
    text = _gpx([(f"2026-03-01T18:00:{s:02d}Z", 0.0) for s in range(5)], encoding="ISO-8859-1",
                name="Nürnberg Spaziergang")
    path.write_bytes(text.encode("latin-1"))
    assert len(read_gpx(path).gnss) == 5
    assert _parse(path).tracks[0].name == "Nürnberg Spaziergang"
    path.write_bytes(text.replace("ISO-8859-1", "no-such-codec").encode("latin-1"))
    with pytest.raises(CurbsideInputError, match="unknown encoding 'no-such-codec'"):
        read_gpx(path)


def test_gpx_waypoint_far_from_the_track_is_dropped(tmp_path, caplog):
    wpts = ('<wpt lat="37.7880" lon="-122.4038"><time>2026-03-01T18:00:01Z</time></wpt>'
            '<wpt lat="3" lon="5"><time>2026-03-01T18:00:02Z</time></wpt>')
    path = tmp_path / "far.gpx"
    path.write_text(_gpx([(f"2026-03-01T18:00:{s:02d}Z", 0.0) for s in range(5)], wpts))
    with caplog.at_level(logging.WARNING):
        waypoints = read_gpx(path).waypoints
    np.testing.assert_array_equal(waypoints["lat"], [37.788])
    expected = "dropped 1 <wpt> more than 5 km from every track point: (3.00000, 5.00000) at t=2.0 s"
    assert expected in caplog.text


# --- 8: Sensor Logger taps and routes far from the fixes -------------------------------------------


def test_tap_note_read_as_a_far_position_is_not_a_waypoint(tmp_path, caplog):
    folder = _android(tmp_path)
    taps = pd.DataFrame({"time": [1700000003000000000, 1700000004000000000, 1700000005000000000],
                         "seconds_elapsed": [3.0, 4.0, 5.0],
                         "text": ["3,5", "door, left", "49.4612756,11.11098835"],
                         "millisecond_press_duration": [100, 100, 100]})
    taps.to_csv(folder / "Annotation.csv", index=False)
    with caplog.at_level(logging.WARNING):
        session = read_sensorlogger(folder)
    np.testing.assert_array_equal(session.waypoints["t"], [5.0])
    assert {"t": 3.0, "text": "3,5"} in session.meta["annotations"]
    expected = "1 tap(s) read as 'lat,lon' lie more than 5 km from every GNSS fix ('3,5' at t=3.0 s)"
    assert expected in caplog.text


def test_route_far_from_the_fixes(tmp_path, caplog):
    route = tmp_path / "route.csv"
    route.write_text("lat,lon\n3.0,5.0\n49.4614,11.1111\n")
    with caplog.at_level(logging.WARNING):
        waypoints = read_any(ANDROID, route=route).waypoints
    np.testing.assert_array_equal(waypoints["lat"], [49.4614])
    expected = "dropped 1 point(s) more than 5 km from every GNSS fix: (3.00000, 5.00000) at t=8.1 s"
    assert expected in caplog.text
    route.write_text("lat,lon\n3.0,5.0\n3.1,5.1\n")
    with pytest.raises(CurbsideInputError, match="none of its 2 point"):
        read_any(ANDROID, route=route)


# --- 9: IPIN trials without surveyed points ---------------------------------------------------------


def _h5_edit(tmp_path: Path, edit) -> Path:
    path = tmp_path / "trial.h5"
    shutil.copy(H5, path)
    with h5py.File(path, "a") as f:
        edit(f[A520])
    return path


def test_ipin_trial_without_posi_converts_without_waypoints(tmp_path, caplog):
    path = _h5_edit(tmp_path, lambda g: g.__delitem__("posi"))
    assert A520 in list_trials(path)
    dst = tmp_path / "out"
    with caplog.at_level(logging.WARNING):
        assert main(["convert", f"{path}::{A520}", str(dst)]) == 0
    assert not (dst / "waypoints.csv").exists() and (dst / "imu.csv").exists() and (dst / "gnss.csv").exists()
    assert "no surveyed waypoints ('posi' dataset missing)" in caplog.text


def test_ipin_trial_with_empty_posi_and_network_fixes_only_is_imu_only(tmp_path, caplog):
    def edit(g):
        gnss = g["gnss"][:]
        gnss[:, 3] = 0.0
        del g["posi"], g["gnss"]
        g["gnss"] = gnss
        g.create_dataset("posi", shape=(0, 4), dtype=float)

    with caplog.at_level(logging.WARNING):
        session = read_trial(_h5_edit(tmp_path, edit), A520)
    assert session.waypoints is None and session.gnss is None and len(session.imu) > 1000
    assert "start" not in session.meta
    assert "no surveyed waypoints ('posi' dataset empty)" in caplog.text
    assert "GNSS fixes are network (alt == 0) locations" in caplog.text


def test_ipin_trial_without_imu_is_refused(tmp_path):
    path = _h5_edit(tmp_path, lambda g: g.__delitem__("acce"))
    assert A520 not in list_trials(path)
    with pytest.raises(CurbsideInputError, match=r"missing dataset\(s\) \['acce'\]"):
        read_trial(path, A520)


# --- 10, 11, 12: messages, separators, zips of zips -------------------------------------------------


@pytest.mark.parametrize(
    ("src", "flag", "expected"),
    [("sensorlogger-android-1.12.zip", "--pdr", "sensorlogger-android-1.12.zip: --pdr needs the orientation "
      "quaternion (qx,qy,qz,qw); this source has none (a Sensor Logger export needs Orientation.csv)"),
     ("walk.gpx", "--steps", "walk.gpx: --steps/--pdr need IMU data, and this source has none")],
)
def test_derived_tables_errors_name_the_source(tmp_path, capsys, src, flag, expected):
    assert main(["convert", str(SESSIONS / src), str(tmp_path / "out"), flag]) == 2
    err = capsys.readouterr().err.strip()
    assert err == f"localize: error: {SESSIONS / expected}" and "imu.csv" not in err


def test_semicolon_separated_export_is_read(tmp_path, caplog):
    folder = _android(tmp_path)
    for path in folder.glob("*.csv"):
        table = pd.read_csv(path)
        if len(table):
            path.write_text(table.to_csv(index=False, sep=";", decimal=","))
    with caplog.at_level(logging.WARNING):
        session = read_sensorlogger(folder)
    original = read_sensorlogger(ANDROID)
    pd.testing.assert_frame_equal(session.imu, original.imu)
    pd.testing.assert_frame_equal(session.gnss, original.gnss)
    assert session.meta["platform"] == "android"
    [line] = _warnings(caplog)
    assert "uses ';' separators" in line and str(folder) in line


def test_list_of_a_zip_of_zips_is_an_error_like_convert(tmp_path, capsys):
    inner = tmp_path / "a.zip"
    with zipfile.ZipFile(inner, "w") as zf:
        for file in ANDROID.iterdir():
            zf.write(file, file.name)
    outer = tmp_path / "zips.zip"
    with zipfile.ZipFile(outer, "w") as zf:
        zf.write(inner, "a.zip")
    assert main(["convert", str(outer), "--list"]) == 2
    listed = capsys.readouterr().err.strip()
    assert main(["convert", str(outer), str(tmp_path / "out")]) == 2
    converted = capsys.readouterr().err.strip()
    assert listed == converted
    assert listed == (f"localize: error: {outer}: not a Sensor Logger export: it holds zip files (a.zip), "
                      "not CSVs; unpack them and give the folder, or give each zip")


def test_a_short_gravity_stream_cuts_the_imu_instead_of_holding_its_last_value(tmp_path, caplog):
    folder = _android(tmp_path)
    total, user = pd.read_csv(folder / "TotalAcceleration.csv"), pd.read_csv(folder / "Accelerometer.csv")
    gravity = total.copy()
    gravity[["x", "y", "z"]] = total[["x", "y", "z"]] - user[["x", "y", "z"]]
    gravity[gravity["seconds_elapsed"] < 4.5].to_csv(folder / "Gravity.csv", index=False)
    (folder / "TotalAcceleration.csv").unlink()  # gravity must come from Gravity.csv
    with caplog.at_level(logging.WARNING):
        imu = read_sensorlogger(folder).imu
    assert imu["t"].max() < 4.5
    [line] = [m for m in _warnings(caplog) if "Gravity.csv covers" in m]
    assert "imu.csv cut to it" in line
