"""Sensor Logger exports with files left out, read against the full export they came from.

The standardised iOS fixture (Android's signs) is turned into CoreMotion's North-West-Up frame, as a
real standardised export may be; "full" is that export with every file. Without ``Gravity.csv`` the
gravity-free ``Accelerometer.csv`` gets gravity back from the orientation, which needs the export's
sign: measured on ``AccelerometerUncalibrated.csv`` when there is one, else the platform's (and
``--platform`` names it where the data cannot tell).
"""

from __future__ import annotations

import json
import logging
import zipfile
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from scipy.spatial.transform import Rotation

from curbside.cli.localize import main
from curbside.localize.readers.sensorlogger import logger as reader_logger
from curbside.localize.readers.sensorlogger import read_sensorlogger
from curbside.localize.session import read_session

SESSIONS = Path(__file__).parent / "data" / "sessions"
QUAT = ["qx", "qy", "qz", "qw"]
ACC = ["ax", "ay", "az"]
G = 9.80665


def _export(tmp_path: Path, fixture: str, name: str, *, nwu: bool = False, raw_unit_ms2: float | None = None,
            drop: tuple[str, ...] = (), invert: bool = False) -> Path:
    """A fixture zip's CSVs in ``tmp_path/name``: turned into NWU, with a raw accelerometer (its unit in
    m/s^2: 1 or g), an inverted orientation, and without the ``drop`` files, as asked."""
    folder = tmp_path / name
    folder.mkdir()
    with zipfile.ZipFile(SESSIONS / fixture) as zf:
        for member in zf.namelist():
            if member.endswith(".csv") and not member.startswith("__MACOSX"):
                (folder / Path(member).name).write_bytes(zf.read(member))
    orientation = pd.read_csv(folder / "Orientation.csv")
    rotation = Rotation.from_quat(orientation[QUAT].to_numpy())
    if nwu:
        rotation = Rotation.from_euler("z", -90.0, degrees=True) * rotation
    if invert:
        rotation = rotation.inv()
    orientation[QUAT] = rotation.as_quat()
    orientation.to_csv(folder / "Orientation.csv", index=False)
    if raw_unit_ms2 is not None:  # the app's raw accelerometer: user + gravity, in the export's sign
        raw = pd.read_csv(folder / "Accelerometer.csv")
        gravity = pd.read_csv(folder / "Gravity.csv")
        for axis in "xyz":
            raw[axis] = (raw[axis] + gravity[axis]) / raw_unit_ms2
        raw.to_csv(folder / "AccelerometerUncalibrated.csv", index=False)
    for file in drop:
        (folder / file).unlink()
    return folder


def _heading_deg(imu: pd.DataFrame) -> np.ndarray:
    y = Rotation.from_quat(imu[QUAT].to_numpy()).apply([0.0, 1.0, 0.0])
    return np.degrees(np.arctan2(y[:, 0], y[:, 1]))


def _assert_same_imu(imu: pd.DataFrame, full: pd.DataFrame, atol_ms2: float = 1e-3) -> None:
    """Same acceleration on the common samples (gravity restored from the orientation equals the
    exported gravity to rounding), and the same heading when both have the quaternion."""
    both = full.merge(imu, on="t", suffixes=("", "_v"))
    assert len(both) >= len(full) - 4
    np.testing.assert_allclose(both[[f"{c}_v" for c in ACC]].to_numpy(), both[ACC].to_numpy(), atol=atol_ms2)
    if "qx" in full.columns:
        off = (_heading_deg(both[[f"{c}_v" for c in QUAT]].set_axis(QUAT, axis=1)) - _heading_deg(both)
               + 180.0) % 360.0 - 180.0
        assert np.abs(off).max() < 0.01


def _warnings(caplog) -> list[str]:
    return [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING]


def test_standardised_ios_without_gravity_or_metadata_takes_its_sign_from_the_raw_accelerometer(
        tmp_path, caplog):
    """The reported case: gravity restored with iOS's sign on a standardised export (error up to 6.2 m/s^2
    on this walk). The raw accelerometer, in m/s^2 with Android's sign, shows the convention."""
    full = read_sensorlogger(_export(tmp_path, "sensorlogger-ios-standardised.zip", "full", nwu=True,
                                     raw_unit_ms2=1.0))
    folder = _export(tmp_path, "sensorlogger-ios-standardised.zip", "variant", nwu=True, raw_unit_ms2=1.0,
                     drop=("Gravity.csv", "Metadata.csv"))
    with caplog.at_level(logging.INFO, logger=reader_logger.name):
        session = read_sensorlogger(folder)
    _assert_same_imu(session.imu, full.imu)
    assert (session.meta["platform"], session.meta["standardised"]) == ("ios", True)
    assert session.meta["platform_inferred_from"][0].startswith("acceleration in Android's sign convention")
    still = np.linalg.norm(session.imu[ACC].to_numpy(), axis=1)
    assert np.median(still) == pytest.approx(G, abs=1.0)


