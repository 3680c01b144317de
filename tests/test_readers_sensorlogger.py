"""Sensor Logger exports: every real export variant, every failure of issue 10, and bad input.

The fixtures (``tests/data/sessions/make_fixtures.py``) re-express IPIN walks in the layout of each
real variant; ``real/`` holds a trimmed real export (MIT). Tests on the other real exports fetched
into ``../realdata/sensorlogger`` (no licence to ship them) skip when that folder is absent.
"""

from __future__ import annotations

import logging
import shutil
import zipfile
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from scipy.spatial.transform import Rotation

from curbside.errors import CurbsideInputError
from curbside.localize.readers import detect_format, read_any
from curbside.localize.readers.ipin import read_trial
from curbside.localize.readers.sensorlogger import NWU_TO_ENU, magnetic_north_deg, read_sensorlogger

SESSIONS = Path(__file__).parent / "data" / "sessions"
H5 = SESSIONS / "ipin2023-cut.h5"
A520 = "IPIN2023_T3_TrainingTrial01_repetition01"
G930 = "IPIN2023_T3_TrainingTrial23_repetition03"
REAL = SESSIONS / "real" / "sensorlogger-android-1.12.0-ethz"
REALDATA = Path(__file__).resolve().parents[2] / "realdata" / "sensorlogger"
QUAT = ["qx", "qy", "qz", "qw"]

# export -> (IPIN trial, UNIX time of the fixture's t_s origin): t_s = t + t0_unix_s - origin
VARIANTS = {
    "sensorlogger-android": (A520, 1_700_000_000.0 - 60.0),
    "sensorlogger-ios.zip": (A520, 1_700_000_000.0 - 60.0),
    "sensorlogger-ios-standardised.zip": (A520, 1_700_000_000.0 - 60.0),
    "sensorlogger-android-v2.zip": (G930, 1_610_478_700.0 - 55.0),
    "sensorlogger-android-1.12.zip": (A520, 1_700_000_000.0 - 60.0),
}


def _reference(session, trial: str = A520, origin: float = 1_700_000_000.0 - 60.0) -> pd.DataFrame:
    """The IPIN imu rows at the session's imu times (``t_s = t + t0_unix_s - origin``)."""
    ref = read_trial(H5, trial).imu
    t_s = (session.imu["t"] + session.meta["t0_unix_s"] - origin).round(4)
    return ref.set_index(ref["t"].round(4)).loc[t_s]


@pytest.mark.parametrize("export", sorted(VARIANTS))
def test_every_variant_decodes_to_the_recording_it_was_made_from(export):
    session = read_any(SESSIONS / export)
    imu = session.imu
    assert len(imu) > 200
    ref = _reference(session, *VARIANTS[export])
    np.testing.assert_allclose(imu[["ax", "ay", "az"]], ref[["ax", "ay", "az"]], atol=1e-5)
    np.testing.assert_allclose(imu[["gx", "gy", "gz"]], ref[["gx", "gy", "gz"]], atol=1e-5)
    if export.endswith("1.12.zip"):
        assert "qx" not in imu.columns  # app 1.12 export without Orientation.csv: no quaternion
    else:
        error = Rotation.from_quat(imu[QUAT].to_numpy()) * Rotation.from_quat(ref[QUAT].to_numpy()).inv()
        assert np.degrees(error.magnitude()).max() < 0.01
    assert session.gnss is not None and len(session.gnss) >= 4
    assert session.meta["platform"] == ("ios" if "ios" in export else "android")


def test_format_2_time_only_export_is_read_on_one_clock():
    """Issue 10: exports with only ``time`` (ns) and no ``seconds_elapsed`` were refused."""
    session = read_sensorlogger(SESSIONS / "sensorlogger-android-v2.zip")
    assert session.meta["export_version"] == "2"
    with zipfile.ZipFile(SESSIONS / "sensorlogger-android-v2.zip") as zf:
        acc = pd.read_csv(zf.open("Accelerometer.csv"))
        loc = pd.read_csv(zf.open("Location.csv"))
    assert "seconds_elapsed" not in acc.columns
    # t = (time - start) / 1e9 on the accelerometer's clock, shared by every stream
    assert session.meta["t0_unix_s"] == pytest.approx(acc["time"].iat[0] / 1e9, abs=1e-6)
    expected = (loc["time"] - acc["time"].iat[0]) / 1e9
    np.testing.assert_allclose(session.gnss["t"], expected, atol=1e-6)


