"""GetSensorData text logfiles of the IPIN competitions (``readers/getsensordata.py``).

The real head is the first 20 KB of an IPIN 2023 training logfile (``tests/data/getsensordata/README.md``);
the synthetic logs are written by :func:`write_log` in the app's exact 2.21 (or 2.0) layout from a known
attitude, with duplicated GNSS lines, a network fix and surveyed POSI points.
"""

from __future__ import annotations

import json
import logging
from pathlib import Path

import numpy as np
import pytest
from convert_checks import assert_spoiled_log_refused
from scipy.spatial.transform import Rotation

from curbside.cli.localize import main
from curbside.errors import CurbsideInputError
from curbside.localize.readers import detect_format, read_any
from curbside.localize.readers.getsensordata import read_getsensordata

REAL = Path(__file__).parent / "data" / "getsensordata" / "IPIN2023_T3_TrainingTrial01_repetition01_head.txt"
H5 = Path(__file__).parents[2] / "shared" / "data" / "ipin2023" / "ipin2023-t3.h5"
HEADER = REAL.read_text().split("\n\n", 1)[0] + "\n\n"
#: App 2.0 (2016) names the rotation vector RotVecX() where 2.21 writes Quat(2).
V20 = ("Quat(2);Quat(3);Quat(4)", "RotVecX();RotVecY();RotVecZ()")
YAW_DEG = 30.0  # the phone's heading: 30 deg counter-clockwise from North (AHRS YawZ convention)
LAT0, LON0 = 49.4613, 11.1110
POSI = [(5.0, LAT0, LON0, 0), (10.0, LAT0 + 0.0002, LON0, -1), (15.0, LAT0 + 0.0002, LON0 + 0.0003, 0)]


def write_log(path: Path, header: str = HEADER, duration_s: float = 20.0, imu: bool = True,
              extra_ahrs_field: bool = False) -> Rotation:
    """Write a still phone (flat, yawed by :data:`YAW_DEG`) with GNSS and POSI rows; return its attitude."""
    rot = Rotation.from_euler("z", YAW_DEG, degrees=True)
    gravity_device = rot.inv().apply([0.0, 0.0, 9.80665])
    qx, qy, qz, _ = rot.as_quat()
    rows = []
    for k, t in enumerate(np.arange(0.05, duration_s, 0.02)):
        sensor_s = 5000.0 + t
        if imu:
            rows.append((t, f"ACCE;{t:.4f};{sensor_s:.4f};{gravity_device[0]:.5f};{gravity_device[1]:.5f};"
                            f"{gravity_device[2]:.5f};3"))
            rows.append((t + 1e-4, f"GYRO;{t + 1e-4:.4f};{sensor_s:.4f};0.00100;-0.00200;0.00300;3"))
            extra = ";7" if extra_ahrs_field else ""
            rows.append((t + 2e-4, f"AHRS;{t + 2e-4:.4f};{sensor_s:.4f};0.000000;0.000000;{YAW_DEG:.6f};"
                                   f"{qx:.8f};{qy:.8f};{qz:.8f}{extra};3"))
        rows.append((t + 3e-4, f"MAGN;{t + 3e-4:.4f};{sensor_s:.4f};-2.10000;-34.14000;-45.42000;0"))
        if k % 50 == 25:  # 1 Hz fixes, each written twice; every 5th a network fix (alt == 0)
            alt = "0.000" if k % 250 == 25 else "346.000"
            fix = f"{1686729678 + t:.4f};{LAT0 + 1e-6 * k:.6f};{LON0:.6f};{alt};79.500;9.0;0.1"
            rows.append((t + 4e-4, f"GNSS;{t + 4e-4:.4f};{fix};22;19"))
            rows.append((t + 9e-3, f"GNSS;{t + 9e-3:.4f};{fix};21;19"))
    rows += [(t, f"POSI;{t:.4f};{i};{lat:.8f};{lon:.8f};{floor};100") for i, (t, lat, lon, floor)
             in enumerate(POSI, 1)]
    rows.append((1.0, "WIFI;1.000;5001.0;SSID2023_0001;20:23:00:00:00:01;2437;-60"))
    rows.append((1.5, "SOUN;1.5000;3093.40;0.09441;73.48"))
    if extra_ahrs_field:
        header = header.replace("Quat(4);Accuracy(int)", "Quat(4);HeadingAccuracy(deg);Accuracy(int)")
    path.write_text(header + "".join(line + "\n" for _, line in sorted(rows)))
    return rot


