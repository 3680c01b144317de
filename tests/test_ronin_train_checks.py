"""Audit of ``localize train-ronin``: what a run records, interruption and resumption, checkpoints and
prepared caches of other data, runs without validation, bad options."""

from __future__ import annotations

import json

import pytest
import torch
from test_ronin_data import write_ronin_sequence
from test_ronin_train import interrupted_in_epoch_two

from curbside.cli.localize import main as localize_main
from curbside.errors import CurbsideInputError
from curbside.localize.ronin import data
from curbside.localize.ronin import train as train_mod
from curbside.localize.ronin.data import WindowSet, read_ronin_dir
from curbside.localize.ronin.train import TrainOptions, train

TINY = ["--epochs", "1", "--windows-per-epoch", "64", "--batch-size", "32", "--threads", "1"]


def _sequences(root, names):
    for k, name in enumerate(names):
        write_ronin_sequence(root / name, speed=1.0 + 0.2 * k, heading=0.5 * k, duration_s=8.0, seed=k)
    return root


@pytest.fixture(scope="module")
def with_val(tmp_path_factory):
    """RoNIN-layout sequences in train (walk0, walk1), validation (walk5) and test (walk2)."""
    return _sequences(tmp_path_factory.mktemp("with_val"), ["walk0", "walk1", "walk2", "walk5"])


@pytest.fixture(scope="module")
def no_val(tmp_path_factory):
    """Sequences in train (seq0, seq1) and test (seq2) only."""
    return _sequences(tmp_path_factory.mktemp("no_val"), ["seq0", "seq1", "seq2"])


def _windows(root):
    recs = read_ronin_dir(root, progress=False)
    return WindowSet.build(recs, 200, 10, 200.0)


def _options(**kw):
    return TrainOptions(**{"epochs": 2, "windows_per_epoch": 64, "batch_size": 32, "seed": 1,
                           "num_threads": 1, **kw})


def test_ronin_layout_sequences_get_a_validation_split():
    assert data.split_of("ronin/walk5", "ronin") == "val"
    names = [f"s{i}" for i in range(2000)]
    share = sum(data.split_of(f"ronin/{n}", "ronin") == "val" for n in names) / len(names)
    assert 0.05 < share < 0.09


def test_weights_record_data_split_software_and_calibration(with_val, tmp_path, capsys):
    out = tmp_path / "w.pt"
    assert localize_main(["train-ronin", "--ronin-h5", str(with_val), *TINY, "-o", str(out)]) == 0
    assert "best epoch 1 of 1, val MSE" in capsys.readouterr().out
    extra = json.loads(out.with_suffix(".json").read_text())["extra"]
    assert extra["data"][0]["source"] == "ronin" and len(extra["data"][0]["sha256"]) == 64
    assert extra["split"]["salt"] == data.SPLIT_SALT
    assert extra["recordings"] == {"train": 2, "val": 1, "test": 1}
    assert extra["software"]["torch"] == torch.__version__
    assert extra["arguments"]["seed"] == 0
    assert extra["output_scale_from"] == "median distance ratio on 1 validation recordings"


