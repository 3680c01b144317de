"""``localize run --ronin-weights``: a researcher's own RoNIN model in the run, recorded in ``run.json``
and used again by its replay; refused where the run would not use it; bad weights as ``localize ronin``
refuses them."""

from __future__ import annotations

import json
import logging
import shutil
from pathlib import Path

import pytest
import torch
from serve_fixtures import TRIAL

from curbside import settings
from curbside.cli.localize import main
from curbside.errors import CurbsideInputError
from curbside.localize.paths import config_path_for
from curbside.localize.pipeline import track_session
from curbside.localize.readers import read_any
from curbside.localize.ronin.model import RoninConfig, RoninResNet
from curbside.localize.ronin.provenance import weights_record
from curbside.localize.ronin.train import save_weights

RUN = ["--particles", "200"]


def tiny_weights(path: Path, seed: int = 0, **config) -> Path:
    """A small, untrained RoNIN model (``config``: other :class:`RoninConfig` values)."""
    torch.manual_seed(seed)
    shape = {"blocks": [1, 1], "base_channels": 8, "head_channels": 8, "head_hidden": 16, **config}
    return save_weights(RoninResNet(RoninConfig.for_arch("compact", **shape)), path)


@pytest.fixture(scope="module")
def walk(tmp_path_factory) -> Path:
    """A real IPIN walk as a session folder: imu.csv, gnss.csv, meta.json, no velocity.csv."""
    folder = tmp_path_factory.mktemp("ronin_weights") / "walk"
    folder.mkdir()
    session = read_any(TRIAL)
    session.imu.to_csv(folder / "imu.csv", index=False)
    session.gnss.to_csv(folder / "gnss.csv", index=False)
    (folder / "meta.json").write_text(json.dumps({"start": session.meta["start"]}))
    return folder


@pytest.fixture(autouse=True)
def _cache_in_tmp(tmp_path, monkeypatch):
    monkeypatch.setattr(settings, "cache_dir", tmp_path / "cache")


def _run(*argv) -> int:
    return main(["run", *map(str, argv)])


def _inputs(out: Path) -> dict:
    return json.loads((out / "run.json").read_text())["inputs"]


def test_own_weights_track_as_localize_ronin_then_run_and_not_as_the_bundled_ones(walk, tmp_path):
    weights = tiny_weights(tmp_path / "my.pt")
    assert _run(walk, *RUN, "--ronin-weights", weights, "-o", tmp_path / "mine") == 0
    assert _run(walk, *RUN, "-o", tmp_path / "bundled") == 0
    recorded = _inputs(tmp_path / "mine")["ronin_weights"]
    assert recorded["path"] == str(weights.resolve()) and recorded["bundled"] is False
    assert len(recorded["sha256"]) == len(recorded["config_sha256"]) == 64
    assert _inputs(tmp_path / "bundled")["ronin_weights"]["bundled"] is True
    session = tmp_path / "session"
    shutil.copytree(walk, session)
    assert main(["ronin", str(session), "--weights", str(weights)]) == 0
    assert _run(session, *RUN, "-o", tmp_path / "from_file") == 0
    assert json.loads((tmp_path / "from_file" / "run.json").read_text())["velocity_source"] == "file"
    mine = (tmp_path / "mine" / "track.csv").read_bytes()
    assert mine == (tmp_path / "from_file" / "track.csv").read_bytes()
    assert mine != (tmp_path / "bundled" / "track.csv").read_bytes()


def _changed(caplog) -> list[str]:
    return [r.getMessage() for r in caplog.records if "changed since the run" in r.getMessage()]


def test_a_replay_runs_the_recorded_weights_and_names_them_when_changed_or_gone(walk, tmp_path, caplog,
                                                                               capsys):
    weights = tiny_weights(tmp_path / "my.pt")
    assert _run(walk, *RUN, "--ronin-weights", weights, "-o", tmp_path / "mine") == 0
    run_json, track = tmp_path / "mine" / "run.json", (tmp_path / "mine" / "track.csv").read_bytes()
    with caplog.at_level(logging.WARNING):
        assert _run("--config", run_json, "-o", tmp_path / "again") == 0
    assert not _changed(caplog) and (tmp_path / "again" / "track.csv").read_bytes() == track
    assert _inputs(tmp_path / "again")["ronin_weights"]["path"] == str(weights.resolve())

    moved = tmp_path / "elsewhere" / "my.pt"
    moved.parent.mkdir()
    for path in (weights, config_path_for(weights)):
        shutil.move(path, moved.parent / path.name)
    capsys.readouterr()
    assert _run("--config", run_json, "-o", tmp_path / "gone") == 2
    assert capsys.readouterr().err == (
        f"localize: error: {weights.resolve()}: no such file (the RoNIN weights {run_json} was run with; "
        "give where they are now: --ronin-weights PT, with its .json beside it)\n"
    )
    assert not (tmp_path / "gone").exists()
    assert _run("--config", run_json, "--ronin-weights", moved, "-o", tmp_path / "moved") == 0
    assert (tmp_path / "moved" / "track.csv").read_bytes() == track

    tiny_weights(moved, seed=1)  # other weights under the same name
    with caplog.at_level(logging.WARNING):
        assert _run("--config", run_json, "--ronin-weights", moved, "-o", tmp_path / "other") == 0
    [line] = _changed(caplog)
    assert f"the RoNIN weights {moved.resolve()}" in line
    assert (tmp_path / "other" / "track.csv").read_bytes() != track


