"""Inputs in the wrong units, or with a clock set back: refused (or warned about) at the input boundary.

Session folders (``imu.csv`` ``t`` in ns or ms, accelerations in g, rotation rates in deg/s, a
``meta.json`` with a BOM) and Sensor Logger exports (``time`` or ``seconds_elapsed`` in other units, a
clock step back, fixes without accuracy), made from the trimmed real-walk fixture in tests/data.
"""

from __future__ import annotations

import logging
import shutil
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from curbside.cli.localize import main
from curbside.errors import CurbsideInputError
from curbside.localize.readers import read_any
from curbside.localize.readers._tidy import clock_step_back
from curbside.localize.readers.sensorlogger import read_sensorlogger
from curbside.localize.session import read_session, validate_table, write_session

EXPORT = Path(__file__).parent / "data" / "sessions" / "sensorlogger-android"
MOTION = ("Accelerometer.csv", "TotalAcceleration.csv", "Gyroscope.csv", "Orientation.csv")


def _input_error(capsys, argv: list[str]) -> str:
    """A command's refusal: exit 2, one line, no traceback."""
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err and err.startswith("localize: error: ")
    return err


@pytest.fixture(scope="module")
def session_folder(tmp_path_factory) -> Path:
    """The fixture export as a SPEC session folder (5 s at 50 Hz, 5 fixes, 1 waypoint)."""
    folder = tmp_path_factory.mktemp("spec") / "walk"
    write_session(read_any(str(EXPORT)), folder)
    return folder


def _session_copy(src: Path, dst: Path, edit: Callable[[str, pd.DataFrame], pd.DataFrame]) -> Path:
    shutil.copytree(src, dst)
    for path in dst.glob("*.csv"):
        edit(path.stem, pd.read_csv(path)).to_csv(path, index=False)
    return dst


def _export_copy(dst: Path, edit: Callable[[str, pd.DataFrame], pd.DataFrame | None]) -> Path:
    """The fixture export with each CSV replaced by ``edit(name, table)`` (``None``: left as it is)."""
    shutil.copytree(EXPORT, dst)
    for path in dst.glob("*.csv"):
        table = edit(path.name, pd.read_csv(path))
        if table is not None:
            table.to_csv(path, index=False)
    return dst


# -- session folders ----------------------------------------------------------------------------------


def test_session_t_in_epoch_nanoseconds_is_refused_before_run_allocates(session_folder, tmp_path, capsys):
    def to_ns(kind, table):
        table["t"] = ((table["t"] + 1.7e9) * 1e9).round()
        return table

    folder = _session_copy(session_folder, tmp_path / "t_ns", to_ns)
    err = _input_error(capsys, ["run", str(folder), "--mode", "gnss", "-o", str(tmp_path / "out")])
    assert f"{folder / 'imu.csv'}: t is not in seconds (nanoseconds or milliseconds since an epoch?)" in err
    assert "data row 1," in err and not (tmp_path / "out").exists()


@pytest.mark.parametrize(("scale", "unit"), [(1e9, "nanoseconds?"), (1e3, "milliseconds?")])
def test_session_imu_t_whose_rate_is_absurd_is_refused(session_folder, tmp_path, capsys, scale, unit):
    def rescale(kind, table):
        table["t"] = table["t"] * scale
        return table

    folder = _session_copy(session_folder, tmp_path / "t", rescale)
    err = _input_error(capsys, ["run", str(folder), "--mode", "gnss", "-o", str(tmp_path / "out")])
    assert f"{folder / 'imu.csv'}: t is not in seconds: its rows come every " in err and unit in err


def test_every_table_refuses_epoch_milliseconds():
    velocity = pd.DataFrame({"t": [1.7e12, 1.7e12 + 100], "ve": [1.0, 1.0], "vn": [0.0, 0.0]})
    with pytest.raises(CurbsideInputError, match=r"velocity.csv: t is not in seconds .*t=1700000000000.0 at "
                       r"data row 1, and \|t\| must be under 1e10 s"):
        validate_table("velocity", velocity, "velocity.csv")


