"""Session-bootstrap intervals: the weighted quantile, pairing, coverage of the point figure."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from curbside.evaluate.uncertainty import (
    MIN_BOOTSTRAP_UNITS,
    SessionSamples,
    bootstrap_intervals,
    map_intervals,
    session_draws,
    waypoint_intervals,
    weighted_quantile,
)


def _run(session: str, correct: np.ndarray, euclid: np.ndarray, method: str = "fused") -> dict:
    errors = pd.DataFrame({"euclid_m": euclid, "across_m": euclid / 2, "correct": correct,
                           "missing": np.zeros(len(euclid), bool)})
    return {"session": session, "errors": errors, "spec": {"method": method}}


def _runs(rng: np.random.Generator, p_correct: float, error_scale_m: float, sessions: int = 8) -> list[dict]:
    runs = []
    for k in range(sessions):
        n = int(rng.integers(50, 200))
        session_p = np.clip(p_correct + rng.normal(0, 0.05), 0, 1)  # sessions differ, as walks do
        runs.append(_run(f"s{k}", rng.random(n) < session_p, rng.gamma(2.0, error_scale_m, n)))
    return runs


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 10_000), st.sampled_from([0.1, 0.5, 0.9]))
def test_weighted_quantile_is_numpys_quantile_of_the_repeated_sample(seed, q):
    rng = np.random.default_rng(seed)
    values = rng.normal(size=int(rng.integers(1, 60)))
    owner = rng.integers(0, 4, len(values))
    order = np.argsort(values)
    counts = np.vstack([np.ones(4, int), rng.integers(0, 4, 4)])
    got = weighted_quantile(values[order], owner[order], counts, q)
    assert got[0] == pytest.approx(np.percentile(values, 100 * q))
    repeated = np.repeat(values, counts[1][owner])
    if len(repeated):
        assert got[1] == pytest.approx(np.percentile(repeated, 100 * q))
    else:
        assert np.isnan(got[1])


def test_weighted_quantile_counts_repeat_a_session():
    rng = np.random.default_rng(3)
    values = rng.normal(size=40)
    owner = np.repeat([0, 1], 20)
    order = np.argsort(values)
    counts = np.array([[2, 1], [0, 3]])
    got = weighted_quantile(values[order], owner[order], counts, 0.5)
    assert got[0] == pytest.approx(np.percentile(np.r_[values[:20], values[:20], values[20:]], 50))
    assert got[1] == pytest.approx(np.percentile(values[20:], 50))


def test_draws_are_seeded_and_keep_the_session_count():
    a, b = session_draws(6, 50, seed=1), session_draws(6, 50, seed=1)
    assert np.array_equal(a, b) and (a.sum(axis=1) == 6).all()
    assert not np.array_equal(a, session_draws(6, 50, seed=2))


def test_intervals_cover_the_pooled_figure_and_lie_within_the_sessions():
    runs = _runs(np.random.default_rng(0), 0.8, 2.0)
    frame = bootstrap_intervals({"fused": runs}, n_resamples=400).set_index("metric")
    pooled_csa = sum(r["errors"]["correct"].sum() for r in runs) / sum(len(r["errors"]) for r in runs)
    per_session = [r["errors"]["correct"].mean() for r in runs]
    assert frame.at["csa", "lo"] <= pooled_csa <= frame.at["csa", "hi"]
    assert min(per_session) <= frame.at["csa", "lo"] and frame.at["csa", "hi"] <= max(per_session)
    median = np.median(np.concatenate([r["errors"]["euclid_m"] for r in runs]))
    assert frame.at["euclid_median_m", "lo"] <= median <= frame.at["euclid_median_m", "hi"]


def test_paired_differences_see_a_clear_winner_and_a_tie():
    rng = np.random.default_rng(1)
    better, worse = _runs(rng, 0.9, 1.0), _runs(rng, 0.6, 4.0)
    for r in worse:
        r["spec"]["method"] = "paper"
    frame = bootstrap_intervals({"paper": worse, "fused": better, "gnss": better}, n_resamples=300)
    diff = frame[frame["method"] == "fused - paper"].set_index("metric")
    assert diff.at["csa", "lo"] > 0 and diff.at["euclid_p90_m", "hi"] < 0
    assert (diff["better_share"] == 1.0).all()
    tie = frame[frame["method"] == "fused - gnss"]  # the same runs: every paired difference is 0
    assert (tie["lo"] == 0).all() and (tie["hi"] == 0).all() and (tie["better_share"] == 0).all()


def test_several_runs_of_a_session_pool_into_it():
    rng = np.random.default_rng(2)
    runs = _runs(rng, 0.7, 2.0, sessions=3)
    again = [_run(r["session"], r["errors"]["correct"].to_numpy(), r["errors"]["euclid_m"].to_numpy())
             for r in runs]
    samples = SessionSamples.from_runs(runs + again, ("s0", "s1", "s2"))
    assert np.array_equal(samples.steps, 2 * np.array([len(r["errors"]) for r in runs]))
    assert len(samples.values["euclid_m"][0]) == samples.steps.sum()


def test_waypoint_intervals_resample_whole_trials_and_render():
    from curbside.evaluate.benchmark import ipin_interval_table
    from curbside.evaluate.criteria import IPIN_BASELINE_RUN

    rng = np.random.default_rng(4)
    sizes = [12, 15, 9, 14, 11]
    rows, fused, old = [], [], []
    for k, n in enumerate(sizes):
        for method in ("fused", IPIN_BASELINE_RUN):
            rows.append({"trial": f"t{k}", "method": method, "n_waypoints": n, "median_m": 0.0})
        base = rng.gamma(2.0, 2.0, n)
        fused.append(base)
        old.append(base + 1.0)  # 0.1 is 1 m worse at every waypoint
    errors = {"fused": np.concatenate(fused), IPIN_BASELINE_RUN: np.concatenate(old), "gnss": np.zeros(3)}
    frame = waypoint_intervals(errors, rows, "fused", (IPIN_BASELINE_RUN, "gnss"), n_resamples=300)
    assert "gnss" not in set(frame["method"])  # not scored at the same waypoints: left out
    diff = frame[frame["method"] == f"fused - {IPIN_BASELINE_RUN}"].set_index("metric")
    assert diff.at["euclid_p90_m", "hi"] < 0 and diff.at["euclid_median_m", "better_share"] == 1.0
    assert "csa" not in set(frame["metric"])  # waypoints have no sidewalks
    fused = frame[frame["method"] == "fused"].set_index("metric")
    assert fused.at["euclid_p90_m", "value"] == pytest.approx(np.percentile(errors["fused"], 90))
    assert diff.at["euclid_median_m", "value"] == pytest.approx(
        np.median(errors["fused"]) - np.median(errors[IPIN_BASELINE_RUN]))
    md = ipin_interval_table(frame, "IPIN").markdown()
    assert "| curbside fused - curbside fused 0.1 |" in md and "100 %" in md
    assert f"| curbside fused | {np.median(errors['fused']):.1f} [" in md


def test_waypoint_intervals_pool_filter_seeds_by_trial():
    rows = [{"trial": t, "method": m, "n_waypoints": n, "median_m": 0.0}
            for t, n in (("a", 3), ("b", 5)) for m in ("fused", "old")]
    one_seed = {"fused": np.r_[1.0, 1, 1, 9, 9, 9, 9, 9], "old": np.r_[2.0, 2, 2, 9, 9, 9, 9, 9]}
    two_seeds = {m: np.r_[e, e] for m, e in one_seed.items()}
    frame = waypoint_intervals(two_seeds, rows + rows, "fused", ("old",), n_resamples=200, min_units=2)
    diff = frame[frame["method"] == "fused - old"].set_index("metric")
    # The median moves off trial "b"'s 9 m only when "a" is drawn twice (p = 1/4): then fused is 1 m better.
    assert diff.at["euclid_median_m", "lo"] == -1.0 and diff.at["euclid_median_m", "hi"] == 0.0
    assert diff.at["euclid_median_m", "better_share"] == pytest.approx(0.25, abs=0.08)


def test_map_intervals_pair_the_maps_on_the_same_sessions():
    rng = np.random.default_rng(5)
    good, bad = _runs(rng, 0.9, 1.0), _runs(rng, 0.5, 5.0)
    spec = {"jaywalk_weight": 0.4, "particles": 500, "gnss_sigma_factor": None}
    results = []
    for map_name, runs in (("osm", good), ("datasf", bad)):
        for r in runs:
            results.append({**r, "spec": {**spec, "method": "fused", "map_name": map_name,
                                          "session": f"/x/paper6/{r['session']}"}})
    results.append({**good[0], "spec": {**spec, "method": "fused", "map_name": "osm", "particles": 100,
                                        "session": "/x/paper6/s0"}})  # another N: left out
    frame = map_intervals(results, {"map": "osm", "jaywalk_weight": 0.4, "particles": 500})
    assert list(frame["method"].drop_duplicates()) == ["osm", "datasf", "datasf - osm"]
    diff = frame[frame["method"] == "datasf - osm"].set_index("metric")
    assert diff.at["csa", "hi"] < 0 and diff.at["csa", "better_share"] == 0.0
    assert set(frame["subset"]) == {"paper6"}
    assert map_intervals(results, {"map": "osm", "jaywalk_weight": 1.0}).empty  # no run at that w


def test_no_sidewalks_and_no_estimates_give_no_csa_and_n_a_cells(recwarn):
    from curbside.evaluate.report import interval_table

    rng = np.random.default_rng(6)
    no_sidewalks = [_run(f"s{k}", np.zeros(30, bool), rng.gamma(2.0, 2.0, 30)) for k in range(5)]
    for r in no_sidewalks:
        r["errors"] = r["errors"].drop(columns=["correct", "across_m"])
    never_started = [_run(f"s{k}", np.zeros(30, bool), np.full(30, np.nan)) for k in range(5)]
    for r in never_started:
        r["errors"]["missing"] = True
        r["errors"] = r["errors"].drop(columns=["correct", "across_m"])
    frame = bootstrap_intervals({"fused": no_sidewalks, "gnss": never_started}, n_resamples=50)
    assert set(frame["metric"]) == {"euclid_median_m", "euclid_p90_m"}
    assert frame.query("method == 'fused'")[["lo", "hi"]].notna().all().all()
    assert frame.query("method != 'fused'")[["lo", "hi"]].isna().all().all()
    md = interval_table(frame, "t", "n").markdown()
    assert "| GNSS | n/a | n/a |" in md
    assert not [w for w in recwarn if "All-NaN" in str(w.message)]


@pytest.mark.parametrize("sessions", [1, MIN_BOOTSTRAP_UNITS - 1])
def test_too_few_sessions_give_no_interval_and_say_why(sessions, monkeypatch):
    from curbside.evaluate.report import interval_table, records
    from curbside.evaluate.uncertainty import SessionSamples

    resampled_rows = []
    statistics = SessionSamples.statistics
    monkeypatch.setattr(SessionSamples, "statistics",
                        lambda self, counts: resampled_rows.append(len(counts)) or statistics(self, counts))
    rng = np.random.default_rng(7)
    fused, paper = _runs(rng, 0.9, 1.0, sessions), _runs(rng, 0.6, 4.0, sessions)
    frame = bootstrap_intervals({"paper": paper, "fused": fused}, n_resamples=100)
    assert max(resampled_rows) == 1  # the point figures only: no resample computed and thrown away
    assert frame[["lo", "hi"]].isna().all().all() and frame["better_share"].isna().all()
    assert frame["value"].notna().all()  # the point figures stay
    plural = "session" if sessions == 1 else "sessions"
    assert (frame["reason"] == f"{sessions} {plural}: an interval needs at least {MIN_BOOTSTRAP_UNITS} "
            "sessions to resample").all()
    row = records(frame)[0]
    assert row["lo"] is None and row["hi"] is None and row["n_units"] == sessions
    md = interval_table(frame, "t", "n").markdown()
    assert f"| curbside fused - paper PF | n/a ({sessions} {plural}) |" in md and "[" not in md
    assert f"fewer than {MIN_BOOTSTRAP_UNITS} sessions" in md


def test_enough_sessions_give_intervals_and_no_reason():
    frame = bootstrap_intervals({"fused": _runs(np.random.default_rng(8), 0.8, 2.0, MIN_BOOTSTRAP_UNITS)},
                                n_resamples=100)
    assert frame[["lo", "hi"]].notna().all().all() and frame["reason"].isna().all()
    assert (frame["n_units"] == MIN_BOOTSTRAP_UNITS).all() and (frame["unit"] == "sessions").all()