def _rewrite_zip(src: Path, dst: Path, edit) -> Path:
    """Copy a zip, passing each CSV member through ``edit(name, table) -> table | bytes | None``."""
    with zipfile.ZipFile(src) as zin, zipfile.ZipFile(dst, "w") as zout:
        for info in zin.infolist():
            data = zin.read(info)
            name = Path(info.filename).name
            if name.endswith(".csv") and not name.startswith("."):
                table = pd.read_csv(zin.open(info)) if data else pd.DataFrame()
                new = edit(name, table)
                if new is None:
                    continue
                data = new if isinstance(new, bytes) else new.to_csv(index=False).encode()
            zout.writestr(info.filename, data)
    return dst


def test_format_2_streams_on_different_clocks_are_refused(tmp_path):
    def shift(name, table):
        if name == "Location.csv":
            table["time"] += 3 * 86400 * 10**9
        return table

    bad = _rewrite_zip(SESSIONS / "sensorlogger-android-v2.zip", tmp_path / "clocks.zip", shift)
    message = r"Location.csv and Accelerometer.csv do not overlap.*3.0 days"
    with pytest.raises(CurbsideInputError, match=message):
        read_sensorlogger(bad)


def _android_copy(tmp_path: Path) -> Path:
    folder = tmp_path / "export"
    shutil.copytree(SESSIONS / "sensorlogger-android", folder)
    return folder


def test_files_of_two_recordings_in_one_folder_are_refused(tmp_path):
    """A folder overwritten file by file with another day's export: seconds_elapsed agree, time does not."""
    folder = _android_copy(tmp_path)
    q = pd.read_csv(folder / "Orientation.csv")
    q["time"] += 3 * 86400 * 10**9
    q.to_csv(folder / "Orientation.csv", index=False)
    with pytest.raises(CurbsideInputError, match="Orientation.csv and TotalAcceleration.csv do not overlap"):
        read_sensorlogger(folder)


@pytest.mark.parametrize("content", [b"", b"time,seconds_elapsed,text,millisecond_press_duration\n"])
def test_empty_annotation_file_is_no_taps(tmp_path, content):
    """Issue 10: a 0-byte Annotation.csv (annotations on, never tapped) aborted the conversion."""
    folder = _android_copy(tmp_path)
    (folder / "Annotation.csv").write_bytes(content)
    session = read_sensorlogger(folder)
    assert session.waypoints is None and "annotations" not in session.meta
    assert session.imu is not None and session.gnss is not None
    with zipfile.ZipFile(SESSIONS / "sensorlogger-android-1.12.zip") as zf:  # as the app writes it
        assert zf.read("Annotation.csv") == b""
    assert read_sensorlogger(SESSIONS / "sensorlogger-android-1.12.zip").waypoints is None


@pytest.mark.parametrize(
    "content",
    [b"", b"time,seconds_elapsed,horizontalAccuracy,longitude,latitude\n",
     b"time,seconds_elapsed,horizontalAccuracy,longitude,latitude\n1700000002000000000,2.0,15,0,0\n"],
    ids=["0-byte", "header-only", "only-(0,0)"],
)
def test_location_without_fixes_gives_an_imu_only_session(tmp_path, caplog, content):
    """Issue 10: a 0-byte or header-only Location.csv aborted the conversion of a fine IMU."""
    folder = _android_copy(tmp_path)
    (folder / "Location.csv").write_bytes(content)
    with caplog.at_level(logging.WARNING):
        session = read_any(folder)
    assert session.gnss is None and len(session.imu) > 200
    assert "Location.csv" in caplog.text