def test_session_in_g_or_deg_per_s_is_refused_as_the_service_refuses_it(session_folder, tmp_path, capsys):
    def in_g(kind, table):
        if kind == "imu":
            table[["ax", "ay", "az"]] /= 9.80665
        return table

    def in_deg_s(kind, table):
        if kind == "imu":
            table[["gx", "gy", "gz"]] = np.degrees(table[["gx", "gy", "gz"]])
        return table

    folder = _session_copy(session_folder, tmp_path / "g", in_g)
    err = _input_error(capsys, ["run", str(folder), "--mode", "fused", "-o", str(tmp_path / "out")])
    assert f"{folder / 'imu.csv'}: ax,ay,az are in g (gravity level 1.0" in err and "not m/s^2" in err
    folder = _session_copy(session_folder, tmp_path / "deg", in_deg_s)
    with pytest.raises(CurbsideInputError, match=r"imu.csv: \|gy\| = .* exceeds 35 rad/s: .* \(deg/s\?\)"):
        read_session(folder)
    assert read_session(session_folder).imu is not None  # the same walk in SPEC units reads


def test_session_without_gravity_is_refused(session_folder, tmp_path):
    def no_gravity(kind, table):
        if kind == "imu":
            table[["ax", "ay", "az"]] -= table[["ax", "ay", "az"]].mean()
        return table

    folder = _session_copy(session_folder, tmp_path / "user", no_gravity)
    with pytest.raises(CurbsideInputError, match="gravity level 0.* neither ~9.8 m/s.2 nor ~1 g"):
        read_session(folder)


def test_meta_json_with_a_byte_order_mark_reads(session_folder, tmp_path):
    folder = tmp_path / "bom"
    shutil.copytree(session_folder, folder)
    meta = folder / "meta.json"
    meta.write_bytes(b"\xef\xbb\xbf" + meta.read_bytes())
    assert read_session(folder).meta == read_session(session_folder).meta


# -- Sensor Logger: the units of its clocks -----------------------------------------------------------


def test_seconds_elapsed_in_nanoseconds_is_refused_at_convert(tmp_path, capsys):
    def to_ns(name, table):
        if "seconds_elapsed" in table:
            table["seconds_elapsed"] = (table["seconds_elapsed"] * 1e9).round().astype("int64")
        return table

    src = _export_copy(tmp_path / "export", to_ns)
    err = _input_error(capsys, ["convert", str(src), str(tmp_path / "out")])
    assert "'seconds_elapsed' is not in seconds: it spans 1e+09 times what 'time' does" in err
    assert "nanoseconds?" in err and not (tmp_path / "out").exists()


@pytest.mark.parametrize(("divisor", "unit"),
                         [(1e3, "microseconds"), (1e6, "milliseconds"), (1e9, "seconds")])
@pytest.mark.parametrize("export_format", [2, 3])
def test_time_in_other_units_is_refused_naming_the_unit(tmp_path, divisor, unit, export_format):
    def rescale(name, table):
        if "time" not in table:
            return None
        table["time"] = table["time"] / divisor
        return table.drop(columns="seconds_elapsed") if export_format == 2 else table

    src = _export_copy(tmp_path / "export", rescale)
    with pytest.raises(CurbsideInputError, match=rf"'time' is not in nanoseconds since the UNIX epoch, as "
                       rf"Sensor Logger writes it: its median 1.7e\+\d+ reads as {unit} since the epoch"):
        read_sensorlogger(src)


# -- Sensor Logger: a clock set back ------------------------------------------------------------------


def _step_back(after_s: float, by_s: float, files: tuple[str, ...]):
    def edit(name, table):
        if name not in files:
            return None
        later = table["seconds_elapsed"] > after_s
        table.loc[later, "time"] -= round(by_s * 1e9)
        table.loc[later, "seconds_elapsed"] -= by_s
        return table
    return edit


def test_a_clock_set_back_in_every_stream_is_refused(tmp_path, capsys):
    src = _export_copy(tmp_path / "export", _step_back(4.0, 1.00037, MOTION))
    err = _input_error(capsys, ["convert", str(src), str(tmp_path / "out")])
    assert f"{src / 'TotalAcceleration.csv'}: time goes back 0.97 s at data row 100 ('seconds_elapsed' " \
        "3.00683 after 3.9794 at data row 99): the phone's clock was set back during the recording, and " \
        "once sorted the rows after it would interleave with, or precede, those before; cut the recording " \
        "there" in err
    assert not (tmp_path / "out").exists()


