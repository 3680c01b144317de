"""Google GnssLogger / GPSTest ``.txt`` logs (``readers/gnsslogger.py``): frame, clock, fixes, bad input.

The synthetic logs are written by :func:`write_log` in GnssLogger v3's exact layout from a known attitude
(``SensorManager.getOrientation``'s angles computed from it with Android's formulas); the real ones are
trimmed gnss_lib_py logs (``tests/data/gnsslogger/README.md``).
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import pytest
from convert_checks import assert_spoiled_log_refused
from scipy.spatial.transform import Rotation

from curbside.cli.localize import main
from curbside.errors import CurbsideInputError
from curbside.localize.readers import detect_format, read_any
from curbside.localize.readers.gnsslogger import _quaternions, read_gnsslogger
from curbside.localize.session import read_session

REAL = Path(__file__).parent / "data" / "gnsslogger"
G = 9.80665
BOOT_UTC_MS = 1_699_400_000_000  # the phone's boot time, UTC ms
T0_NS = 16_118_836_475_732  # elapsedRealtimeNanos of the first sensor row
MAG_WORLD_UT = np.array([0.0, 20.0, -40.0])  # magnetic field in ENU (north and down)

HEADERS = {
    "Raw": "utcTimeMillis,TimeNanos,LeapSecond,Svid,Cn0DbHz,ConstellationType,ChipsetElapsedRealtimeNanos",
    "UncalAccel": "utcTimeMillis,elapsedRealtimeNanos,UncalAccelXMps2,UncalAccelYMps2,UncalAccelZMps2,"
                  "BiasXMps2,BiasYMps2,BiasZMps2",
    "Accel": "utcTimeMillis,elapsedRealtimeNanos,AccelXMps2,AccelYMps2,AccelZMps2",
    "UncalGyro": "utcTimeMillis,elapsedRealtimeNanos,UncalGyroXRadPerSec,UncalGyroYRadPerSec,"
                 "UncalGyroZRadPerSec,DriftXRadPerSec,DriftYRadPerSec,DriftZRadPerSec",
    "Gyro": "utcTimeMillis,elapsedRealtimeNanos,GyroXRadPerSec,GyroYRadPerSec,GyroZRadPerSec",
    "Mag": "utcTimeMillis,elapsedRealtimeNanos,MagXMicroT,MagYMicroT,MagZMicroT",
    "OrientationDeg": "utcTimeMillis,elapsedRealtimeNanos,yawDeg,rollDeg,pitchDeg",
    "Fix": "Provider,LatitudeDegrees,LongitudeDegrees,AltitudeMeters,SpeedMps,AccuracyMeters,BearingDegrees,"
           "UnixTimeMillis,SpeedAccuracyMps,BearingAccuracyDegrees,elapsedRealtimeNanos,VerticalAccuracyMeters,"
           "MockLocation,NumberOfUsedSignals,VerticalSpeedAccuracyMps,SolutionType",
    "Nav": "Svid,Type,Status,MessageId,Sub-messageId,Data(Bytes)",
    "Status": "UnixTimeMillis,SignalCount,SignalIndex,ConstellationType,Svid,Cn0DbHz",
}
#: GnssLogger 2's Fix header: no elapsedRealtimeNanos, short names.
V2_FIX = "Provider,Latitude,Longitude,Altitude,Speed,Accuracy,(UTC)TimeInMs"


def android_orientation(rot: Rotation) -> np.ndarray:
    """``SensorManager.getOrientation`` (azimuth, pitch, roll in degrees) of device-to-ENU rotations."""
    m = rot.as_matrix()
    azimuth = np.arctan2(m[:, 0, 1], m[:, 1, 1])
    pitch = np.arcsin(-m[:, 2, 1])
    roll = np.arctan2(-m[:, 2, 0], m[:, 2, 2])
    return np.degrees(np.column_stack([azimuth, pitch, roll]))


def truth(duration_s: float = 20.0, rate_hz: float = 50.0) -> tuple[np.ndarray, Rotation]:
    """Sample times (s) and a phone held in front of a walker, turning and swaying (device to ENU)."""
    t = np.arange(0.0, duration_s, 1.0 / rate_hz)
    yaw = 40.0 + 3.0 * t  # a slow left turn: getOrientation's azimuth falls
    pitch, roll = -35.0 + 8.0 * np.sin(1.3 * t), 6.0 * np.sin(0.7 * t + 0.4)
    return t, Rotation.from_euler("ZXY", np.column_stack([yaw, -pitch, roll]), degrees=True)


def _csv(values) -> str:
    return ",".join(v if isinstance(v, str) else repr(float(v)) if not float(v).is_integer() or abs(v) < 1e12
                    else str(int(v)) for v in values)


def write_log(path: Path, *, sensors=("Accel", "Gyro", "Mag", "OrientationDeg"), fixes: bool = True,
              orientation: str = "labelled", fix_header: str = "v3", bias: float = 0.0,
              headers: dict[str, str] | None = None) -> tuple[np.ndarray, Rotation]:
    """Write a GnssLogger v3 log of :func:`truth`; return its times and attitude.

    ``orientation``: ``labelled`` (GnssLogger: yaw, roll, pitch under yawDeg,rollDeg,pitchDeg), ``gpstest``
    (azimuth, pitch, roll under the same header), ``whole`` (whole degrees). ``bias``: added to the
    uncalibrated rows' readings and logged as their bias (drift). ``headers`` replaces header lines.
    """
    headers = {**HEADERS, **(headers or {})}
    if fix_header == "v2":
        headers["Fix"] = V2_FIX
    t, rot = truth()
    ns = T0_NS + np.round(t * 1e9).astype(np.int64)
    utc = BOOT_UTC_MS + ns // 1_000_000
    acc = rot.inv().apply([0.0, 0.0, G])
    gyro = (rot[:-1].inv() * rot[1:]).as_rotvec() * 50.0
    gyro = np.vstack([gyro, gyro[-1]])
    mag = rot.inv().apply(MAG_WORLD_UT)
    az, pitch, roll = android_orientation(rot).T
    az = np.mod(az, 360.0)
    columns = {"labelled": (az, roll, pitch), "gpstest": (az, pitch, roll),
               "whole": (np.round(az), np.round(roll), np.round(pitch))}[orientation]
    values = {"Accel": acc, "Gyro": gyro, "Mag": mag, "OrientationDeg": np.column_stack(columns),
              "UncalAccel": np.hstack([acc + bias, np.full_like(acc, bias)]),
              "UncalGyro": np.hstack([gyro + bias, np.full_like(gyro, bias)])}
    lines = ["#", "# Header Description:", "#",
             "# Version: v3.0.6.4 Platform: 14 Manufacturer: Google Model: Pixel 7", "#"]
    for kind, fields in headers.items():
        lines += [f"# {kind},{fields}", "#"]
    lines.append(f"Raw,{utc[0]},61090000000,18,4,28.9,1,{ns[0]}")
    lines.append("Nav,3,769,1,-1,14,116,5,-126,11,42")  # variable length by design: never checked
    for i in range(len(t)):
        for kind in sensors:
            order = headers[kind].split(",")
            row = dict(zip(HEADERS[kind].split(",")[2:], values[kind][i], strict=True))
            row.update(utcTimeMillis=utc[i], elapsedRealtimeNanos=ns[i])
            lines.append(f"{kind}," + _csv([row[f] for f in order]))
        if fixes and i % 50 == 10:
            lines += _fix_rows(i, t[i], ns[i], utc[i], headers["Fix"])
    path.write_text("\n".join(lines) + "\n")
    return t, rot


def _fix_rows(i: int, t_s: float, ns: int, utc_ms: int, header: str) -> list[str]:
    """A GPS fix, the FLP fix passing it on (same stamp), a network fix, and an FLP fix of its own."""
    lat, lon = 37.4265 + 1e-5 * t_s, -122.1737 + 2e-5 * t_s
    out = []
    for provider, dt_ns, acc_m in (("GPS", 0, 4.2), ("FLP", 0, 4.1), ("NLP", 3e8, 18.0), ("FLP", 5e8, 6.0)):
        utc = utc_ms + dt_ns / 1e6
        base = {"Provider": provider, "LatitudeDegrees": lat, "LongitudeDegrees": lon,
                "AccuracyMeters": acc_m, "UnixTimeMillis": utc, "elapsedRealtimeNanos": ns + dt_ns}
        base.update(Latitude=lat, Longitude=lon, Accuracy=acc_m, **{"(UTC)TimeInMs": utc})
        if provider == "NLP":
            base.update(LatitudeDegrees=lat + 1e-3, Latitude=lat + 1e-3)
        out.append("Fix," + _csv([base.get(f, "") for f in header.split(",")]))
    return out


def angle_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Angle (deg) between rotations given as x,y,z,w quaternions."""
    return np.degrees((Rotation.from_quat(a).inv() * Rotation.from_quat(b)).magnitude())