# --- the real logfile head -------------------------------------------------------------------------------

def test_real_head_is_detected_and_read():
    assert detect_format(REAL) == "getsensordata"
    session = read_any(REAL)
    assert session.name == "TrainingTrial01_repetition01_head"
    assert session.meta["device"] == "samsung SM-A520F"
    assert session.meta["source"] == {"format": "getsensordata-txt", "file": REAL.name,
                                      "app_version": "2.21 July 2021",
                                      "created": "Wed Jun 14 10:00:58 GMT+02:00 2023", "android_api": "26",
                                      "android_version": "8.0.0"}
    # 2 GNSS lines at 0.9633 and 0.9732 s are one fix, at the first line's time
    assert session.gnss[["t", "lat", "lon", "accuracy_m"]].to_numpy().tolist() == [[0.9633, 49.461269,
                                                                                    11.111049, 9.0]]
    assert session.waypoints is None and "start" not in session.meta
    first = session.imu.iloc[0]  # the first ACCE row (0.0542 s) precedes the first AHRS row: dropped
    assert first["t"] == 0.058 and first["ax"] == 0.22505
    norm = np.linalg.norm(session.imu[["qx", "qy", "qz", "qw"]].to_numpy(), axis=1)
    np.testing.assert_allclose(norm, 1.0, atol=1e-6)


@pytest.mark.skipif(not H5.is_file(), reason="needs ../shared/data/ipin2023/ipin2023-t3.h5")
def test_real_head_equals_the_hdf5_trial_on_its_rows():
    head = read_any(REAL).imu
    trial = read_any(f"{H5}::TrainingTrial01_repetition01").imu
    trial = trial[trial["t"] <= head["t"].iloc[-1]]
    assert len(trial) == len(head)
    # float32 in the HDF5 (qw computed there before rounding): below the logged resolution
    np.testing.assert_allclose(head.to_numpy(), trial.to_numpy(), rtol=0, atol=1e-6)


#: Real rows of the same logfile from 61.41 s on (characters 973,000-989,000 of it, verbatim): the trial's
#: first surveyed point and its next GNSS fix, written twice (a UNIX fix time in the SensorTimeStamp field).
REAL_LATER_ROWS = """\
ACCE;61.4111;65154.9565;0.23463;7.51300;6.64870;3
AHRS;61.4114;65154.9565;48.293636;1.134247;-173.737732;0.03136169;-0.40795216;-0.91087222;3
GYRO;61.4147;65154.9654;-0.13683;-0.02810;-0.09468;3
POSI;61.4235;1;49.461316433032;11.110964442580;0;100
GYRO;61.9196;65155.4674;-0.07880;0.02566;-0.07391;3
GNSS;61.9264;1686729739.0000;49.461260;11.111010;346.000;0.000;7.0;0.0;23;19
MAGN;61.9363;65155.4720;-0.60000;-25.14000;-2.52000;3
GYRO;61.9368;65155.4773;-0.07880;-0.03482;-0.07880;3
ACCE;61.9384;65155.4783;-0.08859;7.76440;4.88178;3
AHRS;61.9389;65155.4783;48.399555;0.738756;-178.637100;0.01075501;-0.40981203;-0.91200680;3
GNSS;61.9426;1686729739.0000;49.461260;11.111010;346.000;0.000;7.0;0.0;23;19
"""