def test_a_few_swapped_rows_are_still_sorted_silently(tmp_path, caplog):
    def swap(name, table):
        if name not in MOTION:
            return None
        order = np.arange(len(table))
        order[[100, 101]] = [101, 100]
        order[[150, 152]] = [152, 150]
        return table.iloc[order]

    src = _export_copy(tmp_path / "export", swap)
    with caplog.at_level(logging.INFO):
        swapped = read_sensorlogger(src)
    assert not [r for r in caplog.records if r.levelno >= logging.WARNING and "goes back" in r.getMessage()]
    assert any("out of time order; sorted" in r.getMessage() for r in caplog.records)
    pd.testing.assert_frame_equal(swapped.imu, read_sensorlogger(EXPORT).imu)


def test_cached_samples_reported_again_later_are_not_a_clock_step(tmp_path):
    def repeat(name, table):
        return pd.concat([table, table.iloc[40:60]]) if name == "Gyroscope.csv" else None

    src = _export_copy(tmp_path / "export", repeat)
    pd.testing.assert_frame_equal(read_sensorlogger(src).imu, read_sensorlogger(EXPORT).imu)


def test_a_clock_step_in_location_is_a_warning(tmp_path, caplog):
    def fixes(name, table):
        if name != "Location.csv":
            return None
        t_s = np.arange(20) + 0.5 - np.where(np.arange(20) >= 10, 8.5, 0.0)
        rows = pd.concat([table.iloc[[1]]] * 20, ignore_index=True)
        rows["seconds_elapsed"] = t_s
        rows["time"] = 1_700_000_000_000_000_000 + (t_s * 1e9).round().astype("int64")
        return rows

    src = _export_copy(tmp_path / "export", fixes)
    with caplog.at_level(logging.WARNING):
        session = read_sensorlogger(src)
    assert len(session.gnss) == 20
    assert any("Location.csv: time goes back 7.50 s at data row 11" in r.getMessage() for r in caplog.records)


def test_clock_step_back_tells_a_step_from_a_reordering():
    t = np.arange(0.0, 4.0, 0.02)
    assert clock_step_back(t) is None
    swapped = t.copy()
    swapped[[50, 51, 52]] = swapped[[52, 50, 51]]
    assert clock_step_back(swapped) is None
    assert clock_step_back(t[::-1]) is None  # written newest first: sorting is unambiguous
    assert clock_step_back(np.where(t > 2.0, t + 1.0, t)[::-1]) is None  # ... with a gap
    assert clock_step_back(np.append(t, 1.0)) is None  # one row out of place at the end
    delayed = np.concatenate([t[:50], t[51:60], t[50:51], t[60:]])  # one sample handed over 9 rows late
    assert clock_step_back(delayed) is None
    buffered = np.concatenate([t[30:40], t[:30], t[40:]])  # samples from before the first row, reported late
    assert clock_step_back(buffered) is None
    stepped = np.where(t > 2.0, t - 0.5, t)  # interleaves with the half second before the step
    row, back_s = clock_step_back(stepped)
    assert row == int(np.argmax(t > 2.0)) and back_s == pytest.approx(0.48)
    far_back = np.where(t > 2.0, t - 3600.0, t)  # the walk's second half would come first once sorted
    assert clock_step_back(far_back) == (row, pytest.approx(3600.0 - 0.02))


# -- Sensor Logger: fixes without accuracy ------------------------------------------------------------


def test_fixes_whose_accuracy_is_all_negative_warn_as_a_missing_column_does(tmp_path, caplog):
    def invalid(name, table):
        if name != "Location.csv":
            return None
        table["horizontalAccuracy"] = -1
        return table

    src = _export_copy(tmp_path / "export", invalid)
    with caplog.at_level(logging.WARNING):
        read_sensorlogger(src)
    assert any("Location.csv: no horizontalAccuracy above 0; every fix has unknown accuracy (invalid)"
               in r.getMessage() for r in caplog.records)
    caplog.clear()
    with caplog.at_level(logging.WARNING):
        read_sensorlogger(EXPORT)
    assert not any("horizontalAccuracy" in r.getMessage() for r in caplog.records)


def test_an_imu_logged_at_one_hertz_is_called_too_slow_as_well(session_folder, tmp_path, capsys):
    def thin(kind, table):
        return table.iloc[::50].reset_index(drop=True) if kind == "imu" else table

    folder = _session_copy(session_folder, tmp_path / "slow", thin)
    err = _input_error(capsys, ["run", str(folder), "--mode", "gnss", "-o", str(tmp_path / "out")])
    assert "(milliseconds?), or the IMU was logged too slowly to track (20 Hz or more)" in err
