"""Readers: IPIN HDF5, Sensor Logger exports, GPX, the dispatcher, and each kind of bad input."""

from __future__ import annotations

import shutil
import zipfile
from pathlib import Path

import h5py
import numpy as np
import pandas as pd
import pytest
from scipy.spatial.transform import Rotation

from curbside.errors import CurbsideInputError
from curbside.localize.readers import detect_format, read_any
from curbside.localize.readers._resample import interp_quaternions
from curbside.localize.readers._tidy import STANDARD_GRAVITY, accelerometer_ms2, tidy_table
from curbside.localize.readers.gpx import read_gpx
from curbside.localize.readers.ipin import list_trials, read_trial
from curbside.localize.readers.sensorlogger import read_sensorlogger
from curbside.localize.session import read_session, write_session

SESSIONS = Path(__file__).parent / "data" / "sessions"
H5 = SESSIONS / "ipin2023-cut.h5"
A520 = "IPIN2023_T3_TrainingTrial01_repetition01"  # gyro at 100 Hz, accelerometer at 50 Hz
G930 = "IPIN2023_T3_TrainingTrial23_repetition03"


def _raw(trial: str, name: str) -> np.ndarray:
    with h5py.File(H5) as f:
        data = f[trial][name][:]
    # the reader keeps float32 values at their logged decimals (0.0679, not 0.06790000200)
    return data.astype(str).astype(float) if data.dtype == np.float32 else data.astype(float)


# --- IPIN ----------------------------------------------------------------------------------------


def test_list_trials_names_every_group():
    assert list_trials(H5) == [A520, G930]


def test_imu_is_on_the_accelerometer_clock_with_gyro_interpolated():
    session = read_trial(H5, A520)
    acce, gyro = _raw(A520, "acce"), _raw(A520, "gyro")
    assert len(gyro) > 1.8 * len(acce)  # really two rates
    imu = session.imu
    assert np.isin(imu["t"].round(4), acce[:, 0].round(4)).all()
    expected = np.interp(imu["t"], gyro[:, 0], gyro[:, 2])
    np.testing.assert_allclose(imu["gy"], expected, atol=1e-6)
    np.testing.assert_allclose(np.linalg.norm(imu[["qx", "qy", "qz", "qw"]], axis=1), 1.0, atol=1e-9)


def test_quaternion_rotates_gravity_up():
    imu = read_trial(H5, G930).imu
    rot = Rotation.from_quat(imu[["qx", "qy", "qz", "qw"]].to_numpy())
    world = rot.apply(imu[["ax", "ay", "az"]].to_numpy(copy=True))
    assert abs(world[:, 2].mean() - 9.8) < 0.3
    assert np.abs(world[:, :2].mean(axis=0)).max() < 0.3


def test_start_pose_from_first_two_waypoints():
    session = read_trial(H5, "TrainingTrial01_repetition01")  # the short name resolves too
    posi = _raw(A520, "posi")
    start = session.meta["start"]
    assert (start["lat"], start["lon"], start["t"]) == (posi[0, 1], posi[0, 2], posi[0, 0])
    north = posi[1, 1] - posi[0, 1]
    east = (posi[1, 2] - posi[0, 2]) * np.cos(np.radians(posi[0, 1]))
    assert abs(start["heading_deg"] - np.degrees(np.arctan2(east, north)) % 360) < 0.5
    assert session.meta["device"].endswith("SM-A520F")
    np.testing.assert_array_equal(session.waypoints["t"], posi[:, 0])


def test_network_fixes_are_dropped_and_accuracy_kept(tmp_path):
    path = tmp_path / "net.h5"
    shutil.copy(H5, path)
    with h5py.File(path, "a") as f:
        gnss = f[A520]["gnss"][:]
        gnss[::3, 3] = 0.0
        del f[A520]["gnss"]
        f[A520]["gnss"] = gnss
    session = read_trial(path, A520)
    kept = gnss[gnss[:, 3] != 0]
    np.testing.assert_array_equal(session.gnss["t"], kept[:, 0])
    np.testing.assert_array_equal(session.gnss["accuracy_m"], kept[:, 5])