def test_motion_files_without_rows_give_a_gnss_only_session(tmp_path):
    folder = _android_copy(tmp_path)
    for name in ("TotalAcceleration.csv", "Accelerometer.csv", "Gyroscope.csv", "Orientation.csv"):
        (folder / name).write_text("time,seconds_elapsed,z,y,x\n")
    session = read_any(folder)
    assert session.imu is None and len(session.gnss) == 5


@pytest.mark.parametrize("metadata", [True, False], ids=["with-metadata", "without-metadata"])
def test_gnss_only_export_claims_a_platform_only_from_metadata(tmp_path, metadata):
    """Without an IMU no frame needs the platform: without Metadata.csv none is recorded (it said
    "android")."""
    folder = tmp_path / "export"
    folder.mkdir()
    names = ("Location.csv", "Metadata.csv") if metadata else ("Location.csv",)
    for name in names:
        shutil.copy(SESSIONS / "sensorlogger-android" / name, folder / name)
    session = read_any(folder)
    assert session.imu is None and len(session.gnss) == 5
    assert session.meta.get("platform") == ("android" if metadata else None)
    assert "platform_inferred_from" not in session.meta


def _text_magnetometer(folder: Path) -> None:
    """A Magnetometer.csv on the orientation's clock whose z column is text."""
    clock = pd.read_csv(folder / "Orientation.csv")[["time", "seconds_elapsed"]]
    clock.assign(z="n/a", y=20.0, x=5.0).to_csv(folder / "Magnetometer.csv", index=False)


@pytest.mark.parametrize("metadata", [True, False], ids=["with-metadata", "without-metadata"])
def test_malformed_magnetometer_matters_only_against_an_orientation(tmp_path, metadata):
    """The magnetometer is read only to check (or infer) the orientation's frame: without
    Orientation.csv a broken one is not read (it refused the export); with one it is refused."""
    folder = _android_copy(tmp_path)
    _text_magnetometer(folder)
    if not metadata:
        (folder / "Metadata.csv").unlink()
    with pytest.raises(CurbsideInputError, match="Magnetometer.csv"):
        read_sensorlogger(folder)
    (folder / "Orientation.csv").unlink()
    session = read_sensorlogger(folder)
    assert "qx" not in session.imu.columns and len(session.imu) > 200
    assert "magnetic_north_deg" not in session.meta


def _two_recordings_zip(tmp_path: Path) -> Path:
    path = tmp_path / "two.zip"
    with zipfile.ZipFile(path, "w") as zf:
        for day in ("2024-02-11_15-02-01", "2024-02-12_09-30-00"):
            for file in (SESSIONS / "sensorlogger-android").iterdir():
                zf.write(file, f"exports/{day}/{file.name}")
    return path


def test_two_recordings_in_one_zip_are_refused_and_one_can_be_picked(tmp_path):
    """Issue 10: two recordings in one zip were silently mixed."""
    path = _two_recordings_zip(tmp_path)
    with pytest.raises(CurbsideInputError, match=r"holds 2 recordings \(exports/2024-02-11_15-02-01, "
                                                 r"exports/2024-02-12_09-30-00\); pick one as .*two.zip::"):
        read_any(path)
    session = read_any(f"{path}::2024-02-12_09-30-00")  # the last folder name is enough when unique
    assert session.name == "2024-02-12_09-30-00"
    assert session.meta["source"]["recording"] == "exports/2024-02-12_09-30-00"
    assert read_any(f"{path}::exports/2024-02-11_15-02-01").name == "2024-02-11_15-02-01"
    with pytest.raises(CurbsideInputError, match="no such recording; it holds"):
        read_any(f"{path}::2024-03-01")


