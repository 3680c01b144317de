"""Sensor Logger exports without ``Metadata.csv``: the platform, and with it the world frame of the
orientation (iOS: North-West-Up, turned into East-North-Up), is inferred from the data.

Each case reads the same edited fixture export twice, with and without ``Metadata.csv``, and
requires the same platform, quaternions and acceleration: the inference must change nothing that
the metadata would have decided.
"""

from __future__ import annotations

import logging
import shutil
import zipfile
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from scipy.spatial.transform import Rotation

from curbside.localize.readers.sensorlogger import logger as reader_logger
from curbside.localize.readers.sensorlogger import read_sensorlogger

SESSIONS = Path(__file__).parent / "data" / "sessions"
QUAT = ["qx", "qy", "qz", "qw"]
ACC = ["ax", "ay", "az"]
ANDROID_ORIENTATION = ["seconds_elapsed", "time", "qz", "qy", "qx", "qw", "roll", "pitch", "yaw"]

Edit = Callable[[Path], None]


def _unzip(src: Path, folder: Path) -> Path:
    """The CSV files of a fixture zip's one recording, flat in ``folder`` (Mac debris left out)."""
    folder.mkdir(parents=True)
    with zipfile.ZipFile(src) as zf:
        for member in zf.namelist():
            if member.endswith(".csv") and not member.startswith("__MACOSX"):
                (folder / Path(member).name).write_bytes(zf.read(member))
    return folder


def _copy(fixture: str, folder: Path) -> Path:
    src = SESSIONS / fixture
    if src.is_dir():
        return Path(shutil.copytree(src, folder))
    return _unzip(src, folder)


def _pair(tmp_path: Path, fixture: str, *edits: Edit) -> tuple[Path, Path]:
    """The fixture after ``edits``, as exported (with Metadata.csv) and without Metadata.csv."""
    with_meta = _copy(fixture, tmp_path / "with")
    for edit in edits:
        edit(with_meta)
    without = Path(shutil.copytree(with_meta, tmp_path / "without"))
    (without / "Metadata.csv").unlink()
    return with_meta, without


def _drop(*names: str) -> Edit:
    def edit(folder: Path) -> None:
        for name in names:
            (folder / name).unlink()
    return edit


def _android_column_order(folder: Path) -> None:
    """Orientation.csv in Android's column order (hides the iOS 1.10-1.11 layout)."""
    table = pd.read_csv(folder / "Orientation.csv")
    columns = [c for c in ANDROID_ORIENTATION if c in table.columns]
    table[columns].to_csv(folder / "Orientation.csv", index=False)


def _turn_world(degrees: float) -> Edit:
    def edit(folder: Path) -> None:
        table = pd.read_csv(folder / "Orientation.csv")
        turn = Rotation.from_euler("z", degrees, degrees=True)
        table[QUAT] = (turn * Rotation.from_quat(table[QUAT].to_numpy())).as_quat()
        table.to_csv(folder / "Orientation.csv", index=False)
    return edit


def _same_reading(with_meta: Path, without: Path, platform: bool = True):
    """Read both; the platform (unless ``platform`` is False), quaternions and acceleration must
    agree. Returns the one without."""
    expected = read_sensorlogger(with_meta)
    inferred = read_sensorlogger(without)
    if platform:
        assert inferred.meta["platform"] == expected.meta["platform"]
        assert inferred.meta["standardised"] == expected.meta["standardised"]
    assert inferred.imu["t"].equals(expected.imu["t"])
    np.testing.assert_allclose(inferred.imu[ACC], expected.imu[ACC], atol=1e-9)
    if "qx" in expected.imu.columns:
        error = Rotation.from_quat(inferred.imu[QUAT].to_numpy()) * Rotation.from_quat(
            expected.imu[QUAT].to_numpy()).inv()
        assert np.degrees(error.magnitude()).max() < 1e-6
        assert inferred.meta.get("magnetic_north_deg") == expected.meta.get("magnetic_north_deg")
    return inferred


def _inference_lines(caplog) -> list[logging.LogRecord]:
    return [r for r in caplog.records if "no Metadata.csv platform" in r.getMessage()]


def test_ios_export_without_metadata_is_turned_into_enu(tmp_path, caplog):
    """The reported case: an iOS export re-zipped without Metadata.csv was read 90 deg off."""
    with_meta, without = _pair(tmp_path, "sensorlogger-ios.zip")
    with caplog.at_level(logging.INFO, logger=reader_logger.name):
        session = _same_reading(with_meta, without)
    assert session.meta["platform"] == "ios"
    assert session.meta["magnetic_north_deg"] == pytest.approx(0.0, abs=0.5)
    [line] = _inference_lines(caplog)
    assert line.levelno == logging.INFO  # three cues agree
    message = line.getMessage()
    assert "iOS inferred (orientation North-West-Up, turned into ENU)" in message
    assert "iOS's sign convention" in message and "magnetic north at +90 deg" in message
    assert "iOS 1.10-1.11 order" in message and "against" not in message
    assert session.meta["platform_inferred_from"][0].startswith("acceleration in iOS's sign convention")