def test_ipin_bad_inputs(tmp_path):
    with pytest.raises(CurbsideInputError, match="no such trial"):
        read_trial(H5, "TrainingTrial99_repetition01")
    junk = tmp_path / "junk.h5"
    junk.write_text("not hdf5")
    with pytest.raises(CurbsideInputError, match="not a readable HDF5"):
        list_trials(junk)
    empty = tmp_path / "empty.h5"
    with h5py.File(empty, "w") as f:
        f.create_group("trial").create_dataset("acce", data=np.zeros((3, 4)))
    with pytest.raises(CurbsideInputError, match="no trial groups"):
        list_trials(empty)
    with pytest.raises(CurbsideInputError, match="no such file"):
        list_trials(tmp_path / "missing.h5")


# --- the dispatcher --------------------------------------------------------------------------------


def test_read_any_dispatches_and_requires_a_trial_name(tmp_path):
    assert read_any(f"{H5}::TrainingTrial23_repetition03").name == "TrainingTrial23_repetition03"
    with pytest.raises(CurbsideInputError, match="holds 2 trials"):
        read_any(H5)
    assert detect_format(SESSIONS / "walk.gpx") == "gpx"
    assert detect_format(SESSIONS / "sensorlogger-ios.zip") == "sensorlogger"
    assert detect_format(SESSIONS / "sensorlogger-android") == "sensorlogger"
    other = tmp_path / "track.txt"
    other.write_text("x")
    with pytest.raises(CurbsideInputError, match="unknown format"):
        read_any(other)
    with pytest.raises(CurbsideInputError, match="no such file"):
        read_any(tmp_path / "nothing.gpx")
    (tmp_path / "empty").mkdir()
    with pytest.raises(CurbsideInputError, match="neither a session folder"):
        read_any(tmp_path / "empty")


def test_converted_session_round_trips_through_the_spec_folder(tmp_path):
    session = read_any(f"{H5}::{G930}")
    write_session(session, tmp_path / "s")
    back = read_any(tmp_path / "s")
    for kind, table in session.tables().items():
        np.testing.assert_allclose(getattr(back, kind).to_numpy(), table.to_numpy(), rtol=1e-9)
    assert back.meta == session.meta


# --- Sensor Logger -----------------------------------------------------------------------------------


@pytest.mark.parametrize("export", ["sensorlogger-android", "sensorlogger-ios.zip"])
def test_sensorlogger_export_reproduces_the_recording(export):
    """Both platform conventions decode to the IPIN recording they were made from (make_fixtures.py)."""
    session = read_any(SESSIONS / export)
    ref = read_trial(H5, A520).imu
    ref = ref.set_index((ref["t"] - 60.0).round(4))
    imu = session.imu
    assert len(imu) > 200
    match = ref.loc[imu["t"].round(4)]
    np.testing.assert_allclose(imu[["ax", "ay", "az"]], match[["ax", "ay", "az"]], atol=1e-5)
    np.testing.assert_allclose(imu[["gx", "gy", "gz"]], match[["gx", "gy", "gz"]], atol=1e-5)
    mine = Rotation.from_quat(imu[["qx", "qy", "qz", "qw"]].to_numpy())
    theirs = Rotation.from_quat(match[["qx", "qy", "qz", "qw"]].to_numpy())
    assert np.degrees((mine * theirs.inv()).magnitude()).max() < 0.01
    assert session.meta["platform"] == ("ios" if export.endswith("zip") else "android")
    assert session.meta["t0_unix_s"] == pytest.approx(1.7e9, abs=1e-3)


