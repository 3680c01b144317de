"""A stranger's bad inputs to ``localize ronin``, ``train-ronin`` and ``ronin-eval``: each is one line on
stderr naming the file and the problem, exit status 2, and nothing half-written or overwritten."""

from __future__ import annotations

import json
import shutil

import h5py
import numpy as np
import pytest
import torch
from serve_fixtures import TRIAL
from test_ronin_data import write_ronin_sequence

from curbside.cli.localize import main as localize_main
from curbside.errors import CurbsideInputError
from curbside.localize.paths import config_path_for
from curbside.localize.ronin import train as train_mod
from curbside.localize.ronin.data import Recording
from curbside.localize.ronin.evaluate import calibrate_output_scale
from curbside.localize.ronin.infer import load_model
from curbside.localize.ronin.model import RoninConfig, RoninResNet
from curbside.localize.ronin.train import save_weights

TINY = ["--epochs", "1", "--windows-per-epoch", "32", "--batch-size", "32", "--threads", "1"]


@pytest.fixture(scope="module")
def seqs(tmp_path_factory):
    """RoNIN-layout sequences in train (walk0, walk1), validation (walk5) and test (walk2)."""
    root = tmp_path_factory.mktemp("seqs")
    for k, name in enumerate(["walk0", "walk1", "walk2", "walk5"]):
        write_ronin_sequence(root / name, speed=1.0 + 0.2 * k, heading=0.5 * k, duration_s=6.0, seed=k)
    return root


@pytest.fixture(scope="module")
def prepared(seqs, tmp_path_factory):
    path = tmp_path_factory.mktemp("prepared") / "p.npz"
    argv = ["train-ronin", "--ronin-h5", str(seqs), "--prepared", str(path), *TINY,
            "-o", str(path.with_name("w.pt"))]
    assert localize_main(argv) == 0
    return path