def test_quaternion_is_the_exact_inverse_of_get_orientation():
    rot = Rotation.random(5000, random_state=53)
    az, pitch, roll = android_orientation(rot).T
    back = Rotation.from_quat(_quaternions(az, pitch, roll))
    np.testing.assert_allclose(back.as_matrix(), rot.as_matrix(), atol=1e-9)


def test_reads_a_log_in_the_enu_frame_on_one_clock(tmp_path, caplog):
    path = tmp_path / "gnss_log_2024_05_01_10_00_00.txt"
    t, rot = write_log(path)
    assert detect_format(path) == "gnsslogger"
    with caplog.at_level(logging.INFO):
        session = read_any(path)
    imu = session.imu
    assert list(imu.columns) == ["t", "ax", "ay", "az", "gx", "gy", "gz", "qx", "qy", "qz", "qw"]
    np.testing.assert_allclose(imu["t"], t, atol=1e-9)
    quat = imu[["qx", "qy", "qz", "qw"]].to_numpy()
    assert angle_deg(quat, rot.as_quat()).max() < 1e-4
    world = Rotation.from_quat(quat).apply(imu[["ax", "ay", "az"]].to_numpy(dtype=float, copy=True))
    np.testing.assert_allclose(world, np.tile([0.0, 0.0, G], (len(world), 1)), atol=1e-6)
    assert session.meta["magnetic_north_deg"] == 0.0
    # the GPS fixes on the sensors' clock; the FLP ones (which pass GNSS on) and the NLP ones dropped
    gnss = session.gnss
    assert len(gnss) == 20 and np.allclose(gnss["t"], t[10::50]) and (gnss["accuracy_m"] == 4.2).all()
    assert "dropped 20 network (NLP) fix(es)" in caplog.text
    assert "kept the 20 GPS fixes and dropped 40 FLP fix(es)" in caplog.text
    meta = session.meta
    assert meta["platform"] == "android" and meta["device"] == "Google Pixel 7"
    assert meta["app_version"] == "v3.0.6.4" and meta["source"]["format"] == "gnsslogger"
    assert meta["t0_unix_s"] == pytest.approx((BOOT_UTC_MS + T0_NS / 1e6) / 1e3, abs=1e-3)


