"""The yaw-equivariance spread: does a RoNIN model know a recording, without ground truth?"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from serve_fixtures import TRIAL
from test_ronin_cli_checks import ronin_dir  # noqa: F401  (a fixture)

from curbside.cli.localize import main as localize_main
from curbside.localize.readers import read_any
from curbside.localize.ronin import familiarity as familiarity_module
from curbside.localize.ronin.familiarity import (
    UNFAMILIAR_SPREAD_MPS,
    familiarity,
    session_familiarity,
    turned_velocities,
    yaw_spread_mps,
)
from curbside.localize.ronin.infer import load_model

MS_ONLY = Path(__file__).parent.parent / "benchmarks" / "weights" / "ronin_ms_only.pt"


def _windows(n: int = 20, seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).normal(size=(n, 6, 200)).astype(np.float32)


def test_a_yaw_equivariant_velocity_has_no_spread_and_a_fixed_axis_one_has(monkeypatch):
    """The answers are turned back by the angle their input was turned by: a velocity that turns with
    its input (the mean horizontal acceleration) agrees with itself under every turn."""
    def turning(model, windows, batch_size=None):
        return windows[:, 3:5].mean(axis=2).astype(np.float64)

    def fixed_axis(model, windows, batch_size=None):
        return np.column_stack([windows[:, 3].mean(axis=1), np.zeros(len(windows))])

    windows = _windows()
    monkeypatch.setattr(familiarity_module, "infer_windows", turning)
    assert np.max(yaw_spread_mps(turned_velocities(None, windows))) < 1e-6
    monkeypatch.setattr(familiarity_module, "infer_windows", fixed_axis)
    assert np.min(yaw_spread_mps(turned_velocities(None, windows))) > 1e-3
    with pytest.raises(ValueError, match="at least 2"):
        turned_velocities(None, windows, turns=1)


def test_the_spread_does_not_depend_on_the_frame_s_yaw():
    """Turning the input by one of the turns permutes the answers and turns them all alike."""
    model = load_model(None)
    windows = _windows(8, seed=1)
    turned = windows.copy()
    c, s = np.cos(np.pi / 3), np.sin(np.pi / 3)
    for base in (0, 3):
        x, y = windows[:, base], windows[:, base + 1]
        turned[:, base], turned[:, base + 1] = c * x - s * y, s * x + c * y
    spreads = [yaw_spread_mps(turned_velocities(model, w)) for w in (windows, turned)]
    assert np.allclose(*spreads, atol=1e-5)


def test_a_standing_walker_gives_no_verdict(monkeypatch):
    """Every model reads a still phone as still under every turn: those windows say nothing."""
    def still(model, windows, batch_size=None):
        return np.zeros((len(windows), 2))

    monkeypatch.setattr(familiarity_module, "infer_windows", still)
    verdict = familiarity(None, np.arange(200) * 0.1, _windows(200))
    assert verdict.familiar is None and verdict.windows == 0
    assert verdict.to_dict()["spread_mps"] is None
    assert "cannot tell whether the RoNIN model knows this recording: 0 of its windows" in verdict.describe()


def test_the_bundled_model_knows_an_ipin_trial_and_a_model_that_never_saw_the_venue_does_not():
    imu = read_any(TRIAL).imu
    home = session_familiarity(load_model(None), imu)
    unseen = session_familiarity(load_model(MS_ONLY), imu)
    assert home.familiar and home.spread_mps < 0.1
    assert not unseen.familiar and unseen.spread_mps > 1.3 * UNFAMILIAR_SPREAD_MPS
    assert min(home.windows, unseen.windows) > 30


def test_localize_ronin_says_whether_the_model_knows_the_recording(tmp_path, capsys):
    out = tmp_path / "v.csv"
    assert localize_main(["ronin", TRIAL, "-o", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "v.csv: the RoNIN model knows this recording: yaw-equivariance spread 0.0" in printed
    assert localize_main(["ronin", TRIAL, "-o", str(out), "--overwrite", "--weights", str(MS_ONLY)]) == 0
    assert "the RoNIN model does not know this recording" in capsys.readouterr().out


def test_ronin_eval_reports_the_spread_per_recording_and_the_familiar_count(tmp_path, capsys):
    out = tmp_path / "report.json"
    h5 = TRIAL.split("::")[0]
    argv = ["ronin-eval", "--ipin", h5, "--split", "train", "--no-pdr", "-o", str(out)]
    assert localize_main(argv) == 0
    report = json.loads(out.read_text())
    records = [r["ronin"] for r in report["recordings"].values()]
    assert len(records) == 2 and all(r["familiar"] is True for r in records)
    assert all(0 < r["yaw_spread_mps"] <= UNFAMILIAR_SPREAD_MPS and r["early_yaw_spread_mps"] > 0
               and r["walking_windows"] > 20 for r in records)
    summary = report["summary"]["ipin"]["ronin"]
    assert summary["familiar"] == 2
    assert summary["yaw_spread_mps_median"] == np.median([r["yaw_spread_mps"] for r in records])
    assert f"{summary['yaw_spread_mps_median']:>10.3f}   2/2" in capsys.readouterr().out


def test_ronin_eval_gives_no_spread_for_recordings_too_short_to_tell(ronin_dir, tmp_path):  # noqa: F811
    out = tmp_path / "report.json"
    assert localize_main(["ronin-eval", "--ronin-h5", str(ronin_dir), "--no-pdr", "-o", str(out)]) == 0
    report = json.loads(out.read_text())
    (record,) = report["recordings"].values()
    assert record["ronin"]["familiar"] is None and record["ronin"]["yaw_spread_mps"] is None
    assert "yaw_spread_mps_median" not in report["summary"]["ronin"]["ronin"]


def test_localize_run_records_whether_the_model_knows_the_recording(tmp_path, capsys):
    out = tmp_path / "run"
    argv = ["run", TRIAL, "--mode", "fused", "--ronin-weights", str(MS_ONLY), "-o", str(out)]
    assert localize_main(argv) == 0
    record = json.loads((out / "run.json").read_text())["ronin_familiarity"]
    assert record["familiar"] is False and record["spread_mps"] > UNFAMILIAR_SPREAD_MPS
    assert "the RoNIN model does not know this recording" in capsys.readouterr().out
    assert localize_main(["run", TRIAL, "--mode", "fused", "--velocity-source", "pdr", "-o",
                          str(tmp_path / "pdr")]) == 0
    assert json.loads((tmp_path / "pdr" / "run.json").read_text())["ronin_familiarity"] is None
