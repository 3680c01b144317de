"""The benchmark harness: the plan, a small end-to-end report with its done-when section, bad input."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import pandas as pd
import pytest

from curbside.cli.localize import main
from curbside.errors import CurbsideInputError
from curbside.evaluate import criteria, suite
from curbside.evaluate import simulate as sim
from curbside.evaluate.figures import is_base
from curbside.evaluate.report_tables import PAPER_NOTE
from curbside.evaluate.runner import run_all
from curbside.evaluate.suite_ipin import FAMILIAR_VELOCITY_RUN, UNSEEN_VELOCITY_RUN, ipin_runs, ipin_summary
from curbside.evaluate.suite_report import figure_base, sweep_table, write_suite_report
from curbside.localize.filter import FilterConfig
from curbside.localize.session import write_session
from curbside.osmseg.mapio import read_map

MAP = Path(__file__).parent / "data" / "evaluate" / "sf-path3.geojson"
IPIN_CUT = Path(__file__).parent / "data" / "sessions" / "ipin2023-cut.h5"
MS_ONLY = Path(__file__).parents[1] / "benchmarks" / "weights" / "ronin_ms_only.pt"


@pytest.fixture(scope="module")
def sessions(tmp_path_factory) -> dict[str, list[Path]]:
    """Path 3 (the fixture map's route) in the phone profile, filed under two subsets."""
    route_list, frame, osm = sim.sf6_routes()
    route = next(r for r in route_list if r.spec.name == "path3")
    root = tmp_path_factory.mktemp("suite")
    config = sim.SimulationConfig(profile="phone")
    out = {}
    for subset, seed in (("paper6", 1), ("open", 2)):
        session = sim.simulate_session(route, osm, frame, seed, config, name=f"path3-s{seed}")
        out[subset] = [write_session(session, root / subset / session.name)]
    return out


def test_plan_runs_every_method_sweeps_paper6_and_adds_datasf(sessions):
    config = suite.SuiteConfig(subsets=("paper6", "open"), sweep_weights=(0.0, 0.4, 1.0), particles=100,
                               fused_particles=300)
    specs = suite.plan_suite(sessions, {"osm": str(MAP), "datasf": str(MAP)}, config)
    paper6 = [s for s in specs if "paper6" in s.session]
    open_ = [s for s in specs if "/open/" in s.session]
    # paper6: gnss + 3 filters x 3 weights + DataSF paper and fused; open: gnss + 3 filters + DataSF
    assert len(paper6) == 1 + 9 + 2 and len(open_) == 1 + 3 + 2
    assert {(s.method, s.jaywalk_weight) for s in open_ if s.map_name == "osm"} == {
        ("gnss", 0.4),
        ("inertial", 0.4),
        ("paper", 0.4),
        ("fused", 0.4),
    }
    assert all(s.metrics_map == str(MAP) for s in specs)
    # the paper's N for its methods, curbside fused's own (its default unless set)
    assert all(s.particles == (300 if s.method == "fused" else 100) for s in specs)
    assert suite.SuiteConfig().particles_of("fused") == FilterConfig().n_particles
    snapshots = [s for s in specs if s.snapshot_times]
    assert {s.method for s in snapshots} == {"inertial", "paper", "fused"}
    assert all("paper6" in s.session and s.jaywalk_weight == 0.4 for s in snapshots)


def test_more_filter_seeds_repeat_every_filter_run_but_not_gnss(sessions):
    open_only = {"open": sessions["open"]}
    one = suite.plan_suite(open_only, {"osm": str(MAP)}, suite.SuiteConfig(subsets=("open",), filter_seed=5))
    three = suite.plan_suite(
        open_only, {"osm": str(MAP)}, suite.SuiteConfig(subsets=("open",), filter_seed=5, filter_seeds=3)
    )
    assert [s.seed for s in three if s.method == "gnss"] == [5]
    assert sorted(s.seed for s in three if s.method == "fused") == [5, 6, 7]
    assert len(three) == len(one) + 2 * sum(s.method != "gnss" for s in one)
    assert all(not s.snapshot_times for s in three if s.seed != 5)
    with pytest.raises(CurbsideInputError, match="--filter-seeds"):
        suite.SuiteConfig(filter_seeds=0)


def test_unseen_velocity_runs_curbside_fused_with_the_preset_and_nothing_else(sessions):
    maps = {"osm": str(MAP), "datasf": str(MAP)}
    subsets = ("paper6", "open")
    plain = suite.plan_suite(sessions, maps, suite.SuiteConfig(subsets=subsets))
    preset = suite.plan_suite(sessions, maps, suite.SuiteConfig(subsets=subsets, unseen_velocity="on"))
    assert [dataclasses.replace(s, overrides=()) for s in preset] == plain
    assert all(dict(s.overrides) == {"unseen_velocity.mode": "on"} for s in preset if s.method == "fused")
    assert not any(s.overrides for s in preset if s.method != "fused")
    assert sum(s.method == "fused" and s.map_name == "datasf" for s in preset) == 2
    runs = ipin_runs(suite.SuiteConfig())
    judged = ipin_runs(suite.SuiteConfig(unseen_velocity="on"))
    assert set(runs) == {criteria.IPIN_BASELINE_RUN, UNSEEN_VELOCITY_RUN, FAMILIAR_VELOCITY_RUN}
    assert set(judged) == {criteria.IPIN_BASELINE_RUN, FAMILIAR_VELOCITY_RUN, "fused"}
    assert runs[FAMILIAR_VELOCITY_RUN].familiar_velocity.mode == "auto"
    assert judged["fused"] == runs[UNSEEN_VELOCITY_RUN]
    assert judged[criteria.IPIN_BASELINE_RUN] == runs[criteria.IPIN_BASELINE_RUN]
    assert judged["fused"].unseen_velocity.mode == "on"
    assert judged[criteria.IPIN_BASELINE_RUN].unseen_velocity.mode == "off"
    off = ipin_runs(suite.SuiteConfig(unseen_velocity="off"))
    assert off["fused"].unseen_velocity.mode == "off" and off[UNSEEN_VELOCITY_RUN] == judged["fused"]
    assert all(s.overrides == (("unseen_velocity.mode", "off"),) for s in suite.plan_suite(
        sessions, maps, suite.SuiteConfig(subsets=subsets, unseen_velocity="off")) if s.method == "fused")
    with pytest.raises(CurbsideInputError, match="--unseen-velocity"):
        suite.SuiteConfig(unseen_velocity="sometimes")


@pytest.mark.slow
def test_report_has_tables_checks_and_figures(sessions, tmp_path):
    config = suite.SuiteConfig(subsets=("paper6", "open"), sweep_weights=(0.0, 0.4), particles=100,
                               filter_seeds=2)
    specs = suite.plan_suite(sessions, {"osm": str(MAP)}, config)
    results = run_all(specs, workers=1, progress=False)
    pooled = suite.pooled_by_subset(results)
    per_session = suite.pooled_by_subset(results, ("session",))
    assert set(pooled["subset"]) == {"paper6", "open"}
    checks = criteria.done_when(pooled, per_session, 0.4)
    run_info = {"suite": {}, "simulation": sim.SimulationConfig(profile="phone").as_dict(), "workers": 1}
    paths = write_suite_report(
        results,
        tmp_path / "report",
        config,
        pooled,
        per_session,
        checks,
        read_map(MAP),
        run_info,
        {"track_s": 1.0},
        [ipin_summary(IPIN_CUT, range(0, 1), ipin_runs(config), MS_ONLY)],
    )
    md = paths["report.md"].read_text()
    assert "no map, RoNIN ronin_ms_only.pt): error at surveyed waypoints" in md
    assert "IPIN 2023, RoNIN ronin_ms_only.pt: how sure (m)" in md and "not trained on these trials" in md
    assert "| curbside fused, --unseen-velocity |" in md
    assert "Done when (issue 9)" in md and "| fused beats the paper's method on CSA | paper6 |" in md
    assert "paper PF" in md and "curbside fused" in md and "Per session, open" in md
    assert "Table 2. Correct Sidewalk Assignment by jaywalk weight, paper6" in md
    table2_note = sweep_table(pooled, "paper6").note
    assert PAPER_NOTE in table2_note and table2_note in md  # the evaluation report's note, word for word
    assert "Simulation profile 'phone'" in md and "OpenStreetMap" in md
    assert "How sure: 95 % intervals" in md and "| open | curbside fused - GNSS |" in md
    assert "filter seeds 0-1 pooled" in md
    assert f"N = 100 (curbside fused {config.particles_of('fused')})" in md
    fused_open = pooled.query("subset == 'open' and method == 'fused'")
    assert fused_open["n_runs"].iat[0] == 2  # both seeds of the one session pool into one row
    # the figures show every method at its own particle count (fused runs with more than the paper's)
    shown = {r["spec"]["method"] for r in results if is_base(r, figure_base(config))}
    assert shown == {"gnss", "inertial", "paper", "fused"}
    assert config.particles_of("fused") != config.particles_of("paper")
    figures = {p.name for p in (tmp_path / "report" / "figures").iterdir()}
    assert {
        "fig1_tracks_paper6.png",
        "fig1_tracks_open.png",
        "fig3_particles.png",
        "fig4_cdf.png",
        "fig5_per_route_open.png",
        "fig6_sessions.png",
        "fig7_reliability.png",
    } <= figures
    html = paths["report.html"].read_text()
    assert html.count("data:image/png;base64,") == len(figures)
    doc = json.loads(paths["metrics.json"].read_text())
    assert doc["done_when"]["overall"] == criteria.overall(checks)
    assert doc["ipin_held_out"] is None and doc["ipin_unseen_ronin"]["fused"]["n"] > 0
    assert {r["method"] for r in doc["ipin_unseen_ronin_intervals_95"]} >= {"fused", "fused - gnss"}
    intervals = pd.DataFrame(doc["intervals_95"])
    fused_csa = intervals.query("subset == 'open' and method == 'fused' and metric == 'csa'").iloc[0]
    # one session in 'open': too few to resample, so no interval, and the reason instead
    assert pd.isna(fused_csa["lo"]) and pd.isna(fused_csa["hi"])
    assert fused_csa["reason"].startswith("1 session:")
    assert "| open | curbside fused | n/a (1 session) |" in md
    assert fused_csa["value"] == pytest.approx(fused_open["csa"].iat[0])  # the pooled table's figure
    assert "How far to trust segment_prob and accuracy_m, w = 0.4" in md and "| open | curbside fused |" in md
    trust = pd.DataFrame(doc["segment_prob_reliability"])
    assert set(trust["method"]) == {"inertial", "paper", "fused"}  # GNSS alone names no sidewalk
    fused_trust = trust.query("subset == 'open' and method == 'fused'").iloc[0]
    assert 0 < fused_trust["footsteps"] <= fused_open["n_steps"].iat[0]  # both seeds pooled, off crossings
    assert 1.0 >= fused_trust["coverage_0.5"] >= fused_trust["coverage_0.9"] >= fused_trust["coverage_0.99"]
    assert sum(b["footsteps"] for b in fused_trust["bins"]) == fused_trust["footsteps"]  # fig7's points
    assert 0.0 <= fused_trust["accuracy_coverage"] <= 1.0 and fused_trust["accuracy_median_m"] > 0
    ratios = pd.DataFrame(doc["session_ratios"])
    assert set(ratios["session"]) == {"path3-s1", "path3-s2"} and (ratios["ratio"] > 0).all()
    assert doc["session_events"]["path3-s1"]["jumps"] >= 0
    doc["suite"] = {"profile": "phone", "split": "test", "jaywalk_weight": 0.4}
    paths["metrics.json"].write_text(json.dumps(doc))
    summary = suite.suite_summary(tmp_path / "report")
    assert "paper6 (1 session)" in summary and "curbside fused" in summary and "done when:" in summary


def test_benchmark_cli_refuses_a_bad_ipin_ronin_before_simulating(tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["benchmark", "--ipin-ronin", str(MS_ONLY), "-o", str(out)]) == 2
    assert capsys.readouterr().err.strip().splitlines()[-1] == (
        "localize: error: --ipin-ronin: needs --ipin (the trials to score)")
    missing = tmp_path / "none.pt"
    assert main(["benchmark", "--ipin", str(IPIN_CUT), "--ipin-ronin", str(missing), "-o", str(out)]) == 2
    assert capsys.readouterr().err.strip().splitlines()[-1] == (
        f"localize: error: {missing}: no such RoNIN weights file")
    assert not out.exists()


def test_benchmark_cli_bad_input(tmp_path, capsys):
    out = tmp_path / "out"
    with pytest.raises(SystemExit) as usage:
        main(["benchmark", "--subsets", "pocket", "-o", str(out)])
    assert usage.value.code == 2
    assert main(["benchmark", "--datasf-tiles", str(tmp_path / "missing.topojson"), "-o", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1] == f"localize: error: {tmp_path / 'missing.topojson'}: no such DataSF tile file"
    assert not out.exists()


def test_the_persistent_gnss_model_is_recorded_and_its_sessions_are_filed_apart(tmp_path, monkeypatch):
    from curbside.evaluate.gnss_model import GnssErrorModel

    config = suite.SuiteConfig(gnss="persistent", subsets=("open",))
    assert config.simulation().gnss == GnssErrorModel.named("persistent")
    assert suite.SuiteConfig().simulation().gnss == GnssErrorModel()  # the scored model by default
    with pytest.raises(CurbsideInputError, match="unknown GNSS model 'foggy'"):
        suite.SuiteConfig(gnss="foggy")
    calls = []
    monkeypatch.setattr(suite, "load_world", lambda osm_file=None: None)
    monkeypatch.setattr(suite, "benchmark_sessions",
                        lambda out, subset, split, **kw: calls.append((out, kw["config"])) or [])
    suite.simulate_suite(tmp_path, config)
    suite.simulate_suite(tmp_path, suite.SuiteConfig(subsets=("open",)))
    assert [c[0] for c in calls] == [tmp_path / "sessions" / "phone-persistent" / "test" / "open",
                                     tmp_path / "sessions" / "phone" / "test" / "open"]
    assert calls[0][1].gnss.continuous_axes and not calls[1][1].gnss.continuous_axes