def test_gpstest_pitch_roll_order_is_found_from_gravity(tmp_path, caplog):
    t, rot = write_log(tmp_path / "gpstest.txt", orientation="gpstest")
    with caplog.at_level(logging.WARNING):
        session = read_any(tmp_path / "gpstest.txt")
    assert angle_deg(session.imu[["qx", "qy", "qz", "qw"]].to_numpy(), rot.as_quat()).max() < 1e-4
    assert "hold pitch and roll (GPSTest's order)" in caplog.text


def test_whole_degrees_of_older_versions(tmp_path):
    t, rot = write_log(tmp_path / "old.txt", orientation="whole")
    session = read_any(tmp_path / "old.txt")
    assert angle_deg(session.imu[["qx", "qy", "qz", "qw"]].to_numpy(), rot.as_quat()).max() < 1.0


def test_uncalibrated_rows_stand_in_less_their_bias(tmp_path, caplog):
    write_log(tmp_path / "cal.txt")
    write_log(tmp_path / "uncal.txt", sensors=("UncalAccel", "UncalGyro", "OrientationDeg"), bias=0.05)
    with caplog.at_level(logging.WARNING):
        uncal = read_any(tmp_path / "uncal.txt").imu
    cal = read_any(tmp_path / "cal.txt").imu
    np.testing.assert_allclose(uncal.to_numpy(), cal.to_numpy(), atol=1e-9)
    assert "no Gyro rows; UncalGyro rows less their logged drift used instead" in caplog.text