@pytest.mark.parametrize(
    ("edits", "evidence"),
    [
        ((_drop("Magnetometer.csv"), _android_column_order), "acceleration in iOS's sign convention"),
        ((_drop("Gravity.csv"), _android_column_order), "magnetic north at +90 deg"),
        ((_drop("Gravity.csv", "Magnetometer.csv"),), "Orientation.csv columns in iOS 1.10-1.11 order"),
    ],
    ids=["sign-alone", "magnetometer-alone", "column-order-alone"],
)
def test_each_cue_alone_finds_ios(tmp_path, caplog, edits, evidence):
    """Without Gravity.csv the sign cannot be measured (gravity is restored from the orientation with
    the platform's sign), so the magnetometer or the column order must decide, and before restoring."""
    with_meta, without = _pair(tmp_path, "sensorlogger-ios.zip", *edits)
    with caplog.at_level(logging.INFO, logger=reader_logger.name):
        session = _same_reading(with_meta, without)
    assert session.meta["platform"] == "ios"
    [line] = _inference_lines(caplog)
    assert line.levelno == logging.WARNING  # a single cue: said louder
    [cue] = session.meta["platform_inferred_from"]
    assert cue.startswith(evidence)


def _uncalibrated_in_g(folder: Path) -> None:
    """AccelerometerUncalibrated.csv as iOS writes it without standardisation: in g, iOS's sign."""
    user = pd.read_csv(folder / "Accelerometer.csv")
    gravity = pd.read_csv(folder / "Gravity.csv")
    for axis in "xyz":
        user[axis] = (user[axis] + gravity[axis]) / 9.80665
    user.to_csv(folder / "AccelerometerUncalibrated.csv", index=False)


def test_uncalibrated_accelerometer_in_g_gives_the_ios_sign_without_orientation(tmp_path, caplog):
    """No orientation, so no measured sign: the raw accelerometer's unit tells iOS, and the acceleration
    gets the iOS sign flip the metadata would have given."""
    with_meta, without = _pair(tmp_path, "sensorlogger-ios.zip", _uncalibrated_in_g,
                               _drop("Orientation.csv", "Magnetometer.csv"))
    with caplog.at_level(logging.INFO, logger=reader_logger.name):
        session = _same_reading(with_meta, without)
    assert session.meta["platform_inferred_from"] == ["AccelerometerUncalibrated.csv in g"]
    assert session.imu["az"].mean() > 0  # Android's convention: the fixture's phone is screen-up


def test_sign_outranks_a_magnetometer_that_disagrees(tmp_path, caplog):
    """iOS signs, but the world frame turned so that the magnetometer reads East-North-Up: the platform
    follows the sign (as with Metadata.csv) and the north check reports the 90 deg."""
    with_meta, without = _pair(tmp_path, "sensorlogger-ios.zip", _turn_world(90.0))
    with caplog.at_level(logging.INFO, logger=reader_logger.name):
        session = _same_reading(with_meta, without)
    assert session.meta["platform"] == "ios"
    [line] = _inference_lines(caplog)
    assert line.levelno == logging.WARNING
    assert "against it: magnetic north at +0 deg in the orientation's frame (East-North-Up)" in \
        line.getMessage()
    assert abs(session.meta["magnetic_north_deg"]) == pytest.approx(90.0, abs=0.5)


def _east_pointing_magnetometer(folder: Path) -> None:
    """A magnetometer that, in the Android fixture's ENU frame, points east: disturbed, or a wrong frame."""
    quat = pd.read_csv(folder / "Orientation.csv")
    field = Rotation.from_quat(quat[QUAT].to_numpy()).inv().apply([22.0, 0.0, -40.0])
    mag = quat[["time", "seconds_elapsed"]].assign(z=field[:, 2], y=field[:, 1], x=field[:, 0])
    mag.to_csv(folder / "Magnetometer.csv", index=False)


def test_android_stays_android_when_the_magnetometer_points_east(tmp_path, caplog):
    """Android signs and TotalAcceleration.csv outrank a magnetometer 90 deg off (a real Android walk
    showed north at -108 deg): no turn, and the disagreement is said."""
    with_meta, without = _pair(tmp_path, "sensorlogger-android", _east_pointing_magnetometer)
    with caplog.at_level(logging.INFO, logger=reader_logger.name):
        session = _same_reading(with_meta, without)
    assert session.meta["platform"] == "android"
    assert session.meta["platform_inferred_from"] == [
        "acceleration in Android's sign convention (Android, or standardised iOS)",
        "TotalAcceleration.csv (iOS writes none)"]
    [line] = _inference_lines(caplog)
    assert line.levelno == logging.WARNING and "against it: magnetic north at +90 deg" in line.getMessage()


