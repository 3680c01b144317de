"""RoNIN inference: ronin_velocity, the ``localize ronin`` command, and the shipped model on real data."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from test_imu import synthetic_imu

from curbside.cli.localize import main as localize_main
from curbside.errors import CurbsideInputError
from curbside.localize.ronin.infer import load_model, ronin_velocity
from curbside.localize.ronin.stream import RoninStreamConfig
from curbside.localize.session import read_session


@pytest.mark.parametrize("stride", [10, 20, 40])
def test_velocity_rows_are_window_centres_every_stride(stride):
    table, _ = synthetic_imu(duration_s=12.0)
    vel = ronin_velocity(table, config=RoninStreamConfig(stride=stride))
    assert list(vel.columns) == ["t", "ve", "vn"]
    assert np.allclose(np.diff(vel["t"]), stride / 200.0)
    assert vel["t"].iat[0] == pytest.approx(table["t"].iat[0] + 199 / 400.0)
    assert np.isfinite(vel[["ve", "vn"]].to_numpy()).all()


def test_long_gap_produces_no_rows_inside_it():
    table, _ = synthetic_imu(duration_s=30.0)
    gapped = table[(table["t"] < 12.0) | (table["t"] > 14.0)]
    vel = ronin_velocity(gapped)
    inside = (vel["t"] > 12.0) & (vel["t"] < 14.0)
    assert not inside.any()
    assert (vel["t"] < 12.0).any() and (vel["t"] > 14.0).any()


def test_recording_shorter_than_a_window_is_an_input_error():
    table, _ = synthetic_imu(duration_s=0.8)
    with pytest.raises(CurbsideInputError):
        ronin_velocity(table)


def test_ronin_command_writes_velocity_csv(tmp_path, capsys):
    table, _ = synthetic_imu(duration_s=10.0)
    session = tmp_path / "walk"
    session.mkdir()
    table.to_csv(session / "imu.csv", index=False)
    assert localize_main(["ronin", str(session)]) == 0
    assert "(weights ronin_compact.pt, sha256 " in capsys.readouterr().out
    vel = pd.read_csv(session / "velocity.csv")
    assert list(vel.columns) == ["t", "ve", "vn"] and len(vel) == 90  # 9 s of centres every 100 ms
    # bit for bit what `localize run` computes when the session has no velocity.csv (pipeline._velocity)
    read = read_session(session)
    assert np.array_equal(read.velocity.to_numpy(), ronin_velocity(read.imu).to_numpy())
    assert localize_main(["ronin", str(session), "-o", str(tmp_path / "v.csv")]) == 0
    assert pd.read_csv(tmp_path / "v.csv").equals(vel)
    assert localize_main(["ronin", str(session), "--stride", "40", "-o", str(tmp_path / "v40.csv")]) == 0
    assert np.allclose(np.diff(pd.read_csv(tmp_path / "v40.csv")["t"]), 0.2, atol=2e-6)


def test_ronin_command_bad_input_exits_2_and_writes_nothing(tmp_path, capsys):
    session = tmp_path / "walk"
    session.mkdir()
    table, _ = synthetic_imu(duration_s=10.0)
    table[["t"]].iloc[::50].to_csv(session / "steps.csv", index=False)  # a session without imu.csv
    assert localize_main(["ronin", str(session)]) == 2
    assert "imu.csv" in capsys.readouterr().err
    table.to_csv(session / "imu.csv", index=False)
    assert localize_main(["ronin", str(session), "--weights", str(tmp_path / "none.pt")]) == 2
    assert localize_main(["ronin", str(session), "--stride", "500"]) == 2
    assert "--stride" in capsys.readouterr().err
    assert not (session / "velocity.csv").exists()
    assert [p.name for p in session.iterdir() if p.name.startswith(".")] == []


def test_shipped_model_on_a_held_out_ipin_trial(shared_data):
    """The bundled model integrated over a trial it never saw lands near the surveyed waypoints."""
    from curbside.localize.readers.ipin import read_trial
    from curbside.projection import LocalFrame

    session = read_trial(shared_data / "ipin2023" / "ipin2023-t3.h5", "TrainingTrial01_repetition04")
    vel = ronin_velocity(session.imu, load_model())
    wp = session.waypoints
    frame = LocalFrame.around(wp["lon"].iat[0], wp["lat"].iat[0])
    x, y = frame.to_xy(wp["lon"], wp["lat"])
    span = (vel["t"] >= wp["t"].iat[0]) & (vel["t"] <= wp["t"].iat[-1])
    v = vel[span]
    dt = np.diff(v["t"], prepend=v["t"].iat[0])
    est = np.cumsum(v[["ve", "vn"]].to_numpy() * dt[:, None], axis=0)
    path = np.sum(np.hypot(np.diff(x), np.diff(y)))
    ratio = np.sum(np.hypot(*(v[["ve", "vn"]].to_numpy() * dt[:, None]).T)) / path
    assert 0.8 < ratio < 1.25
    ex = np.interp(wp["t"], v["t"], est[:, 0]) + x[0]
    ey = np.interp(wp["t"], v["t"], est[:, 1]) + y[0]
    assert np.median(np.hypot(ex - x, ey - y)) < 0.1 * path


def test_ronin_on_a_simulated_imu_is_warned_about(caplog):
    import logging

    from curbside.localize.session import Session, warn_if_simulated_imu

    with caplog.at_level(logging.WARNING):
        warn_if_simulated_imu(Session(name="real", meta={"start": {}}), "real/imu.csv")
        assert not caplog.records
        warn_if_simulated_imu(Session(name="walk", meta={"simulation": {"route": "path1"}}), "walk/imu.csv")
    [record] = caplog.records
    assert "walk/imu.csv is simulated" in record.getMessage() and "velocity.csv" in record.getMessage()