def test_fields_are_read_by_name_not_position(tmp_path):
    write_log(tmp_path / "plain.txt")
    shuffled = {kind: ",".join(np.random.default_rng(5).permutation(HEADERS[kind].split(",")))
                for kind in ("Accel", "Gyro", "OrientationDeg", "Fix")}
    write_log(tmp_path / "shuffled.txt", headers=shuffled)
    a, b = read_any(tmp_path / "plain.txt"), read_any(tmp_path / "shuffled.txt")
    for kind in ("imu", "gnss"):
        np.testing.assert_array_equal(getattr(a, kind).to_numpy(), getattr(b, kind).to_numpy())


def test_gnsslogger_2_fix_header_goes_on_the_sensor_clock(tmp_path):
    write_log(tmp_path / "v3.txt")
    write_log(tmp_path / "v2.txt", fix_header="v2")
    v2, v3 = read_any(tmp_path / "v2.txt").gnss, read_any(tmp_path / "v3.txt").gnss
    np.testing.assert_allclose(v2.to_numpy(), v3.to_numpy(), atol=2e-3)  # UTC ms vs ns since boot


def test_gnss_only_and_imu_only_logs(tmp_path):
    write_log(tmp_path / "fixes.txt", sensors=())
    write_log(tmp_path / "imu.txt", fixes=False)
    fixes, imu = read_any(tmp_path / "fixes.txt"), read_any(tmp_path / "imu.txt")
    assert fixes.imu is None and len(fixes.gnss) == 20 and fixes.gnss["t"].iat[0] == 0.0
    assert imu.gnss is None and len(imu.imu) == 1000


def test_real_pixel7_logs():
    session = read_any(REAL / "pixel7-fixes-trimmed.txt")
    assert session.imu is None and len(session.gnss) == 5  # the 5 GPS fixes; 5 FLP and 3 NLP dropped
    assert session.meta["device"] == "Google Pixel 7" and session.meta["android_version"] == "14"
    assert session.gnss["t"].is_monotonic_increasing and session.gnss["accuracy_m"].max() < 10
    with pytest.raises(CurbsideInputError, match="neither a usable IMU .* nor a GPS or FLP Fix row"):
        read_any(REAL / "pixel7-all-sensors.txt")  # one sample of each sensor, no Fix


def test_real_pixel4_gnsslogger_2_log(caplog):
    """GnssLogger v2.0.4.2: Fix rows without elapsedRealtimeNanos, an NLP fix before the first sensor row, a
    GPS and an FLP fix of one UnixTimeMillis, and a Mag header naming MagYmicroT twice."""
    with caplog.at_level(logging.INFO):
        session = read_any(REAL / "pixel4-v2-trimmed.txt")
    assert session.imu["t"].iat[0] < 0.001  # t = 0 at the first sensor row, not at the dropped NLP fix
    first_sensor_utc_ms = 1589494244844  # its Gyro row; the first fix (FLP) at 1589494246000
    np.testing.assert_allclose(session.gnss["t"], np.array([2.156, 3.156]), atol=2e-3)  # its two GPS fixes
    assert session.meta["t0_unix_s"] == pytest.approx(first_sensor_utc_ms / 1e3, abs=2e-3)
    assert session.meta["device"] == "Google Pixel 4" and session.meta["app_version"] == "v2.0.4.2"
    assert "kept the 2 GPS fixes and dropped 2 FLP fix(es)" in caplog.text