@pytest.mark.parametrize("fixture", ["sensorlogger-android-v2.zip", "sensorlogger-android-1.12.zip"])
def test_other_fixtures_read_the_same_without_metadata(tmp_path, fixture):
    with_meta, without = _pair(tmp_path, fixture)
    session = _same_reading(with_meta, without)
    assert session.meta["platform"] == "android" and session.meta["platform_inferred_from"]


def test_standardised_ios_in_enu_reads_as_android_frames_without_metadata(tmp_path):
    """A standardised iOS export whose orientation is East-North-Up (the fixture's): Android signs and
    a north at 0 deg read as Android frames, giving the quaternions its Metadata.csv gives (the label
    is the one difference)."""
    with_meta, without = _pair(tmp_path, "sensorlogger-ios-standardised.zip")
    inferred = _same_reading(with_meta, without, platform=False)
    assert read_sensorlogger(with_meta).meta["platform"] == "ios"
    assert (inferred.meta["platform"], inferred.meta["standardised"]) == ("android", False)


def test_standardised_ios_in_nwu_reads_the_same_without_metadata(tmp_path, caplog):
    """A standardised iOS export whose orientation is CoreMotion's North-West-Up: its Android sign
    allows Android or standardised iOS, and the magnetometer (north at +90 deg) picks the latter, so
    the frame is turned into ENU as with Metadata.csv. It was read 90 deg off: the sign alone decided."""
    with_meta, without = _pair(tmp_path, "sensorlogger-ios-standardised.zip", _turn_world(-90.0))
    with caplog.at_level(logging.INFO, logger=reader_logger.name):
        session = _same_reading(with_meta, without)
    assert (session.meta["platform"], session.meta["standardised"]) == ("ios", True)
    assert session.meta["magnetic_north_deg"] == pytest.approx(0.0, abs=0.5)
    assert [cue.split(" (")[0] for cue in session.meta["platform_inferred_from"]] == [
        "acceleration in Android's sign convention", "magnetic north at +90 deg in the orientation's frame"]
    [line] = _inference_lines(caplog)
    assert "standardised iOS inferred (orientation North-West-Up, turned into ENU" in line.getMessage()


def test_without_any_cue_android_frames_are_assumed_and_said(tmp_path, caplog):
    """No orientation, no TotalAcceleration.csv, no raw accelerometer: nothing shows the platform, and
    ``meta`` claims none (it said "android")."""
    with_meta, without = _pair(tmp_path, "sensorlogger-android-v2.zip", _drop("Orientation.csv"))
    with caplog.at_level(logging.INFO, logger=reader_logger.name):
        session = _same_reading(with_meta, without, platform=False)
    assert not {"platform", "standardised", "platform_inferred_from"} & set(session.meta)
    [line] = _inference_lines(caplog)
    assert line.levelno == logging.WARNING
    assert "no cue to it in the data; assuming Android frames" in line.getMessage()


def test_unknown_platform_in_metadata_is_inferred(tmp_path, caplog):
    folder = _copy("sensorlogger-ios.zip", tmp_path / "export")
    meta = pd.read_csv(folder / "Metadata.csv").assign(platform="ipados")
    meta.to_csv(folder / "Metadata.csv", index=False)
    with caplog.at_level(logging.WARNING, logger=reader_logger.name):
        session = read_sensorlogger(folder)
    assert session.meta["platform"] == "ios" and session.meta["app_version"] == "1.11"
    assert "Metadata.csv platform 'ipados' unknown; inferred from the data" in caplog.text
    assert session.meta["magnetic_north_deg"] == pytest.approx(0.0, abs=0.5)


def test_world_to_device_ios_orientation_is_inverted_before_the_frame_turn(tmp_path):
    """An iOS orientation stored the other way round: the inversion comes first, then the world frame's
    NWU->ENU turn. The turn applied before the inversion turned the phone instead, and the export was
    refused ("orientation and accelerometer disagree on gravity")."""
    original = read_sensorlogger(SESSIONS / "sensorlogger-ios.zip")
    folder = _copy("sensorlogger-ios.zip", tmp_path / "inverted")
    table = pd.read_csv(folder / "Orientation.csv")
    table[QUAT] = Rotation.from_quat(table[QUAT].to_numpy()).inv().as_quat()
    table.to_csv(folder / "Orientation.csv", index=False)
    session = read_sensorlogger(folder)
    error = Rotation.from_quat(session.imu[QUAT].to_numpy()) * Rotation.from_quat(
        original.imu[QUAT].to_numpy()).inv()
    assert np.degrees(error.magnitude()).max() < 1e-6
    assert session.meta["magnetic_north_deg"] == pytest.approx(0.0, abs=0.5)
