"""The shipped RoNIN weights record what newly trained weights record (data, split, software, commit,
date...), reconstructed or "unknown", without a change to their tensors."""

from __future__ import annotations

import datetime
import hashlib
import json
import re
from pathlib import Path

import pytest
from test_ronin_data import write_ronin_sequence

from curbside import settings
from curbside.cli.localize import main as localize_main
from curbside.localize.paths import config_path_for
from curbside.localize.ronin.infer import load_model

ROOT = Path(__file__).resolve().parents[1]
BUNDLED = Path(settings.ronin_default_weights)
MS_ONLY = ROOT / "benchmarks" / "weights" / "ronin_ms_only.pt"
#: The SHA-256 of the shipped tensors (MODEL_CARD.md, benchmarks/weights): the provenance leaves them be.
WEIGHTS_SHA256 = {
    BUNDLED: "83509a56dc28edcd8fdca35bcd6d23c61cc70acaef512a6df1864299df7fe0f2",
    MS_ONLY: "0ef8a8a5f01687147612a7c63bb6e65a174ff0683c659c755f48c12a61d740c3",
}


@pytest.fixture(scope="module")
def new_extra(tmp_path_factory) -> dict:
    """The ``extra`` of weights that ``localize train-ronin`` writes now."""
    root = tmp_path_factory.mktemp("provenance")
    for k, name in enumerate(["walk0", "walk5"]):  # train and validation
        write_ronin_sequence(root / name, speed=1.0 + 0.2 * k, duration_s=6.0, seed=k)
    out = root / "w.pt"
    argv = ["train-ronin", "--ronin-h5", str(root), "--epochs", "1", "--windows-per-epoch", "32",
            "--batch-size", "32", "--threads", "1", "-o", str(out)]
    assert localize_main(argv) == 0
    return json.loads(config_path_for(out).read_text())["extra"]


def test_new_weights_record_the_commit_and_the_date(new_extra):
    assert "git_commit" in new_extra["software"]
    commit = new_extra["software"]["git_commit"]
    assert commit is None or re.fullmatch(r"[0-9a-f]{40}", commit)
    trained = datetime.datetime.fromisoformat(new_extra["trained_utc"])
    assert trained.utcoffset() == datetime.timedelta(0)


@pytest.mark.parametrize("weights", [BUNDLED, MS_ONLY], ids=["bundled", "ms_only"])
def test_shipped_weights_record_every_field_new_weights_record(weights, new_extra):
    extra = json.loads(config_path_for(weights).read_text())["extra"]
    assert set(new_extra) <= set(extra), sorted(set(new_extra) - set(extra))
    assert set(new_extra["software"]) <= set(extra["software"])
    assert {r["source"] for r in extra["data"]} == set(extra["sources"])
    assert all(re.fullmatch(r"[0-9a-f]{64}", r["sha256"]) for r in extra["data"])
    assert set(extra["split"]) == set(new_extra["split"])
    # What nobody recorded is said to be unknown, and where each reconstructed field came from.
    assert extra["trained_utc"] == "unknown" and extra["software"]["git_commit"] == "unknown"
    notes = extra["provenance_recorded_afterwards"]
    assert {"data", "split", "arguments", "software", "trained_utc", "git_commit", "weights_commit"} <= set(
        notes)


@pytest.mark.parametrize("weights", [BUNDLED, MS_ONLY], ids=["bundled", "ms_only"])
def test_shipped_weights_load_and_their_tensors_are_unchanged(weights):
    assert hashlib.sha256(weights.read_bytes()).hexdigest() == WEIGHTS_SHA256[weights]
    model = load_model(weights)
    assert model.config.extra["recordings"]["val"] == 66