def test_two_recordings_in_one_folder_tree_are_refused(tmp_path):
    tree = tmp_path / "walks"
    shutil.copytree(SESSIONS / "sensorlogger-android", tree / "monday")
    shutil.copytree(SESSIONS / "sensorlogger-android", tree / "tuesday")
    assert detect_format(tree) == "sensorlogger"
    with pytest.raises(CurbsideInputError, match=r"holds 2 recordings \(monday, tuesday\)"):
        read_any(tree)
    assert read_any(f"{tree}::tuesday").name == "tuesday"
    shutil.copy(SESSIONS / "sensorlogger-android" / "Gyroscope.csv", tree / "Gyroscope.csv")
    with pytest.raises(CurbsideInputError, match=r"holds 3 recordings \(\(top level\), monday, tuesday\)"):
        read_any(tree)


def test_mac_zip_debris_is_skipped():
    with zipfile.ZipFile(SESSIONS / "sensorlogger-ios.zip") as zf:
        assert any(n.startswith("__MACOSX/") for n in zf.namelist())
    assert read_any(SESSIONS / "sensorlogger-ios.zip").imu is not None


def test_ios_world_frame_is_checked_against_magnetic_north(caplog):
    """Issue 10: the iOS frame turn. In ENU the magnetometer must point north; unturned it points east."""
    session = read_any(SESSIONS / "sensorlogger-ios.zip")
    assert session.meta["magnetic_north_deg"] == pytest.approx(0.0, abs=0.5)
    with zipfile.ZipFile(SESSIONS / "sensorlogger-ios.zip") as zf:
        folder = "2023-11-14_22-13-20/"
        mag = pd.read_csv(zf.open(folder + "Magnetometer.csv"))
        quat = pd.read_csv(zf.open(folder + "Orientation.csv"))
    mag = mag.rename(columns={"seconds_elapsed": "t", "x": "mx", "y": "my", "z": "mz"})
    quat = quat.rename(columns={"seconds_elapsed": "t"})
    # The quaternions as exported (North-West-Up) taken as ENU: north, their x axis, reads as east.
    assert magnetic_north_deg(quat, mag) == pytest.approx(90.0, abs=0.5)


def test_standardised_ios_orientation_follows_the_magnetometer(caplog):
    with caplog.at_level(logging.WARNING):
        session = read_any(SESSIONS / "sensorlogger-ios-standardised.zip")
    assert session.meta["standardised"] is True
    assert session.meta["magnetic_north_deg"] == pytest.approx(0.0, abs=0.5)
    assert "world frame turned -90 deg" in caplog.text


def test_wrong_frame_is_reported(tmp_path, caplog):
    """A world frame a quarter turn off (iOS export): the check sees north 90 deg off and says so."""
    def turn(name, table):
        if name == "Orientation.csv":
            quarter_turn = Rotation.from_euler("z", 90, degrees=True)
            table[QUAT] = (quarter_turn * Rotation.from_quat(table[QUAT])).as_quat()
        return table

    path = _rewrite_zip(SESSIONS / "sensorlogger-ios.zip", tmp_path / "turned.zip", turn)
    with caplog.at_level(logging.WARNING):
        session = read_any(path)
    assert abs(session.meta["magnetic_north_deg"]) == pytest.approx(90.0, abs=0.5)
    assert "magnetic north lies at" in caplog.text


def test_gravity_is_restored_from_the_orientation(tmp_path, caplog):
    folder = _android_copy(tmp_path)
    (folder / "TotalAcceleration.csv").unlink()  # leaves the gravity-free Accelerometer.csv
    with caplog.at_level(logging.WARNING):
        session = read_sensorlogger(folder)
    assert "gravity restored from Orientation.csv" in caplog.text
    ref = _reference(session)
    # the restored gravity is the rotation vector's, interpolated onto the accelerometer clock
    np.testing.assert_allclose(session.imu[["ax", "ay", "az"]], ref[["ax", "ay", "az"]], atol=0.02)


def test_acceleration_without_any_gravity_source_is_refused(tmp_path):
    folder = _android_copy(tmp_path)
    (folder / "TotalAcceleration.csv").unlink()
    (folder / "Orientation.csv").unlink()
    with pytest.raises(CurbsideInputError, match="without gravity, and no TotalAcceleration.csv"):
        read_sensorlogger(folder)