def test_a_log_without_gps_fixes_keeps_the_fused_ones(tmp_path, caplog):
    t, _ = write_log(tmp_path / "log.txt")
    _edit(tmp_path / "log.txt", "Fix,GPS,", "Fix,NLP,", count=-1)
    with caplog.at_level(logging.INFO):
        gnss = read_any(tmp_path / "log.txt").gnss
    assert len(gnss) == 40 and np.allclose(gnss["t"].iloc[1::2], t[10::50] + 0.5)
    assert "FLP fix(es)" not in caplog.text


def test_a_magnetometer_header_it_cannot_read_only_skips_the_north_check(tmp_path, caplog):
    write_log(tmp_path / "log.txt")
    _edit(tmp_path / "log.txt", "MagXMicroT,MagYMicroT,MagZMicroT", "MagXmicroT,MagYmicroT,MagYmicroT")
    with caplog.at_level(logging.INFO):
        session = read_any(tmp_path / "log.txt")
    assert "magnetic_north_deg" not in session.meta and "north not checked" in caplog.text


def test_convert_writes_a_session_folder(tmp_path):
    write_log(tmp_path / "walk.txt")
    dst = tmp_path / "out"
    assert main(["convert", str(tmp_path / "walk.txt"), str(dst)]) == 0
    session = read_session(dst)
    assert set(session.tables()) == {"imu", "gnss"}
    assert session.meta["source"] == {"format": "gnsslogger", "file": "walk.txt"}


def _edit(path: Path, old: str, new: str, count: int = 1) -> None:
    text = path.read_text()
    assert old in text
    path.write_text(text.replace(old, new, count))


def _rows(path: Path, kind: str, change) -> None:
    """Rewrite the fields of every ``kind`` row with ``change(fields, row index)``."""
    lines = path.read_text().splitlines()
    rows = [i for i, line in enumerate(lines) if line.startswith(f"{kind},")]
    for n, i in enumerate(rows):
        lines[i] = ",".join(change(lines[i].split(","), n))
    path.write_text("\n".join(lines) + "\n")


def _upside_down(path: Path) -> None:
    _rows(path, "Accel", lambda f, n: [*f[:3], *(str(-float(v)) for v in f[3:])])


def _on_another_clock(path: Path) -> None:
    clock = HEADERS["Fix"].split(",").index("elapsedRealtimeNanos") + 1
    _rows(path, "Fix", lambda f, n: [*f[:clock], str(int(f[clock]) + 900_000_000_000), *f[clock + 1:]])


def _text_in_gyro(path: Path) -> None:
    _rows(path, "Gyro", lambda f, n: [*f[:4], "abc", *f[5:]] if n == 3 else f)


BAD = {
    "no header": (lambda p: p.write_text("Accel,1,2,0.1,0.2,9.8\nGyro,1,2,0,0,0\n"),
                  "does not start with GnssLogger's header lines"),
    "field count": (lambda p: _edit(p, "\nAccel,", "\nAccel,1,"), "Accel row with 6 fields where its header"),
    "nothing read": (lambda p: p.write_text("# Raw,utcTimeMillis,TimeNanos\nRaw,1,2\nRaw,3,4\n"),
                     "no Fix and no sensor (Accel, Gyro, OrientationDeg...) rows (it has Raw rows"),
    "text in a number": (_text_in_gyro, "non-numeric value 'abc' in field 'GyroYRadPerSec' of the Gyro row"),
    "text in a reading": (lambda p: _edit(p, ",-122.", ",west-122."), "non-numeric value 'west-122."),
    "no header for a row type": (lambda p: _edit(p, "# Gyro,", "# Gyroscope,"),
                                 "Gyro rows, but no '# Gyro,...'"),
    "missing field": (lambda p: _edit(p, "AccelYMps2,AccelZMps2\n", "AccelYMps2,AccelWMps2\n"),
                      "names no AccelZMps2"),
    "gravity": (_upside_down, "OrientationDeg and the accelerometer disagree on gravity"),
    "two clocks": (_on_another_clock, "Fix rows and Accel rows do not overlap in time"),
}