def test_sensorlogger_repairs_location_and_reads_tap_waypoints():
    session = read_sensorlogger(SESSIONS / "sensorlogger-android")
    raw = pd.read_csv(SESSIONS / "sensorlogger-android" / "Location.csv")
    assert len(session.gnss) == len(raw) - 1  # one exact duplicate dropped
    assert session.gnss["t"].is_monotonic_increasing
    expected = [[8.05, 49.4612756, 11.11098835]]
    np.testing.assert_allclose(session.waypoints[["t", "lat", "lon"]].to_numpy(), expected)
    assert session.meta["annotations"] == [{"t": 9.0, "text": "corner"}]


def test_sensorlogger_route_gives_every_tap_a_position(tmp_path):
    route = tmp_path / "route.csv"
    route.write_text("lat,lon\n49.1,11.1\n49.2,11.2\n")
    session = read_any(SESSIONS / "sensorlogger-android", route=route)
    np.testing.assert_allclose(session.waypoints["lat"], [49.1, 49.2])
    route.write_text("lat,lon\n49.1,11.1\n")
    with pytest.raises(CurbsideInputError, match="1 route points for 2 taps"):
        read_any(SESSIONS / "sensorlogger-android", route=route)
    with pytest.raises(CurbsideInputError, match="Sensor Logger exports only"):
        read_any(SESSIONS / "walk.gpx", route=route)


def _android_copy(tmp_path: Path) -> Path:
    folder = tmp_path / "export"
    shutil.copytree(SESSIONS / "sensorlogger-android", folder)
    return folder


def test_sensorlogger_accelerometer_without_gravity_is_refused(tmp_path):
    folder = _android_copy(tmp_path)
    (folder / "TotalAcceleration.csv").unlink()
    with pytest.raises(CurbsideInputError, match="gravity must be included"):
        read_sensorlogger(folder)


def test_sensorlogger_bad_files(tmp_path):
    folder = _android_copy(tmp_path)
    loc = pd.read_csv(folder / "Location.csv").drop(columns=["horizontalAccuracy"])
    loc.to_csv(folder / "Location.csv", index=False)
    with pytest.raises(CurbsideInputError, match=r"Location.csv: missing column\(s\) \['accuracy_m'\]"):
        read_sensorlogger(folder)
    (folder / "Location.csv").write_text("")
    with pytest.raises(CurbsideInputError, match="malformed CSV"):
        read_sensorlogger(folder)
    bad_zip = tmp_path / "broken.zip"
    bad_zip.write_bytes(b"PK\x03\x04 this is not a zip")
    with pytest.raises(CurbsideInputError, match="unreadable zip"):
        read_any(bad_zip)
    empty_zip = tmp_path / "empty.zip"
    with zipfile.ZipFile(empty_zip, "w") as zf:
        zf.writestr("notes.txt", "hello")
    with pytest.raises(CurbsideInputError, match="not a Sensor Logger export"):
        read_any(empty_zip)


def test_sensorlogger_orientation_inconsistent_with_gravity_is_refused(tmp_path):
    folder = _android_copy(tmp_path)
    q = pd.read_csv(folder / "Orientation.csv")
    # A quarter turn about x puts gravity horizontal: neither sign nor direction fixes that.
    quarter_turn = Rotation.from_euler("x", 90, degrees=True)
    q[["qx", "qy", "qz", "qw"]] = (quarter_turn * Rotation.from_quat(q[["qx", "qy", "qz", "qw"]])).as_quat()
    q.to_csv(folder / "Orientation.csv", index=False)
    with pytest.raises(CurbsideInputError, match="disagree on gravity"):
        read_sensorlogger(folder)


# --- GPX -----------------------------------------------------------------------------------------------


def test_gpx_fixes_accuracy_from_hdop_and_timed_waypoints():
    session = read_gpx(SESSIONS / "walk.gpx")
    gnss = session.gnss
    np.testing.assert_array_equal(gnss["t"], [0, 10, 20, 30, 40, 50])  # sorted, duplicate and untimed dropped
    np.testing.assert_allclose(gnss["accuracy_m"].iloc[[0, 1, 2, 3, 5]], [6.0, 7.0, 8.0, 10.0, 4.5])
    assert np.isnan(gnss["accuracy_m"].iat[4])  # no <hdop>: invalid fix
    np.testing.assert_array_equal(session.waypoints["t"], [0, 50])
    assert session.imu is None
    assert session.meta["t0_utc"].startswith("2026-03-01T18:00:00")