def test_real_posi_and_gnss_rows_read_as_the_hdf5_has_them(tmp_path):
    log = tmp_path / "IPIN2023_T3_TrainingTrial01_repetition01.txt"
    log.write_text(REAL.read_text() + REAL_LATER_ROWS)
    session = read_any(log)
    assert session.waypoints[["t", "lat", "lon"]].to_numpy().tolist() == [[61.4235, 49.461316433032,
                                                                           11.11096444258]]
    assert session.meta["waypoint_floors"] == [0]
    assert session.gnss[["t", "lat", "lon", "accuracy_m"]].to_numpy().tolist()[-1] == [61.9264, 49.46126,
                                                                                      11.11101, 7.0]
    assert len(session.gnss) == 2  # each fix written twice is one
    if H5.is_file():
        trial = read_any(f"{H5}::TrainingTrial01_repetition01")
        np.testing.assert_allclose(session.waypoints.iloc[0][["t", "lat", "lon"]].to_numpy(dtype=float),
                                   trial.waypoints.iloc[0][["t", "lat", "lon"]].to_numpy(dtype=float),
                                   rtol=0, atol=1e-6)


# --- synthetic logs: what becomes of each row type -------------------------------------------------------

def test_synthetic_log_makes_the_ipin_session(tmp_path, caplog):
    rot = write_log(tmp_path / "walk.txt")
    with caplog.at_level(logging.INFO):
        session = read_any(tmp_path / "walk.txt")
    q = session.imu[["qx", "qy", "qz", "qw"]].to_numpy()
    np.testing.assert_allclose(np.abs(q @ rot.as_quat()), 1.0, atol=1e-7)  # qw = sqrt(1 - |xyz|^2)
    world = Rotation.from_quat(q).apply(session.imu[["ax", "ay", "az"]].to_numpy(copy=True))
    np.testing.assert_allclose(world[:, 2], 9.80665, atol=1e-4)
    # 20 fixes written twice, 4 of them network fixes (alt == 0): 16 satellite fixes remain
    assert len(session.gnss) == 16 and session.gnss["t"].is_monotonic_increasing
    assert "40 GNSS line(s) make 20 fix(es)" in caplog.text and "dropped 4 network" in caplog.text
    assert session.waypoints.to_numpy().tolist() == [list(p[:3]) for p in POSI]
    assert session.meta["floors"] == [-1, 0] and session.meta["waypoint_floors"] == [0, -1, 0]
    start = session.meta["start"]
    assert (start["lat"], start["lon"], start["t"]) == (LAT0, LON0, 5.0)
    assert start["heading_deg"] == pytest.approx(0.0, abs=1e-6)  # the second POSI is due north


def test_app_2_0_rotation_vector_names_read_alike(tmp_path):
    write_log(tmp_path / "v221.txt")
    old_header = HEADER.replace("Version 2.21 July 2021", "Version 2.0 November 2016").replace(*V20)
    write_log(tmp_path / "v20.txt", header=old_header)
    new, old = read_any(tmp_path / "v221.txt"), read_any(tmp_path / "v20.txt")
    assert new.imu.equals(old.imu) and new.gnss.equals(old.gnss)
    assert old.meta["source"]["app_version"] == "2.0 November 2016"


def test_fields_are_read_by_the_format_line(tmp_path):
    """A format line naming one more AHRS field: the quaternion is still found by name."""
    write_log(tmp_path / "plain.txt")
    write_log(tmp_path / "extra.txt", extra_ahrs_field=True)
    assert read_any(tmp_path / "extra.txt").imu.equals(read_any(tmp_path / "plain.txt").imu)


def test_without_format_lines_the_2_21_layout_is_read(tmp_path):
    write_log(tmp_path / "full.txt")
    bare = HEADER.split("% LogFile Data format:")[0]
    write_log(tmp_path / "bare.txt", header=bare.replace("%\n% Phone", "% Phone") + "\n")
    assert read_any(tmp_path / "bare.txt").imu.equals(read_any(tmp_path / "full.txt").imu)


def test_gnss_only_log_warns_and_has_no_imu(tmp_path, caplog):
    write_log(tmp_path / "gnss.txt", imu=False)
    with caplog.at_level(logging.WARNING):
        session = read_any(tmp_path / "gnss.txt")
    assert session.imu is None and len(session.gnss) == 16
    assert "no ACCE/GYRO rows; the session has no imu.csv" in caplog.text