def test_location_repairs_and_null_island(tmp_path):
    session = read_sensorlogger(SESSIONS / "sensorlogger-android")
    raw = pd.read_csv(SESSIONS / "sensorlogger-android" / "Location.csv")
    assert ((raw["latitude"] == 0) & (raw["longitude"] == 0)).sum() == 1
    assert len(session.gnss) == len(raw) - 2  # the (0, 0) fix and one exact duplicate dropped
    assert session.gnss["t"].is_monotonic_increasing
    folder = _android_copy(tmp_path)
    loc = pd.read_csv(folder / "Location.csv").drop(columns=["horizontalAccuracy"])
    loc.to_csv(folder / "Location.csv", index=False)
    assert read_sensorlogger(folder).gnss["accuracy_m"].isna().all()  # unknown accuracy: invalid fixes


def test_tap_waypoints_and_route(tmp_path):
    session = read_sensorlogger(SESSIONS / "sensorlogger-android")
    expected = [[8.05, 49.4612756, 11.11098835]]
    np.testing.assert_allclose(session.waypoints[["t", "lat", "lon"]].to_numpy(), expected)
    assert session.meta["annotations"] == [{"t": 9.0, "text": "corner"}]
    route = tmp_path / "route.csv"
    route.write_text("lat,lon\n49.4613,11.1110\n49.4614,11.1111\n")  # near the fixes (far ones are refused)
    np.testing.assert_allclose(read_any(SESSIONS / "sensorlogger-android", route=route).waypoints["lat"],
                               [49.4613, 49.4614])
    route.write_text("lat,lon\n49.1,11.1\n")
    with pytest.raises(CurbsideInputError, match="1 route points for 2 taps"):
        read_any(SESSIONS / "sensorlogger-android", route=route)
    with pytest.raises(CurbsideInputError, match="Sensor Logger exports only"):
        read_any(SESSIONS / "walk.gpx", route=route)
    with pytest.raises(CurbsideInputError, match="no Annotation.csv taps"):
        read_any(SESSIONS / "sensorlogger-android-1.12.zip", route=route)


def test_orientation_inconsistent_with_gravity_is_refused(tmp_path):
    folder = _android_copy(tmp_path)
    q = pd.read_csv(folder / "Orientation.csv")
    quarter_turn = Rotation.from_euler("x", 90, degrees=True)  # gravity horizontal: no sign fixes that
    q[QUAT] = (quarter_turn * Rotation.from_quat(q[QUAT])).as_quat()
    q.to_csv(folder / "Orientation.csv", index=False)
    with pytest.raises(CurbsideInputError, match="disagree on gravity"):
        read_sensorlogger(folder)


def _break(folder: Path, name: str, content: bytes) -> None:
    (folder / name).write_bytes(content)


@pytest.mark.parametrize(
    ("name", "content", "message"),
    [
        ("Gyroscope.csv", b"\x89PNG\r\n\x1a\n\x00\x00\x00\rIHDR\xff\xfe", "malformed CSV"),
        ("Gyroscope.csv", b"z,y,x\n1,2,3\n", r"no time column \('seconds_elapsed' or 'time'\)"),
        ("Gyroscope.csv", b"time,seconds_elapsed,z,y\n1700000002000000000,2.0,1,2\n", r"missing column"),
        ("Gyroscope.csv", b"time,seconds_elapsed,z,y,x\n1700000002000000000,2.0,a,b,c\n", "non-numeric"),
        ("Location.csv", b"time,seconds_elapsed,horizontalAccuracy\n1700000002000000000,2.0,5\n",
         r"missing column\(s\) \['latitude', 'longitude'\]"),
        ("Orientation.csv", b"time,seconds_elapsed,qz,qy,qx,qw\n1700000002000000000,2.0,0,0,0,2\n",
         "not unit quaternions"),
        ("Accelerometer.csv", b'"Time (s)","Acceleration x (m/s^2)"\n0.1,0.2\n', "phyphox export"),
    ],
    ids=["binary", "no-clock", "missing-axis", "text-values", "no-lat-lon", "not-unit-q", "phyphox"],
)
def test_bad_files_are_one_line_input_errors(tmp_path, name, content, message):
    folder = _android_copy(tmp_path)
    _break(folder, name, content)
    with pytest.raises(CurbsideInputError, match=message):
        read_sensorlogger(folder)


