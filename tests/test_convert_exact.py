"""A converted session is its source, bit for bit: ``localize convert`` writes floats that read back exactly,
so ``localize run`` on the converted folder writes the same ``track.csv`` as on the source."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from curbside.cli.localize import main
from curbside.cli.localize_convert import add_derived
from curbside.localize.readers import read_any
from curbside.localize.session import Session, read_session, validate_table, write_session

SESSIONS = Path(__file__).parent / "data" / "sessions"
TRIAL = f"{SESSIONS / 'ipin2023-cut.h5'}::TrainingTrial01_repetition01"


def assert_same_tables(written: Session, source: Session) -> None:
    expected = {kind: validate_table(kind, table, kind) for kind, table in source.tables().items()}
    assert set(written.tables()) == set(expected)
    for kind, table in written.tables().items():
        pd.testing.assert_frame_equal(table, expected[kind], check_exact=True, obj=f"{kind}.csv")
    assert written.meta == source.meta


def test_write_session_reads_back_every_float_exactly(tmp_path):
    rng = np.random.default_rng(0)
    t = np.cumsum(rng.uniform(1e-3, 2e-2, 200)) + 1.7e9 / 3  # epoch-sized times: 10 digits lose the ms
    values = rng.standard_normal((200, 6)) * 10.0 ** rng.integers(-12, 1, (200, 6))
    axes = ("ax", "ay", "az", "gx", "gy", "gz")
    imu = pd.DataFrame({"t": t, **{c: values[:, i] for i, c in enumerate(axes)}})
    imu["az"] += 9.80665  # SPEC units (read_session checks them): m/s^2 with gravity, rad/s under 35
    imu.loc[0, "ax"], imu.loc[1, "ay"], imu.loc[2, "az"] = 0.1 + 0.2, -0.0, 1 / 3
    gnss = pd.DataFrame({"t": t[::50], "lat": 37.7749295 + rng.standard_normal(4) * 1e-7,
                         "lon": -122.4194155 + rng.standard_normal(4) * 1e-7,
                         "accuracy_m": [4.1, np.nan, 0.0, 12.5]})
    session = Session(name="exact", imu=imu, gnss=gnss)
    assert_same_tables(read_session(write_session(session, tmp_path / "exact")), session)


@pytest.mark.parametrize(
    ("src", "derived"),
    [(TRIAL, True), (str(SESSIONS / "sensorlogger-android"), True),
     (str(SESSIONS / "sensorlogger-ios.zip"), False),
     (str(SESSIONS / "real" / "sensorlogger-android-1.12.0-ethz"), False),
     (str(SESSIONS / "walk.gpx"), False)],
    ids=["ipin-steps-pdr", "sensorlogger-android-steps-pdr", "sensorlogger-ios", "sensorlogger-real", "gpx"],
)
def test_converted_tables_equal_the_source(tmp_path, src, derived):
    flags = ["--steps", "--pdr"] if derived else []
    assert main(["convert", src, str(tmp_path / "out"), *flags]) == 0
    source = add_derived(read_any(src), steps=derived, pdr=derived)
    assert_same_tables(read_session(tmp_path / "out"), source)


def test_run_on_converted_trial_writes_the_same_track(tmp_path):
    assert main(["convert", TRIAL, str(tmp_path / "conv")]) == 0
    common = ["--velocity-source", "ronin", "--particles", "500", "--seed", "0"]
    assert main(["run", TRIAL, *common, "-o", str(tmp_path / "from_h5")]) == 0
    assert main(["run", str(tmp_path / "conv"), *common, "-o", str(tmp_path / "from_folder")]) == 0
    track = (tmp_path / "from_h5" / "track.csv").read_bytes()
    assert track == (tmp_path / "from_folder" / "track.csv").read_bytes()
