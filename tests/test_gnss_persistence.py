"""How long a fix's error lasts: the measurement, the persistent GNSS model, and the benchmark script."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from curbside.errors import CurbsideInputError
from curbside.evaluate import gnss_model
from curbside.evaluate import simulate as sim
from curbside.evaluate.gnss_persistence import ar1_reference, fix_errors, window_persistence
from curbside.evaluate.walker import simulate_walk
from curbside.projection import LocalFrame

sys.path.insert(0, str(Path(__file__).parents[1] / "benchmarks"))
from gnss_persistence import main, summary_row  # noqa: E402


def errors_table(e: np.ndarray) -> pd.DataFrame:
    return pd.DataFrame({"t": np.arange(len(e), dtype=float), "east_m": e[:, 0], "north_m": e[:, 1]})


def test_a_constant_offset_persists_entirely_and_white_noise_not_at_all():
    rng = np.random.default_rng(0)
    offset = window_persistence(errors_table(np.tile([3.0, -4.0], (300, 1))), 90.0)
    assert len(offset) == 3  # 300 s: three whole 90 s windows, the tail left out
    assert offset["lag_30s"].tolist() == pytest.approx([1.0] * 3)
    assert offset["offset_share"].tolist() == pytest.approx([1.0] * 3)
    white = window_persistence(errors_table(rng.normal(0, 5, (900, 2))), 90.0)
    assert white["lag_5s"].abs().median() < 0.1
    assert white["offset_share"].median() < 0.1


def test_a_gauss_markov_error_reads_its_time_constant():
    for tau in (10.0, 30.0):
        ref = ar1_reference(tau, window_s=150.0)
        for lag in (5, 10, 20):
            assert ref[f"lag_{lag}s"] == pytest.approx(np.exp(-lag / tau), abs=0.06)
    assert ar1_reference(60.0)["lag_10s"] > ar1_reference(10.0)["lag_10s"] + 0.3


def test_an_outlier_of_a_few_seconds_does_not_outweigh_a_slow_error():
    slow = np.column_stack([np.linspace(2, 4, 90), np.full(90, 1.0)])
    spiked = slow.copy()
    spiked[40:43] = [100.0, -80.0]  # 3 s, 100 m off
    assert window_persistence(errors_table(spiked), 90.0)["lag_10s"].iat[0] > 0.8


def test_fix_errors_are_measured_against_the_straight_line_between_waypoints():
    frame = LocalFrame.around(-122.4, 37.79)
    wlon, wlat = frame.to_lonlat(np.array([0.0, 100.0]), np.array([0.0, 0.0]))
    waypoints = pd.DataFrame({"t": [10.0, 110.0], "lat": wlat, "lon": wlon})
    t = np.arange(0.0, 130.0, 1.0)
    glon, glat = frame.to_lonlat(t - 10.0 + 2.0, np.full(len(t), -3.0))  # 2 m ahead, 3 m south
    gnss = pd.DataFrame({"t": t, "lat": glat, "lon": glon, "accuracy_m": 5.0})
    errors = fix_errors(gnss, waypoints)
    assert errors["t"].min() == 10.0 and errors["t"].max() == 110.0  # inside the waypoints' span only
    assert errors["east_m"].to_numpy() == pytest.approx(2.0, abs=0.01)
    assert errors["north_m"].to_numpy() == pytest.approx(-3.0, abs=0.01)


def test_continuous_sign_never_lets_consecutive_axes_point_apart():
    axes = np.array([[1.0, 0.0], [-1.0, 0.0], [0.0, 1.0], [-0.6, -0.8], [1.0, 0.0]])
    fixed = gnss_model.continuous_sign(axes)
    assert (np.einsum("ij,ij->i", fixed[1:], fixed[:-1]) >= 0).all()
    assert np.abs(fixed).tolist() == np.abs(axes).tolist()


def test_the_persistent_model_keeps_the_error_size_and_makes_it_last():
    route_list, _, osm = sim.sf6_routes()
    route = route_list[0]
    walk = simulate_walk(route, sim.SimulationConfig().walker, np.random.default_rng(1))
    stride = int(round(1.0 / (walk.t[1] - walk.t[0])))
    t, xy = walk.t[::stride], walk.xy[::stride]
    reads = {}
    for name in ("canyon", "persistent"):
        tables, sizes = [], []
        for seed in range(4):
            f = gnss_model.simulate_gnss(t, xy, osm, gnss_model.GnssErrorModel.named(name),
                                         np.random.default_rng(seed))
            e = np.column_stack([f["x_m"] - f["true_x_m"], f["y_m"] - f["true_y_m"]])
            tables.append(window_persistence(errors_table(e).assign(t=f["t"].to_numpy()), 90.0))
            sizes.append(np.hypot(e[:, 0], e[:, 1]))
        reads[name] = (pd.concat(tables)["lag_10s"].median(), np.median(np.concatenate(sizes)))
    assert reads["persistent"][0] > reads["canyon"][0] + 0.2
    assert reads["persistent"][1] == pytest.approx(reads["canyon"][1], rel=0.3)


def test_an_unknown_gnss_model_is_a_one_line_input_error():
    with pytest.raises(CurbsideInputError, match="unknown GNSS model 'foggy'"):
        gnss_model.GnssErrorModel.named("foggy")


def test_the_script_refuses_nothing_to_measure_a_missing_folder_and_a_short_window(tmp_path, capsys):
    short = ["--sessions", str(tmp_path), "--window-s", "20"]
    for argv in ([], ["--sessions", str(tmp_path / "absent")], short):
        with pytest.raises(SystemExit) as exc:
            main(argv)
        assert exc.value.code == 2
    err = capsys.readouterr().err
    assert "absent: no such file or folder" in err and "longer than the longest lag" in err


def test_the_script_summarises_simulated_sessions(tmp_path, capsys):
    route_list, frame, osm = sim.sf6_routes()
    folder = tmp_path / "sessions"
    for seed in (1, 2):
        session = sim.simulate_session(route_list[0], osm, frame, seed)
        sim.write_session(session, folder / session.name)
    figure = tmp_path / "persistence.png"
    assert main(["--sessions", str(folder), "--tau-s", "30", "--plot", str(figure)]) == 0
    assert figure.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    out = capsys.readouterr().out
    assert f"simulated {tmp_path.name}/sessions" in out and "AR(1), tau 30 s" in out
    assert summary_row("none", [])["windows"] == 0