def test_an_inverted_orientation_is_found_before_gravity_is_restored(tmp_path):
    """World-to-device quaternions: with gravity in the data they were inverted, while restored gravity
    came out rotated (the tilt twice). The raw accelerometer now decides it the same way."""
    full = read_sensorlogger(_export(tmp_path, "sensorlogger-ios.zip", "full", raw_unit_ms2=G))
    folder = _export(tmp_path, "sensorlogger-ios.zip", "variant", raw_unit_ms2=G, invert=True,
                     drop=("Gravity.csv",))
    _assert_same_imu(read_sensorlogger(folder).imu, full.imu)


def test_without_a_raw_accelerometer_the_tie_is_said_and_the_option_settles_it(tmp_path, caplog, capsys):
    """Magnetic north at +90 deg allows iOS or standardised iOS, and restored gravity shows no sign: the
    warning says so and names the option; ``--platform ios-standardised`` reads it as the full export."""
    full = read_sensorlogger(_export(tmp_path, "sensorlogger-ios-standardised.zip", "full", nwu=True))
    folder = _export(tmp_path, "sensorlogger-ios-standardised.zip", "variant", nwu=True,
                     drop=("Gravity.csv", "Metadata.csv"))
    with caplog.at_level(logging.WARNING, logger=reader_logger.name):
        read_sensorlogger(folder)
    [line] = [m for m in _warnings(caplog) if "no Metadata.csv platform" in m]
    assert line.startswith(f"{folder}: ")
    assert line.endswith("standardised iOS fits the data too (then give --platform ios-standardised)")
    assert main(["convert", str(folder), str(tmp_path / "out"), "--platform", "ios-standardised"]) == 0
    session = read_session(tmp_path / "out")
    _assert_same_imu(session.imu, full.imu)
    assert session.meta["platform_given"] == "ios-standardised" and session.meta["standardised"] is True


@pytest.mark.parametrize("gravity", [True, False], ids=["with-gravity", "gravity-restored"])
def test_standardised_nwu_without_metadata_and_magnetometer_reads_right_with_the_option(
        tmp_path, caplog, gravity):
    """Nothing in the data tells this export from Android's: read as Android it is 90 deg off, with a
    one-line warning naming the option, which reads it as its metadata would."""
    full = read_sensorlogger(_export(tmp_path, "sensorlogger-ios-standardised.zip", "full", nwu=True))
    drop = ("Metadata.csv", "Magnetometer.csv") + (() if gravity else ("Gravity.csv",))
    folder = _export(tmp_path, "sensorlogger-ios-standardised.zip", "variant", nwu=True, drop=drop)
    with caplog.at_level(logging.WARNING, logger=reader_logger.name):
        guessed = read_sensorlogger(folder)
    both = full.imu.merge(guessed.imu, on="t", suffixes=("", "_v"))
    off = (_heading_deg(both[[f"{c}_v" for c in QUAT]].set_axis(QUAT, axis=1)) - _heading_deg(both)
           + 180.0) % 360.0 - 180.0
    assert np.abs(np.abs(off) - 90.0).max() < 0.01
    [line] = [m for m in _warnings(caplog) if "no Metadata.csv platform" in m]
    assert line.startswith(f"{folder}: ") and "give --platform" in line and "ios-standardised" in line
    _assert_same_imu(read_sensorlogger(folder, platform="ios-standardised").imu, full.imu)


