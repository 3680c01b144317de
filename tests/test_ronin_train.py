"""RoNIN training: reproducible from a seed, resumable from checkpoints, usable end to end."""

from __future__ import annotations

import contextlib
from collections.abc import Iterator

import pytest
import torch
from test_ronin_data import write_ronin_sequence

from curbside.cli.localize import main as localize_main
from curbside.errors import CurbsideInputError
from curbside.localize.ronin import train as train_mod
from curbside.localize.ronin.data import WindowSet, read_ronin_dir
from curbside.localize.ronin.infer import load_model
from curbside.localize.ronin.train import TrainOptions, train


@pytest.fixture(scope="module")
def windows(tmp_path_factory):
    root = tmp_path_factory.mktemp("ronin")
    for k, (speed, heading) in enumerate([(1.0, 0.3), (1.4, -1.2), (0.8, 2.0)]):
        write_ronin_sequence(root / f"seq{k}", speed=speed, heading=heading, duration_s=8.0, seed=k)
    recs = read_ronin_dir(root, progress=False)
    return root, WindowSet.build(recs, 200, 10, 200.0)


def _options(**kw):
    base = {"epochs": 2, "windows_per_epoch": 128, "batch_size": 32, "seed": 3, "num_threads": 1}
    return TrainOptions(**{**base, **kw})


def _state(path):
    return torch.load(path, weights_only=True)


def test_same_seed_same_weights_other_seed_other_weights(windows, tmp_path):
    _, ws = windows
    train(ws, ws, _options(), tmp_path / "a.pt", progress=False)
    train(ws, ws, _options(), tmp_path / "b.pt", progress=False)
    train(ws, ws, _options(seed=4), tmp_path / "c.pt", progress=False)
    a, b, c = (_state(tmp_path / n) for n in ("a.pt", "b.pt", "c.pt"))
    assert all(torch.equal(a[k], b[k]) for k in a)
    assert not all(torch.equal(a[k], c[k]) for k in a)


@contextlib.contextmanager
def interrupted_in_epoch_two() -> Iterator[None]:
    """Inside the block, :func:`train` meets Ctrl-C at its second validation pass (epoch two)."""
    real = train_mod.evaluate_loss
    calls = {"n": 0}

    def evaluate_then_interrupt(*args, **kwargs):
        calls["n"] += 1
        if calls["n"] == 2:
            raise KeyboardInterrupt
        return real(*args, **kwargs)

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(train_mod, "evaluate_loss", evaluate_then_interrupt)
        yield


def test_interrupted_run_resumes_to_the_same_weights(windows, tmp_path):
    _, ws = windows
    history = train(ws, ws, _options(), tmp_path / "full.pt", checkpoint=tmp_path / "full.ckpt",
                    progress=False)
    assert [h["epoch"] for h in history] == [1, 2]

    with interrupted_in_epoch_two(), pytest.raises(KeyboardInterrupt):
        train(ws, ws, _options(), tmp_path / "r.pt", checkpoint=tmp_path / "r.ckpt", progress=False)
    resumed = train(ws, ws, _options(), tmp_path / "r.pt", checkpoint=tmp_path / "r.ckpt", progress=False)
    assert [h["epoch"] for h in resumed] == [1, 2]
    ckpt_full = _state(tmp_path / "full.ckpt")["model"]
    ckpt_resumed = _state(tmp_path / "r.ckpt")["model"]
    assert all(torch.allclose(ckpt_full[k].float(), ckpt_resumed[k].float()) for k in ckpt_full)


def test_checkpoint_of_other_options_is_refused(windows, tmp_path):
    _, ws = windows
    train(ws, ws, _options(epochs=1), tmp_path / "a.pt", checkpoint=tmp_path / "a.ckpt", progress=False)
    with pytest.raises(CurbsideInputError, match="other options"):
        train(ws, ws, _options(epochs=1, seed=9), tmp_path / "a.pt", checkpoint=tmp_path / "a.ckpt",
              progress=False)


def test_train_command_end_to_end(windows, tmp_path, capsys):
    root, _ = windows
    out = tmp_path / "w.pt"
    args = ["train-ronin", "--ronin-h5", str(root), "--epochs", "1", "--windows-per-epoch", "64",
            "--batch-size", "32", "--threads", "1", "-o", str(out)]
    assert localize_main(args) == 0
    assert out.is_file() and out.with_suffix(".json").is_file()
    assert load_model(out).config.arch == "compact"
    assert localize_main(["train-ronin", "-o", str(out)]) == 2
    assert "no recordings given" in capsys.readouterr().err
    if not torch.cuda.is_available():
        assert localize_main(["train-ronin", "--device", "cuda", "-o", str(out)]) == 2
        assert "CUDA" in capsys.readouterr().err
