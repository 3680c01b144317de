"""Readers: IPIN HDF5, Sensor Logger exports, GPX, the dispatcher, and each kind of bad input."""

from __future__ import annotations

import shutil
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
    single = tmp_path / "combined.csv"
    single.write_text("time,seconds_elapsed\n")
    with pytest.raises(CurbsideInputError, match="single CSV is not a recording"):
        read_any(single)
    with pytest.raises(CurbsideInputError, match="applies to an .h5 file, a .zip or a folder"):
        read_any(f"{SESSIONS / 'walk.gpx'}::x")
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
    doubled = read_gpx(SESSIONS / "walk.gpx", uere_m=10.0).gnss["accuracy_m"]
    np.testing.assert_allclose(doubled.iloc[[0, 5]], [12.0, 9.0])


def test_gpx_routes_and_zones_are_read(tmp_path):
    path = tmp_path / "route.gpx"
    path.write_text(
        "<gpx version='1.0'><rte><rtept lat='1' lon='2'><time>2026-01-01T00:00:00</time></rtept>"
        "<rtept lat='1.001' lon='2'><time>2026-01-01T01:00:05+01:00</time><hdop>2</hdop></rtept></rte></gpx>"
    )
    session = read_gpx(path)
    np.testing.assert_array_equal(session.gnss["t"], [0.0, 5.0])  # no zone = UTC; +01:00 converted
    assert session.gnss["accuracy_m"].iat[1] == 10.0


@pytest.mark.parametrize(
    ("content", "message"),
    [
        ("<gpx><trk><trkseg><trkpt lat='1' lon='2'>", "not a readable GPX file"),
        ("<gpx><trk><trkseg><trkpt lat='1' lon='2'/></trkseg></trk></gpx>", "no <trkpt> with a <time>"),
        ("<kml/>", "no track, route or waypoint"),
        ("<gpx><trk><trkseg><trkpt lat='north' lon='2'/></trkseg></trk></gpx>", "not a readable GPX file"),
        ("\udcff", "not a readable GPX file"),
    ],
)
def test_gpx_bad_inputs(tmp_path, content, message):
    bad = tmp_path / "bad.gpx"
    bad.write_bytes(content.encode("utf-8", errors="surrogateescape"))
    with pytest.raises(CurbsideInputError, match=message):
        read_gpx(bad)


def test_gpx_latitude_out_of_range_is_refused(tmp_path):
    bad = tmp_path / "bad.gpx"
    bad.write_text("<gpx><trk><trkseg><trkpt lat='95' lon='2'><time>2026-01-01T00:00:00Z</time>"
                   "</trkpt></trkseg></trk></gpx>")
    with pytest.raises(CurbsideInputError, match=r"'lat' = 95.0 at point 1 is outside -90\.\.90"):
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