def test_unreadable_metadata_is_a_warning(tmp_path, caplog):
    folder = _android_copy(tmp_path)
    (folder / "Metadata.csv").write_bytes(b'version,platform\n3,"android\n')
    with caplog.at_level(logging.WARNING):
        session = read_sensorlogger(folder)
    assert session.meta["platform"] == "android" and "Metadata.csv" in caplog.text


def test_bad_sources(tmp_path):
    bad_zip = tmp_path / "broken.zip"
    bad_zip.write_bytes(b"PK\x03\x04 this is not a zip")
    with pytest.raises(CurbsideInputError, match="unreadable zip"):
        read_any(bad_zip)
    no_export = tmp_path / "notes.zip"
    with zipfile.ZipFile(no_export, "w") as zf:
        zf.writestr("notes.txt", "hello")
    with pytest.raises(CurbsideInputError, match="not a Sensor Logger export"):
        read_any(no_export)
    empty = tmp_path / "empty"
    empty.mkdir()
    for name in ("Accelerometer.csv", "Gyroscope.csv", "Location.csv"):
        (empty / name).write_bytes(b"")
    with pytest.raises(CurbsideInputError, match="every motion and location file is empty"):
        read_any(empty)


# --- real exports -----------------------------------------------------------------------------------------


def test_trimmed_real_android_1_12_export():
    """A real export (app 1.12.0, SM-A520F lying on a table; MIT, see real/README.md)."""
    session = read_any(REAL)
    assert session.meta["app_version"] == "1.12.0"
    assert "qx" not in session.imu.columns  # the repository has no Orientation.csv
    np.testing.assert_allclose(session.imu[["ax", "ay", "az"]].mean(), [0.13, -0.04, 9.71], atol=0.02)
    assert np.abs(session.imu[["gx", "gy", "gz"]].to_numpy()).max() < 0.01  # still
    np.testing.assert_allclose(session.gnss["accuracy_m"], [24.354, 24.796, 21.119], atol=1e-3)


@pytest.fixture
def realdata() -> Path:
    if not REALDATA.is_dir():
        pytest.skip("../realdata/sensorlogger (fetched real exports) is not beside this checkout")
    return REALDATA


def test_real_exports_of_every_kind(realdata):
    v2 = read_any(realdata / "android-v2-2021-SM-N960F-inhand-27steps")
    assert v2.meta["export_version"] == "2" and len(v2.gnss) == 24
    ios = read_any(realdata / "ios-1.10.4-2022-iphone12mini-tue")
    acc = ios.imu[["ax", "ay", "az"]].to_numpy(copy=True)
    world = Rotation.from_quat(ios.imu[QUAT].to_numpy()).apply(acc)
    assert world[:, 2].mean() == pytest.approx(9.8, abs=0.3)  # iOS sign found from the data
    with pytest.raises(CurbsideInputError, match=r"do not overlap in time \(3.2 days apart"):
        read_any(realdata / "ios-1.11-iphone13-jmandzak-root-mixed")


def test_real_ios_frame_points_north(realdata):
    """The verification of the NWU->ENU turn on a real iOS export (docs/sessions.md)."""
    folder = realdata / "ios-1.11-iphone13-jmandzak-root-mixed"
    quat = pd.read_csv(folder / "Orientation.csv").rename(columns={"seconds_elapsed": "t"})
    mag = pd.read_csv(folder / "Magnetometer.csv").rename(
        columns={"seconds_elapsed": "t", "x": "mx", "y": "my", "z": "mz"})
    quat[QUAT] = (NWU_TO_ENU * Rotation.from_quat(quat[QUAT].to_numpy())).as_quat()
    assert magnetic_north_deg(quat, mag) == pytest.approx(-5.0, abs=2.0)  # declination in Tennessee ~ -5
