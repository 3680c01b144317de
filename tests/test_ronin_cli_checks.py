"""Audit of ``localize ronin`` and ``localize ronin-eval``: velocity.csv is what ``localize run`` would
compute, any recording ``localize run`` reads is accepted, configs are complete, reports say what
they scored."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest
from serve_fixtures import TRIAL
from test_ronin_data import write_ronin_sequence

from curbside.cli.localize import main as localize_main
from curbside.errors import CurbsideInputError
from curbside.localize.paths import config_path_for
from curbside.localize.readers import read_any
from curbside.localize.ronin.infer import load_model, ronin_velocity
from curbside.localize.ronin.model import RoninConfig, RoninResNet
from curbside.localize.ronin.train import save_weights
from curbside.localize.session import validate_table


def test_an_h5_trial_is_read_like_localize_run_reads_it(tmp_path, capsys):
    assert localize_main(["ronin", TRIAL]) == 2
    assert "name the velocity file with -o" in capsys.readouterr().err
    out = tmp_path / "v.csv"
    assert localize_main(["ronin", TRIAL, "-o", str(out)]) == 0
    expected = ronin_velocity(read_any(TRIAL).imu)
    written = validate_table("velocity", pd.read_csv(out), out)
    assert np.array_equal(written.to_numpy(), expected.to_numpy())
    assert localize_main(["ronin", TRIAL.replace("repetition01", "repetition99"), "-o", str(out)]) == 2
    assert "no such trial" in capsys.readouterr().err


def test_a_config_missing_keys_is_refused_not_defaulted(tmp_path):
    path = save_weights(RoninResNet(RoninConfig.for_arch("compact")), tmp_path / "m.pt")
    config = json.loads(config_path_for(path).read_text())
    del config["output_scale"], config["head_hidden"]
    config_path_for(path).write_text(json.dumps(config))
    with pytest.raises(CurbsideInputError, match="missing head_hidden, output_scale"):
        load_model(path)


@pytest.fixture(scope="module")
def ronin_dir(tmp_path_factory):
    """Sequences in train (walk0, walk1) and test (walk2)."""
    root = tmp_path_factory.mktemp("eval")
    for k, name in enumerate(["walk0", "walk1", "walk2"]):
        write_ronin_sequence(root / name, speed=1.0 + 0.2 * k, heading=0.5 * k, duration_s=8.0, seed=k)
    return root


def test_eval_report_names_the_weights_split_and_data(ronin_dir, tmp_path, capsys):
    out = tmp_path / "report.json"
    assert localize_main(["ronin-eval", "--ronin-h5", str(ronin_dir), "--no-pdr", "-o", str(out)]) == 0
    printed = capsys.readouterr().out
    assert printed.startswith("RoNIN weights ronin_compact.pt (sha256 ")
    assert "on the test split, a velocity every 100 ms\n" in printed
    assert "distances in m, speeds in m/s" in printed
    report = json.loads(out.read_text())
    assert report["split"] == "test" and len(report["weights"]["sha256"]) == 64
    assert report["weights"]["trained_on"] == ["ipin", "ms"]
    assert report["data"][0]["source"] == "ronin"
    assert list(report["recordings"]) == ["ronin/walk2"]


def test_eval_says_when_the_recordings_trained_the_weights(ronin_dir, tmp_path, capsys):
    weights = tmp_path / "w.pt"
    argv = ["train-ronin", "--ronin-h5", str(ronin_dir), "--epochs", "1", "--windows-per-epoch", "32",
            "--batch-size", "32", "--threads", "1", "-o", str(weights)]
    assert localize_main(argv) == 0
    capsys.readouterr()
    argv = ["ronin-eval", "--ronin-h5", str(ronin_dir), "--no-pdr", "--split", "train", "--weights",
            str(weights)]
    assert localize_main(argv) == 0
    assert "train recordings of ronin are not held out" in capsys.readouterr().out


def test_eval_of_an_empty_split_names_the_data(ronin_dir, capsys):
    assert localize_main(["ronin-eval", "--ronin-h5", str(ronin_dir), "--no-pdr", "--split", "val"]) == 2
    err = capsys.readouterr().err
    assert f"{ronin_dir.name}: no 'val' recordings" in err and len(err.strip().splitlines()) == 1
