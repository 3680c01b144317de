"""Benchmark subsets and splits: disjoint, reproducible by name, sessions reused and never clobbered."""

from __future__ import annotations

import json

import numpy as np
import pytest

from curbside.cli import localize_evaluate_args
from curbside.errors import CurbsideInputError
from curbside.evaluate import gnss_model, simulate, subsets


@pytest.fixture(scope="module")
def world():
    return subsets.load_world()


def test_splits_have_disjoint_seeds_and_distinct_simulator_seeds():
    test, tune = subsets.session_seeds("test", 5), subsets.session_seeds("tune", 5)
    assert test == (1, 2, 3, 4, 5) and not set(test) & set(tune)
    sim_seeds = {
        subsets.simulator_seed(sub, split, i, s)
        for sub in subsets.SUBSETS
        for split in subsets.SPLITS
        for i in range(8)
        for s in range(1, 4)
    }
    assert len(sim_seeds) == len(subsets.SUBSETS) * len(subsets.SPLITS) * 8 * 3
    with pytest.raises(CurbsideInputError, match="seeds"):
        subsets.session_seeds("test", 101)
    with pytest.raises(CurbsideInputError, match="split"):
        subsets.session_seeds("train", 3)


def test_cli_choices_match_the_library():
    assert tuple(simulate.PROFILES) == localize_evaluate_args.PROFILES
    assert tuple(gnss_model.GNSS_MODELS) == localize_evaluate_args.GNSS_MODELS


@pytest.mark.slow
def test_routes_are_reproducible_and_differ_between_splits(world):
    test_a = subsets.benchmark_routes("downtown", "test", 2, world)
    test_b = subsets.benchmark_routes("downtown", "test", 2, world)
    tune = subsets.benchmark_routes("downtown", "tune", 2, world)
    for a, b in zip(test_a, test_b, strict=True):
        np.testing.assert_array_equal(a.xy, b.xy)
    assert {r.spec.name for r in test_a} == {"downtown-01", "downtown-02"}
    for a, t in zip(test_a, tune, strict=True):
        assert a.seed != t.seed and not np.array_equal(a.xy[:2], t.xy[:2])
    lo, hi = subsets.RANDOM_LENGTH_M
    assert all(lo - 1 <= r.length_m <= hi + 1 for r in test_a)
    paper_test = subsets.benchmark_routes("paper6", "test", world=world)
    paper_tune = subsets.benchmark_routes("paper6", "tune", world=world)
    assert [r.spec.name for r in paper_test] == [f"path{i}" for i in range(1, 7)]
    assert any(not np.array_equal(a.xy, b.xy) for a, b in zip(paper_test, paper_tune, strict=True))


@pytest.mark.slow
def test_open_routes_are_under_open_sky(world):
    (route,) = subsets.benchmark_routes("open", "test", 1, world)
    assert route.extra["sky_severity_mean"] <= subsets.OPEN_MAX_SEVERITY
    sev, covered, built = world.at(route.xy)
    assert sev.max() <= subsets.OPEN_PEAK_SEVERITY and not covered.any()


@pytest.mark.slow
def test_sessions_are_written_reused_and_foreign_folders_refused(world, tmp_path):
    out = tmp_path / "downtown"
    (first,) = subsets.benchmark_sessions(out, "downtown", "test", "phone", 1, 1, world)
    meta = json.loads((first / "meta.json").read_text())["simulation"]
    assert (meta["subset"], meta["split"], meta["session_seed"], meta["profile"]) == (
        "downtown",
        "test",
        1,
        "phone",
    )
    assert meta["seed"] == subsets.simulator_seed("downtown", "test", 0, 1)
    stamp = (first / "velocity.csv").stat().st_mtime_ns
    subsets.benchmark_sessions(out, "downtown", "test", "phone", 1, 1, world)
    assert (first / "velocity.csv").stat().st_mtime_ns == stamp  # reused, not simulated again
    subsets.benchmark_sessions(out, "downtown", "test", "nominal", 1, 1, world)
    assert json.loads((first / "meta.json").read_text())["simulation"]["profile"] == "nominal"
    manifest = json.loads((out / "benchmark.json").read_text())
    assert manifest["sessions"] == [first.name] and manifest["profile"] == "nominal"
    foreign = tmp_path / "mine"
    (foreign / first.name).mkdir(parents=True)
    (foreign / first.name / "notes.txt").write_text("not a session")
    with pytest.raises(CurbsideInputError, match="not a curbside simulated session"):
        subsets.benchmark_sessions(foreign, "downtown", "test", "phone", 1, 1, world)
    assert (foreign / first.name / "notes.txt").read_text() == "not a session"