@pytest.mark.parametrize("case", list(BAD))
def test_bad_input_is_one_line_exit_2_nothing_written(tmp_path, capsys, case):
    assert_spoiled_log_refused(tmp_path, capsys, write_log, *BAD[case])


def test_reader_refuses_a_log_without_header_lines(tmp_path):
    src = tmp_path / "rows.txt"
    src.write_text("Accel,1,2,0.1,0.2,9.8\n")
    with pytest.raises(CurbsideInputError, match="no '# TYPE,field,...' header lines"):
        read_gnsslogger(src)


def session_to_gnsslogger(session, path: Path, boot_ns: int = 9_000_000_000_000) -> None:
    """Write a session (``imu`` with quaternion, ``gnss``) as a GnssLogger v3 log: Accel, Gyro and
    OrientationDeg rows at the IMU times (getOrientation of the quaternion), a GPS Fix row per fix."""
    imu, gnss = session.imu, session.gnss
    ns = boot_ns + np.round(imu["t"].to_numpy() * 1e9).astype(np.int64)
    az, pitch, roll = android_orientation(Rotation.from_quat(imu[["qx", "qy", "qz", "qw"]].to_numpy())).T
    lines = ["# Header Description:", "# Version: v3.0.6.4 Platform: 7 Manufacturer: samsung Model: SM-A520F"]
    lines += [f"# {kind},{HEADERS[kind]}" for kind in ("Accel", "Gyro", "OrientationDeg", "Fix")]
    for i, n in enumerate(ns):
        utc = BOOT_UTC_MS + n // 1_000_000
        lines.append(f"Accel,{utc},{n}," + _csv(imu[["ax", "ay", "az"]].iloc[i]))
        lines.append(f"Gyro,{utc},{n}," + _csv(imu[["gx", "gy", "gz"]].iloc[i]))
        lines.append(f"OrientationDeg,{utc},{n}," + _csv([np.mod(az[i], 360.0), roll[i], pitch[i]]))
    for fix in gnss.itertuples():
        n = boot_ns + round(fix.t * 1e9)
        utc = BOOT_UTC_MS + n // 1_000_000
        lines.append(f"Fix,GPS,{fix.lat!r},{fix.lon!r},,,{fix.accuracy_m!r},,{utc},,,{n},,0,,,")
    path.write_text("\n".join(lines) + "\n")


def test_a_real_walk_rendered_as_gnsslogger_reads_back(tmp_path):
    h5 = Path(__file__).parent / "data" / "sessions" / "ipin2023-cut.h5"
    ipin = read_any(f"{h5}::TrainingTrial01_repetition01")
    session_to_gnsslogger(ipin, tmp_path / "walk.txt")
    back = read_any(tmp_path / "walk.txt")
    t0 = ipin.imu["t"].iat[0]
    np.testing.assert_allclose(back.imu["t"], ipin.imu["t"] - t0, atol=1e-9)
    cols = ["ax", "ay", "az", "gx", "gy", "gz"]
    np.testing.assert_allclose(back.imu[cols].to_numpy(), ipin.imu[cols].to_numpy(), atol=1e-12)
    quat = ["qx", "qy", "qz", "qw"]
    assert angle_deg(back.imu[quat].to_numpy(), ipin.imu[quat].to_numpy()).max() < 1e-5
    np.testing.assert_allclose(back.gnss["t"], ipin.gnss["t"] - t0, atol=1e-9)
    fix = ["lat", "lon", "accuracy_m"]
    np.testing.assert_array_equal(back.gnss[fix], ipin.gnss[fix])


def test_pdr_without_orientation_rows_says_what_the_log_lacks(tmp_path, capsys):
    write_log(tmp_path / "log.txt", sensors=("Accel", "Gyro"))
    assert main(["convert", str(tmp_path / "log.txt"), str(tmp_path / "out"), "--pdr"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.endswith("this source has none (a GnssLogger or GPSTest log needs OrientationDeg rows)"), err
    assert not (tmp_path / "out").exists()