def test_ios_without_metadata_and_orientation_reads_right_with_the_option(tmp_path, caplog):
    """No orientation, so no sign to measure and no frame: Android is assumed (gravity reads -9.8 m/s^2
    on this screen-up phone) and the warning names the option that fixes it."""
    full = read_sensorlogger(_export(tmp_path, "sensorlogger-ios.zip", "full", drop=("Orientation.csv",)))
    folder = _export(tmp_path, "sensorlogger-ios.zip", "variant", drop=("Orientation.csv", "Metadata.csv"))
    with caplog.at_level(logging.WARNING, logger=reader_logger.name):
        guessed = read_sensorlogger(folder)
    assert guessed.imu["az"].mean() < 0 < full.imu["az"].mean()
    [line] = [m for m in _warnings(caplog) if "no Metadata.csv platform" in m]
    assert line == (f"{folder}: no Metadata.csv platform, and no cue to it in the data; assuming Android "
                    "frames (an iOS export: give --platform ios or ios-standardised)")
    session = read_sensorlogger(folder, platform="ios")
    _assert_same_imu(session.imu, full.imu)
    assert "platform_inferred_from" not in session.meta


def test_the_option_outranks_metadata_and_says_so(tmp_path, caplog):
    """A standardised export whose orientation is already East-North-Up, without a magnetometer: its
    metadata makes the reader assume CoreMotion's frame (90 deg off); ``--platform android`` reads it as
    the full export, where the magnetometer showed the frame."""
    full = read_sensorlogger(_export(tmp_path, "sensorlogger-ios-standardised.zip", "full"))
    folder = _export(tmp_path, "sensorlogger-ios-standardised.zip", "variant", drop=("Magnetometer.csv",))
    with caplog.at_level(logging.WARNING, logger=reader_logger.name):
        session = read_sensorlogger(folder, platform="android")
    _assert_same_imu(session.imu, full.imu)
    assert f"{folder}: Metadata.csv says ios-standardised; read as android (--platform)" in _warnings(caplog)
    assert session.meta["device"] == "iPhone 12 Pro Max"  # the rest of Metadata.csv is kept


def test_platform_option_errors_exit_2(tmp_path, capsys):
    gpx = SESSIONS / "walk.gpx"
    assert main(["convert", str(gpx), str(tmp_path / "out"), "--platform", "ios"]) == 2
    assert capsys.readouterr().err.strip() == (
        "localize: error: --platform: applies to Sensor Logger exports only")
    with pytest.raises(SystemExit) as exc:
        main(["convert", str(SESSIONS / "sensorlogger-ios.zip"), str(tmp_path / "o2"), "--platform", "win"])
    assert exc.value.code == 2
    assert "invalid choice: 'win'" in capsys.readouterr().err


def test_run_records_the_option_and_a_replay_uses_it(tmp_path, caplog):
    folder = _export(tmp_path, "sensorlogger-ios-standardised.zip", "variant", nwu=True,
                     drop=("Metadata.csv", "Magnetometer.csv"))
    args = ["--mode", "gnss", "--particles", "50"]
    assert main(["run", str(folder), *args, "--platform", "ios-standardised", "-o", str(tmp_path / "a")]) == 0
    assert json.loads((tmp_path / "a" / "run.json").read_text())["platform"] == "ios-standardised"
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger=reader_logger.name):
        assert main(["run", "--config", str(tmp_path / "a" / "run.json"), "-o", str(tmp_path / "b")]) == 0
    assert not [m for m in _warnings(caplog) if "no Metadata.csv platform" in m]
    assert json.loads((tmp_path / "b" / "run.json").read_text())["platform"] == "ios-standardised"


@pytest.mark.parametrize("column", ["time", "recording epoch time"])
def test_a_time_clock_without_numbers_is_a_clear_error(tmp_path, capsys, column):
    """A format-2 export (``time`` only) whose clock holds no number: an internal error before."""
    folder = tmp_path / "v2"
    folder.mkdir()
    with zipfile.ZipFile(SESSIONS / "sensorlogger-android-v2.zip") as zf:
        zf.extractall(folder)
    if column == "time":
        table = pd.read_csv(folder / "Accelerometer.csv").assign(time="")  # blank: text is refused
        table.to_csv(folder / "Accelerometer.csv", index=False)
        expected = f"{folder}/Accelerometer.csv: no 'seconds_elapsed', and the 'time' clock has no start"
    else:  # a Metadata.csv epoch that is not a number: the clock falls back on the accelerometer's start
        meta = pd.read_csv(folder / "Metadata.csv").assign(**{column: "soon"})
        meta.to_csv(folder / "Metadata.csv", index=False)
        expected = None
    status = main(["convert", str(folder), str(tmp_path / "out")])
    err = capsys.readouterr().err
    if expected is None:
        assert status == 0, err
    else:
        assert status == 2 and f"localize: error: {expected}" in err