def test_gpx_bad_inputs(tmp_path):
    bad = tmp_path / "bad.gpx"
    bad.write_text("<gpx><trk><trkseg><trkpt lat='1' lon='2'>")
    with pytest.raises(CurbsideInputError, match="malformed XML"):
        read_gpx(bad)
    bad.write_text("<gpx><trk><trkseg><trkpt lat='1' lon='2'/></trkseg></trk></gpx>")
    with pytest.raises(CurbsideInputError, match="no <trkpt> with a <time>"):
        read_gpx(bad)
    bad.write_text("<kml/>")
    with pytest.raises(CurbsideInputError, match="not <gpx>"):
        read_gpx(bad)
    bad.write_text("<gpx><trk><trkseg><trkpt lat='95' lon='2'><time>2026-01-01T00:00:00Z</time>"
                   "</trkpt></trkseg></trk></gpx>")
    with pytest.raises(CurbsideInputError, match="lat/lon outside"):
        read_any(bad)


# --- shared helpers -------------------------------------------------------------------------------------


def test_accelerometer_units_detected():
    flat = pd.DataFrame({"ax": [0.0, 0.01], "ay": [0.0, 0.0], "az": [1.0, 0.99]})
    converted = accelerometer_ms2(flat, "acc.csv")
    np.testing.assert_allclose(converted["az"], [STANDARD_GRAVITY, 0.99 * STANDARD_GRAVITY])
    ms2 = flat * STANDARD_GRAVITY
    np.testing.assert_allclose(accelerometer_ms2(ms2, "acc.csv"), ms2)
    with pytest.raises(CurbsideInputError, match="neither"):
        accelerometer_ms2(flat * 0.05, "acc.csv")


def test_tidy_table_repairs_order_duplicates_and_nan_but_not_conflicts():
    table = pd.DataFrame({"t": [2.0, 1.0, 1.0, 3.0, np.nan], "v": [20.0, 10.0, 10.0, np.nan, 5.0]})
    out = tidy_table(table, "x.csv", ["t", "v"])
    np.testing.assert_array_equal(out.to_numpy(), [[1.0, 10.0], [2.0, 20.0]])
    conflict = pd.DataFrame({"t": [1.0, 1.0], "v": [1.0, 2.0]})
    with pytest.raises(CurbsideInputError, match="conflicting rows share timestamp"):
        tidy_table(conflict, "x.csv", ["t", "v"])
    with pytest.raises(CurbsideInputError, match="no usable rows"):
        tidy_table(pd.DataFrame({"t": [np.nan], "v": [1.0]}), "x.csv", ["t", "v"])


def test_quaternion_interpolation_ignores_the_sign_of_q():
    a = Rotation.from_euler("z", 0, degrees=True).as_quat()
    b = -Rotation.from_euler("z", 20, degrees=True).as_quat()  # same rotation as +q, opposite hemisphere
    mid = interp_quaternions(np.array([0.5]), np.array([0.0, 1.0]), np.vstack([a, b]))
    assert Rotation.from_quat(mid).as_euler("zyx", degrees=True)[0, 0] == pytest.approx(10.0, abs=0.05)


def test_spec_folder_is_read_as_is(tmp_path):
    session = read_gpx(SESSIONS / "walk.gpx")
    write_session(session, tmp_path / "gpx")
    assert detect_format(tmp_path / "gpx") == "spec"
    back = read_any(tmp_path / "gpx")
    pd.testing.assert_frame_equal(back.gnss, read_session(tmp_path / "gpx").gnss)


def test_single_trial_h5_needs_no_trial_name(tmp_path):
    path = tmp_path / "one.h5"
    shutil.copy(H5, path)
    with h5py.File(path, "a") as f:
        del f[A520]
    assert read_any(path).name == "TrainingTrial23_repetition03"