def test_a_bundled_run_replays_with_the_bundled_model_as_installed_now(walk, tmp_path, caplog):
    """A run.json from another installation (or from before ``bundled`` was recorded) names the bundled
    weights at a path that is not here."""
    assert _run(walk, *RUN, "-o", tmp_path / "bundled") == 0
    info = json.loads((tmp_path / "bundled" / "run.json").read_text())
    record = info["inputs"]["ronin_weights"]
    info["inputs"]["ronin_weights"] = {"path": "/elsewhere/ronin_compact.pt", "sha256": record["sha256"]}
    (tmp_path / "old.json").write_text(json.dumps(info))
    with caplog.at_level(logging.WARNING):
        assert _run("--config", tmp_path / "old.json", "-o", tmp_path / "again") == 0
    assert not _changed(caplog)
    again, bundled = (tmp_path / name / "track.csv" for name in ("again", "bundled"))
    assert again.read_bytes() == bundled.read_bytes()


@pytest.mark.parametrize(
    ("options", "why"),
    [
        (["--velocity-source", "pdr"], "the velocity comes from PDR (velocity source pdr)"),
        (["--velocity-source", "file"], "the velocity comes from velocity.csv (velocity source file)"),
        (["--mode", "gnss"], "--mode gnss tracks without inertial velocity"),
        (["--set", "engine.velocity_source=pdr"], "the velocity comes from PDR"),
    ],
)
def test_weights_the_run_would_not_use_are_refused(walk, tmp_path, capsys, options, why):
    weights = tiny_weights(tmp_path / "my.pt")
    assert _run(walk, *options, "--ronin-weights", weights, "-o", tmp_path / "out") == 2
    assert capsys.readouterr().err.startswith(f"localize: error: --ronin-weights: not used: {why}")
    assert not (tmp_path / "out").exists()


def test_weights_are_refused_where_auto_reads_velocity_csv(walk, tmp_path, capsys):
    weights = tiny_weights(tmp_path / "my.pt")
    session = tmp_path / "session"
    shutil.copytree(walk, session)
    assert main(["ronin", str(session)]) == 0
    assert _run(session, "--ronin-weights", weights, "-o", tmp_path / "out") == 2
    assert "--ronin-weights: not used: " in capsys.readouterr().err and not (tmp_path / "out").exists()
    assert _run(session, *RUN, "--velocity-source", "ronin", "--ronin-weights", weights,
                "-o", tmp_path / "ronin") == 0
    assert _inputs(tmp_path / "ronin")["ronin_weights"]["path"] == str(weights.resolve())


def _bad_weights(tmp_path: Path) -> dict[str, Path]:
    good = tiny_weights(tmp_path / "good.pt")
    corrupt = tmp_path / "corrupt.pt"
    corrupt.write_bytes(good.read_bytes()[:100])
    shutil.copy(config_path_for(good), config_path_for(corrupt))
    other = tmp_path / "other.pt"  # the bundled architecture's tensors with the tiny model's config
    shutil.copy(settings.ronin_default_weights, other)
    shutil.copy(config_path_for(good), config_path_for(other))
    return {"missing": tmp_path / "missing.pt", "corrupt": corrupt, "other architecture": other,
            "other window": tiny_weights(tmp_path / "w50.pt", window=50)}


def test_bad_weights_get_the_error_localize_ronin_gives(walk, tmp_path, capsys):
    for name, weights in _bad_weights(tmp_path).items():
        capsys.readouterr()
        assert main(["ronin", str(walk), "--weights", str(weights), "-o", str(tmp_path / "v.csv")]) == 2, name
        expected = capsys.readouterr().err
        assert _run(walk, "--ronin-weights", weights, "-o", tmp_path / "out") == 2, name
        assert capsys.readouterr().err == expected, name
        assert len(expected.splitlines()) == 1 and not (tmp_path / "out").exists(), name


def test_own_weights_that_cannot_run_are_an_error_under_auto_not_a_fall_back_to_pdr(tmp_path):
    session = read_any(TRIAL)
    with pytest.raises(CurbsideInputError, match=r"w\.pt: trained on 50-sample windows"):
        track_session(session, None, "fused", particles=100, ronin_weights=tiny_weights(tmp_path / "w.pt",
                                                                                          window=50))


def test_the_weights_record_ignores_the_training_record_but_not_the_model_fields(tmp_path):
    # Adding provenance to a config's ``extra`` read as other weights on replay (a warning on every
    # run.json made before); a model field such as the output scale must still count.
    weights = tiny_weights(tmp_path / "w.pt")
    config_path = weights.with_suffix(".json")
    before = weights_record(weights)
    config = json.loads(config_path.read_text())
    config.setdefault("extra", {})["provenance_recorded_afterwards"] = {"trained_utc": "unknown"}
    config_path.write_text(json.dumps(config, indent=1))
    assert weights_record(weights) == before
    config["output_scale"] = config.get("output_scale", 1.0) * 1.01
    config_path.write_text(json.dumps(config))
    assert weights_record(weights)["config_sha256"] != before["config_sha256"]