def test_without_validation_the_last_epoch_is_kept_and_said_so(no_val, tmp_path, capsys, caplog):
    out = tmp_path / "w.pt"
    assert localize_main(["train-ronin", "--ronin-h5", str(no_val), *TINY, "-o", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "last epoch 1 (no validation), output scale 1.000" in printed and "val MSE" not in printed
    assert "no validation recordings" in caplog.text
    config = json.loads(out.with_suffix(".json").read_text())
    assert config["output_scale"] == 1.0 and config["extra"]["val_loss"] is None
    assert config["extra"]["output_scale_from"].startswith("not calibrated")


def test_the_whole_history_is_recorded_not_only_up_to_the_best_epoch(with_val, tmp_path, monkeypatch):
    losses = iter([0.5, 0.3, 0.4])
    monkeypatch.setattr(train_mod, "evaluate_loss", lambda *a, **k: next(losses))
    ws = _windows(with_val)
    train(ws, ws, _options(epochs=3), tmp_path / "w.pt", progress=False)
    extra = json.loads((tmp_path / "w.json").read_text())["extra"]
    assert extra["best_epoch"] == 2 and extra["val_loss"] == 0.3
    assert [h["epoch"] for h in extra["history"]] == [1, 2, 3]


def test_an_interrupted_run_writes_no_weights_and_resumes_to_the_same_ones(with_val, tmp_path):
    ws = _windows(with_val)
    train(ws, ws, _options(), tmp_path / "full.pt", progress=False)
    out, ckpt = tmp_path / "r.pt", tmp_path / "r.ckpt"
    with interrupted_in_epoch_two(), pytest.raises(KeyboardInterrupt):
        train(ws, ws, _options(), out, checkpoint=ckpt, progress=False)
    assert not out.exists() and not out.with_suffix(".json").exists() and ckpt.is_file()
    train(ws, ws, _options(), out, checkpoint=ckpt, progress=False)
    full, resumed = (torch.load(p, weights_only=True) for p in (tmp_path / "full.pt", out))
    assert all(torch.equal(full[k], resumed[k]) for k in full)


def test_ctrl_c_exits_130_and_says_how_to_resume_on_one_line(with_val, tmp_path, capsys, monkeypatch):
    real, calls = train_mod._train_epoch, {"n": 0}

    def interrupted_in_epoch_two(*args, **kwargs):
        calls["n"] += 1
        if calls["n"] == 2:
            raise KeyboardInterrupt
        return real(*args, **kwargs)

    monkeypatch.setattr(train_mod, "_train_epoch", interrupted_in_epoch_two)
    out, ckpt = tmp_path / "w.pt", tmp_path / "w.ckpt"
    argv = ["train-ronin", "--ronin-h5", str(with_val), *TINY, "--epochs", "2", "--checkpoint", str(ckpt),
            "-o", str(out)]
    assert localize_main(argv) == 130
    err = capsys.readouterr().err
    assert err == (f"localize: interrupted: nothing written to {out}; rerun the same command to resume "
                   f"from {ckpt}\n")
    assert not out.exists() and not out.with_suffix(".json").exists() and ckpt.is_file()


def test_a_checkpoint_of_other_data_is_refused(with_val, no_val, tmp_path):
    a, b = _windows(with_val), _windows(no_val)
    ckpt = tmp_path / "c.ckpt"
    train(a, a, _options(epochs=1), tmp_path / "a.pt", checkpoint=ckpt, progress=False)
    with pytest.raises(CurbsideInputError, match="other data"):
        train(b, b, _options(epochs=1), tmp_path / "b.pt", checkpoint=ckpt, progress=False)


def test_a_checkpoint_that_is_not_one_is_an_input_error_and_kept(with_val, tmp_path, capsys):
    notes = tmp_path / "notes.txt"
    notes.write_text("my notes")
    argv = ["train-ronin", "--ronin-h5", str(with_val), *TINY, "--checkpoint", str(notes),
            "-o", str(tmp_path / "w.pt")]
    assert localize_main(argv) == 2
    err = capsys.readouterr().err
    assert f"{notes}: not a train-ronin checkpoint" in err and len(err.strip().splitlines()) == 1
    assert notes.read_text() == "my notes"


def test_a_prepared_cache_of_other_data_is_refused(with_val, no_val, tmp_path):
    prepared = tmp_path / "p.npz"
    first = data.prepare_recordings(ronin_dir=with_val, prepared=prepared, progress=False)
    again = data.prepare_recordings(ronin_dir=with_val, prepared=prepared, progress=False)
    assert [r.name for r in again] == [r.name for r in first]
    with pytest.raises(CurbsideInputError, match="was prepared from --ronin-h5"):
        data.prepare_recordings(ronin_dir=no_val, prepared=prepared, progress=False)
    assert data.prepared_sources(prepared)[0]["source"] == "ronin"


def test_weights_named_json_are_refused_before_training(with_val, tmp_path, capsys):
    out = tmp_path / "w.json"
    assert localize_main(["train-ronin", "--ronin-h5", str(with_val), *TINY, "-o", str(out)]) == 2
    assert "name the weights .pt" in capsys.readouterr().err
    assert not out.exists()


@pytest.mark.parametrize(("option", "value"), [("--epochs", "0"), ("--windows-per-epoch", "0"),
                                               ("--batch-size", "0"), ("--lr", "-1"), ("--threads", "0")])
def test_bad_numbers_are_usage_errors(with_val, tmp_path, capsys, option, value):
    argv = ["train-ronin", "--ronin-h5", str(with_val), *TINY, option, value, "-o", str(tmp_path / "w.pt")]
    with pytest.raises(SystemExit) as exc:
        localize_main(argv)
    assert exc.value.code == 2
    assert option in capsys.readouterr().err


def test_a_checkpoint_on_the_weights_path_is_refused_before_training(with_val, tmp_path, capsys):
    out = tmp_path / "w.pt"
    argv = ["train-ronin", "--ronin-h5", str(with_val), *TINY, "--checkpoint", str(out), "-o", str(out)]
    assert localize_main(argv) == 2
    assert "the checkpoint needs a file of its own" in capsys.readouterr().err
    assert not out.exists()