def _fails(argv, capsys, *expected: str) -> str:
    """Run ``localize``; it must exit 2 with one line on stderr holding every ``expected``."""
    capsys.readouterr()
    assert localize_main([str(a) for a in argv]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and err.startswith("localize: error: "), err
    for text in expected:
        assert text in err, err
    return err


def test_a_data_hdf5_that_is_a_folder_is_an_input_error(tmp_path, capsys):
    (tmp_path / "walk0" / "data.hdf5").mkdir(parents=True)
    _fails(["train-ronin", "--ronin-h5", tmp_path, *TINY, "-o", tmp_path / "w.pt"], capsys,
           "walk0/data.hdf5: is not a file")
    _fails(["ronin-eval", "--ronin-h5", tmp_path, "--no-pdr", "-o", tmp_path / "report.json"], capsys,
           "walk0/data.hdf5: is not a file")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["walk0"]


def test_data_paths_of_the_wrong_kind_are_named_as_such(seqs, tmp_path, capsys):
    out = ["-o", tmp_path / "w.pt"]
    _fails(["train-ronin", "--ronin-h5", tmp_path / "absent", *TINY, *out], capsys, "absent: no such folder")
    _fails(["train-ronin", "--ronin-h5", seqs / "walk0" / "data.hdf5", *TINY, *out], capsys,
           "data.hdf5: is a file; --ronin-h5 takes the folder")
    _fails(["train-ronin", "--ms-indoor", seqs, *TINY, *out], capsys,
           "is a folder; --ms-indoor takes an HDF5")
    _fails(["train-ronin", "--ipin", tmp_path / "absent.h5", *TINY, *out], capsys,
           "absent.h5: no such file (--ipin)")


@pytest.mark.parametrize("kind", ["truncated", "empty", "text", "folder"])
def test_a_prepared_file_that_is_not_one_is_an_input_error(prepared, tmp_path, capsys, kind):
    bad = tmp_path / "bad.npz"
    if kind == "truncated":
        bad.write_bytes(prepared.read_bytes()[:3000])
    elif kind == "empty":
        bad.write_bytes(b"")
    elif kind == "text":
        bad.write_text("t,ax\n0,1\n")
    else:
        bad.mkdir()
    expected = "is a folder; --prepared takes a file" if kind == "folder" else "not a prepared RoNIN dataset"
    _fails(["train-ronin", "--prepared", bad, *TINY, "-o", tmp_path / "w.pt"], capsys, f"bad.npz: {expected}")
    _fails(["ronin-eval", "--prepared", bad, "--no-pdr"], capsys, f"bad.npz: {expected}")


def test_the_weights_may_not_go_where_the_prepared_cache_is_written(seqs, tmp_path, capsys):
    cache = tmp_path / "cache.npz"
    _fails(["train-ronin", "--ronin-h5", seqs, "--prepared", cache, *TINY, "-o", cache], capsys,
           "cache.npz: is both --prepared and an output")
    assert not cache.exists() and not cache.with_suffix(".json").exists()


def test_an_evaluation_report_never_replaces_its_data(prepared, seqs, tmp_path, capsys):
    before = prepared.read_bytes()
    _fails(["ronin-eval", "--prepared", prepared, "--no-pdr", "-o", prepared, "--overwrite"], capsys,
           "is both --prepared and an output")
    assert prepared.read_bytes() == before
    copy = shutil.copytree(seqs, tmp_path / "seqs")
    sequence = copy / "walk2" / "data.hdf5"
    before = sequence.read_bytes()
    _fails(["ronin-eval", "--ronin-h5", copy, "--no-pdr", "-o", sequence, "--overwrite"], capsys,
           "is also an input of this command")
    assert sequence.read_bytes() == before


def test_non_finite_ground_truth_rows_are_dropped_not_trained_on(tmp_path, caplog):
    for k, name in enumerate(["walk0", "walk5"]):
        write_ronin_sequence(tmp_path / name, speed=1.0 + 0.2 * k, duration_s=6.0, seed=k)
    with h5py.File(tmp_path / "walk0" / "data.hdf5", "r+") as f:
        f["pose/tango_pos"][300, 0] = np.nan
    out = tmp_path / "w.pt"
    assert localize_main(["train-ronin", "--ronin-h5", str(tmp_path), *TINY, "-o", str(out)]) == 0
    assert "walk0/data.hdf5: 1 ground-truth row(s) with NaN or infinite values dropped" in caplog.text
    assert all(torch.isfinite(v).all() for v in torch.load(out, weights_only=True).values())
    assert np.isfinite(json.loads(config_path_for(out).read_text())["extra"]["history"][0]["train_loss"])


def test_a_diverging_run_stops_with_an_error_and_writes_nothing(seqs, tmp_path, capsys):
    out, ckpt = tmp_path / "w.pt", tmp_path / "w.ckpt"
    _fails(["train-ronin", "--ronin-h5", seqs, *TINY, "--lr", "1e9", "--checkpoint", ckpt, "-o", out], capsys,
           "epoch 1: the ", "training diverged; try a lower --lr")
    assert not out.exists() and not config_path_for(out).exists() and not ckpt.exists()


def _nan_weights(path):
    model = RoninResNet(RoninConfig.for_arch("compact"))
    with torch.no_grad():
        model.stem[0].weight[0, 0, 0] = float("nan")
    return save_weights(model, path)


def test_weights_with_nan_are_refused_before_any_velocity_is_written(tmp_path, capsys):
    weights, out = _nan_weights(tmp_path / "nan.pt"), tmp_path / "v.csv"
    _fails(["ronin", TRIAL, "--weights", weights, "-o", out], capsys,
           "nan.pt: NaN or infinite values in stem.0.weight")
    assert not out.exists()
    config = json.loads(config_path_for(weights).read_text())
    good = save_weights(RoninResNet(RoninConfig.from_dict(config)), tmp_path / "scale.pt")
    config_path_for(good).write_text(json.dumps({**config, "output_scale": float("nan")}))
    with pytest.raises(CurbsideInputError, match="scale.json: NaN or infinite feature_mean, feature_std"):
        load_model(good)


def test_weights_that_are_a_folder_or_lack_their_config_say_so(tmp_path, capsys):
    (tmp_path / "dir.pt").mkdir()
    out = ["-o", tmp_path / "v.csv"]
    _fails(["ronin", TRIAL, "--weights", tmp_path / "dir.pt", *out], capsys, "dir.pt: is a folder")
    lone = save_weights(RoninResNet(RoninConfig.for_arch("compact")), tmp_path / "lone.pt")
    config_path_for(lone).unlink()
    _fails(["ronin", TRIAL, "--weights", lone, *out], capsys,
           "lone.json: no such file: the config of lone.pt must sit beside it")


def test_an_unknown_device_is_a_usage_error_before_the_data_are_read(tmp_path, capsys):
    _fails(["train-ronin", "--ronin-h5", tmp_path / "never-read", *TINY, "--device", "banana",
            "-o", tmp_path / "w.pt"], capsys, "--device: 'banana' is not a torch device")


def test_an_interrupted_save_leaves_the_previous_weights_and_config_together(tmp_path, monkeypatch):
    out = tmp_path / "w.pt"
    torch.manual_seed(0)
    save_weights(RoninResNet(RoninConfig.for_arch("compact")), out)
    before = out.read_bytes(), config_path_for(out).read_bytes()

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(train_mod.json, "dumps", interrupted)  # Ctrl-C while the config is written
    with pytest.raises(KeyboardInterrupt):
        save_weights(RoninResNet(RoninConfig.for_arch("compact", dropout=0.1)), out)
    monkeypatch.undo()
    assert (out.read_bytes(), config_path_for(out).read_bytes()) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == [".curbside-output", "w.json", "w.pt"]


def test_an_output_scale_is_never_calibrated_to_nan():
    t = np.arange(0, 4, 0.005)
    still = Recording("ronin/still", "ronin", t, np.zeros((len(t), 6), np.float32),
                      np.column_stack([t, np.zeros_like(t), np.zeros_like(t)]), "val")
    model = RoninResNet(RoninConfig.for_arch("compact")).eval()
    assert calibrate_output_scale(model, [still]) == 1.0


@pytest.mark.parametrize("command", ["ronin", "train-ronin", "ronin-eval"])
def test_each_help_ends_with_examples(command, capsys):
    with pytest.raises(SystemExit):
        localize_main([command, "--help"])
    assert f"examples:\n  localize {command} " in capsys.readouterr().out


def test_weights_given_as_the_checkpoint_are_not_to_be_deleted(seqs, tmp_path, capsys):
    weights = save_weights(RoninResNet(RoninConfig.for_arch("compact")), tmp_path / "mine.pt")
    before = weights.read_bytes()
    err = _fails(["train-ronin", "--ronin-h5", seqs, *TINY, "--checkpoint", weights, "-o", tmp_path / "w.pt"],
                 capsys, "mine.pt: holds model weights, not a train-ronin checkpoint: give another")
    assert "delete" not in err and weights.read_bytes() == before