def test_without_ahrs_rows_the_imu_has_no_quaternion(tmp_path, caplog):
    write_log(tmp_path / "log.txt")
    _edit(tmp_path / "log.txt", "\nAHRS;", "\nXXXX;", count=-1)  # an unknown type: skipped
    with caplog.at_level(logging.WARNING):
        session = read_any(tmp_path / "log.txt")
    assert list(session.imu.columns) == ["t", "ax", "ay", "az", "gx", "gy", "gz"]
    assert "no AHRS rows: the IMU has no orientation" in caplog.text


def test_convert_a_logfile(tmp_path, capsys):
    write_log(tmp_path / "IPIN2024_T3_Trial07.txt")
    dst = tmp_path / "out"
    assert main(["convert", str(tmp_path / "IPIN2024_T3_Trial07.txt"), str(dst)]) == 0
    assert {"imu.csv", "gnss.csv", "waypoints.csv", "meta.json"} <= {p.name for p in dst.iterdir()}
    meta = json.loads((dst / "meta.json").read_text())
    assert meta["start"]["t"] == 5.0 and meta["device"] == "samsung SM-A520F"


# --- bad input: one line naming the file and the line, exit 2, nothing written ---------------------------

def _edit(path: Path, old: str, new: str, count: int = 1) -> None:
    text = path.read_text()
    assert old in text, old
    path.write_text(text.replace(old, new, count))


def _no_imu_no_gnss(path: Path) -> None:
    lines = path.read_text().splitlines(keepends=True)
    path.write_text("".join(line for line in lines if not line.startswith(("ACCE", "GYRO", "AHRS", "GNSS"))))


BAD = {
    "field count": (lambda p: _edit(p, "\nGYRO;0.0501;", "\nGYRO;0.0501;9.9;"),
                    "line 40: GYRO row with 7 fields where its format line (line 15) names 6"),
    "text in a number": (lambda p: _edit(p, ";-0.00200;0.00300;3\nAHRS;0.0702", ";abc;0.00300;3\nAHRS;0.07"
                                         "02"),
                         "non-numeric value 'abc' in field 'Gyr_Y(rad/s)' of a GYRO row"),
    "text in a fix": (lambda p: _edit(p, ";79.500;9.0;", ";79.500;nine;"),
                      "non-numeric value 'nine' in field 'Accuracy(m)' of a GNSS row"),
    "no imu and no gnss": (_no_imu_no_gnss, "no ACCE/GYRO rows and no GNSS rows: nothing to make a session"),
    "format line without a field": (lambda p: _edit(p, "Acc_Z(m/s^2)", "Acc_W(m/s^2)"),
                                    "the format line of the ACCE rows names no Acc_Z(m/s^2) field"),
    "latitude out of range": (lambda p: _edit(p, "POSI;10.0000;2;49.", "POSI;10.0000;2;99."),
                              "'Latitude(degrees)' = 99.4615 at line"),
}


@pytest.mark.parametrize("case", list(BAD))
def test_bad_input_is_one_line_exit_2_nothing_written(tmp_path, capsys, case):
    assert_spoiled_log_refused(tmp_path, capsys, write_log, *BAD[case])


def test_a_txt_of_neither_log_is_refused_naming_both(tmp_path, capsys):
    src = tmp_path / "notes.txt"
    src.write_text("% some MATLAB comment\nACCE;0.1;1.0;0.1;0.2;9.8;3\n")
    assert main(["convert", str(src), str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert "GnssLogger" in err and "% LogFile created by the 'GetSensorData' App" in err


def test_reader_error_names_the_line_of_an_empty_number(tmp_path):
    write_log(tmp_path / "log.txt")
    _edit(tmp_path / "log.txt", "\nACCE;0.0500;", "\nACCE;;")
    session = read_getsensordata(tmp_path / "log.txt")  # a blank cell is a missing value: the row is dropped
    assert session.imu["t"].iloc[0] > 0.05
    message = r"line \d+: ACCE row with 5 fields where its format line \(line 14\) names 6"
    with pytest.raises(CurbsideInputError, match=message):
        _edit(tmp_path / "log.txt", "\nACCE;0.0700;5000.0700;", "\nACCE;0.0700;")
        read_getsensordata(tmp_path / "log.txt")
