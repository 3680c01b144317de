"""``localize simulate`` / ``localize evaluate``: plans, reports, dask == serial, and bad input."""

from __future__ import annotations

import json
import logging
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from curbside.cli.localize import main
from curbside.evaluate import dask_cluster, runner
from curbside.evaluate.benchmark import plan
from curbside.localize.paths import expand_sessions

MAP = Path(__file__).parent / "data" / "evaluate" / "sf-path3.geojson"


@pytest.fixture(scope="module")
def sessions(tmp_path_factory) -> list[Path]:
    """Two simulated recordings of the benchmark's path 3 (the fixture map is clipped around it)."""
    root = tmp_path_factory.mktemp("sessions")
    out = []
    for seed in (1, 2):
        assert (
            main(
                [
                    "simulate",
                    "--route",
                    "path3",
                    "--seed",
                    str(seed),
                    "--map",
                    str(MAP),
                    "-o",
                    str(root / f"path3-s{seed}"),
                ]
            )
            == 0
        )
        out.append(root / f"path3-s{seed}")
    return out


def test_plan_sweeps_one_parameter_at_a_time(tmp_path, sessions):
    specs, base = plan(
        sessions,
        {"a": str(MAP), "b": str(MAP)},
        jaywalk_weights=(0.0, 0.4, 1.0),
        particles=(500, 100),
        gnss_sigma_factors=(None, 2.0),
        snapshots=False,
    )
    assert base == {"map": "a", "jaywalk_weight": 0.4, "particles": 500, "gnss_sigma_factor": None}
    fused = {(s.jaywalk_weight, s.particles, s.gnss_sigma_factor) for s in specs if s.method == "fused"}
    assert fused == {(0.0, 500, None), (0.4, 500, None), (1.0, 500, None), (0.4, 100, None), (0.4, 500, 2.0)}
    inertial = [s for s in specs if s.method == "inertial"]
    assert all(s.gnss_sigma_factor is None for s in inertial)
    paper = {(s.jaywalk_weight, s.particles, s.gnss_sigma_factor) for s in specs if s.method == "paper"}
    assert paper == fused
    # per session and map: 1 gnss + 4 inertial + 5 paper + 5 fused
    assert len(specs) == 2 * 2 * (1 + 4 + 5 + 5)


def test_expand_sessions(tmp_path, sessions):
    assert expand_sessions([sessions[0].parent]) == sorted(sessions)
    assert expand_sessions([sessions[1]]) == [sessions[1]]


@pytest.mark.slow
def test_dask_results_equal_serial(sessions):
    specs, _ = plan(
        sessions,
        {"osm": str(MAP)},
        methods=("gnss", "fused"),
        jaywalk_weights=(0.4,),
        particles=(100,),
        seed=3,
        snapshots=False,
    )
    serial = runner.run_all(specs, workers=1)
    parallel = runner.run_all(specs, workers=2)
    from dask.distributed import LocalCluster

    with LocalCluster(
        n_workers=1, processes=False, dashboard_address=":0", scheduler_kwargs={"dashboard": False}
    ) as cluster:
        existing = runner.run_all(specs, scheduler=cluster.scheduler_address)
    for a, b, c in zip(serial, parallel, existing, strict=True):
        assert a["spec"] == b["spec"] == c["spec"]
        pd.testing.assert_frame_equal(a["track"], b["track"])
        pd.testing.assert_frame_equal(a["track"], c["track"])
        assert a["metrics"] == b["metrics"] == c["metrics"]
        assert a["metrics_mode"] == b["metrics_mode"] == c["metrics_mode"]
        if a["spec"]["method"] == "gnss":  # no particles: the mode estimate is the estimate
            assert a["metrics_mode"] == a["metrics"]


def test_a_heartbeat_racing_the_shutdown_is_not_reported():
    quiet = dask_cluster.HeartbeatAtShutdown()
    message = "Failed to communicate with scheduler during heartbeat."
    record = logging.LogRecord("distributed.worker", logging.ERROR, "", 0, message, None, None)
    other = logging.LogRecord("distributed.worker", logging.ERROR, "", 0, "Compute Failed", None, None)
    assert not quiet.filter(record) and quiet.filter(other)


@pytest.mark.slow
def test_evaluate_writes_the_report(tmp_path, sessions):
    out = tmp_path / "report"
    rc = main(
        [
            "evaluate",
            str(sessions[0].parent),
            "--maps",
            str(MAP),
            str(MAP),
            "--map-names",
            "osm",
            "copy",
            "--jaywalk-weights",
            "0",
            "0.4",
            "--particles",
            "100",
            "--workers",
            "1",
            "-o",
            str(out),
        ]
    )
    assert rc == 0
    doc = json.loads((out / "metrics.json").read_text())
    pooled = pd.DataFrame(doc["pooled"])
    for name in (
        "csa",
        "euclid_mean_m",
        "euclid_median_m",
        "euclid_p90_m",
        "along_median_m",
        "across_median_m",
        "along_p90_m",
        "across_p90_m",
    ):
        assert name in pooled
    assert set(pooled["method"]) == {"gnss", "inertial", "paper", "fused"}
    assert set(pooled["map"]) == {"osm", "copy"}
    # the same map under two names gives the same numbers
    fused = pooled[(pooled["method"] == "fused") & (pooled["jaywalk_weight"] == 0.4)].set_index("map")
    assert fused.loc["osm", "csa"] == fused.loc["copy", "csa"]
    assert ((pooled["csa"] >= 0) & (pooled["csa"] <= 1)).all()
    # every metric again on the posterior-mode estimate; GNSS has no particles, so the same there
    assert ((pooled["csa_mode"] >= 0) & (pooled["csa_mode"] <= 1)).all()
    gnss = pooled[pooled["method"] == "gnss"]
    assert (gnss["csa_mode"] == gnss["csa"]).all()
    assert (gnss["euclid_median_m_mode"] == gnss["euclid_median_m"]).all()
    per_session = pd.DataFrame(doc["per_session"])
    assert set(per_session["session"]) == {"path3-s1", "path3-s2"}
    md = (out / "report.md").read_text()
    assert "Table 2" in md and "Table 3" in md and "Table 4" in md and "Map sources compared" in md
    assert "(0.80)" in md  # the paper's fused CSA at w = 0.4 beside ours
    assert "mean / posterior-mode estimate" in md
    # the base map only, its methods and paired differences, with figures that match the pooled table
    assert "How sure: 95 % intervals, w = 0.4, map 'osm'" in md and "| curbside fused - paper PF |" in md
    intervals = pd.DataFrame(doc["intervals_95"]).set_index(["method", "metric"])
    assert intervals.at[("fused", "csa"), "value"] == pytest.approx(fused.loc["osm", "csa"])
    # the same map under two names: every paired difference between them is exactly 0
    maps = pd.DataFrame(doc["map_intervals_95"])
    assert set(maps["method"]) == {"osm", "copy", "copy - osm"}
    same = maps[maps["method"] == "copy - osm"]
    assert (same["value"] == 0).all() and "How sure: map sources" in md
    # two sessions are too few to resample: no interval (null) and why, not a zero-width one
    assert intervals[["lo", "hi"]].isna().all().all() and maps[["lo", "hi"]].isna().all().all()
    assert intervals["reason"].str.startswith("2 sessions:").all()
    assert "| curbside fused - paper PF | n/a (2 sessions) |" in md and "[+0.00, +0.00]" not in md
    # segment_prob's reliability: the base map's filters, one group, no subset column
    assert "How far to trust segment_prob and accuracy_m, w = 0.4, map 'osm'" in md
    assert "| method | footsteps | calibration error | p >= 0.5: share / CSA |" in md
    trust = pd.DataFrame(doc["segment_prob_reliability"])
    assert trust["method"].tolist() == ["inertial", "paper", "fused"] and trust["subset"].isna().all()
    assert ((trust["calibration_error"] >= 0) & (trust["calibration_error"] <= 1)).all()
    assert trust["accuracy_coverage"].between(0, 1).all() and (trust["accuracy_median_m"] > 0).all()
    for row in doc["segment_prob_reliability"]:  # the radius scaled to other shares: held more often
        curve = pd.DataFrame(row["accuracy_curve"])
        assert curve["claimed"].tolist() == [0.5, 0.68, 0.8, 0.9, 0.95]
        assert curve["held"].is_monotonic_increasing
        assert curve.loc[curve["claimed"] == 0.68, "held"].item() == row["accuracy_coverage"]
    html = (out / "report.html").read_text()
    assert html.count("data:image/png;base64,") >= 4
    assert not (out / "figures" / "missing.png").exists()
    assert (out / "figures" / "fig4_cdf.png").stat().st_size > 1000
    assert (out / "figures" / "fig_reliability.png").stat().st_size > 1000


def _fails(capsys, argv: list[str], needle: str, out: Path | None = None) -> None:
    try:
        rc = main(argv)
    except SystemExit as exc:  # argparse usage errors
        rc = exc.code
    assert rc == 2
    err = capsys.readouterr().err
    assert needle in err and "Traceback" not in err
    assert len(err.strip().splitlines()) == 1
    if out is not None:
        assert not out.exists()


def test_bad_input(tmp_path, capsys, sessions):
    out = tmp_path / "r"
    _fails(
        capsys,
        ["evaluate", str(tmp_path / "nope"), "--maps", str(MAP), "-o", str(out)],
        "no such session folder",
        out,
    )
    empty = tmp_path / "empty"
    empty.mkdir()
    _fails(capsys, ["evaluate", str(empty), "--maps", str(MAP), "-o", str(out)], "folder of sessions", out)
    _fails(
        capsys,
        ["evaluate", str(sessions[0]), "--maps", str(tmp_path / "x.geojson"), "-o", str(out)],
        "no such map file",
        out,
    )
    bad = tmp_path / "bad.geojson"
    bad.write_text("{not json")
    _fails(capsys, ["evaluate", str(sessions[0]), "--maps", str(bad), "-o", str(out)], "bad.geojson", out)
    no_sidewalks = tmp_path / "buildings.geojson"
    doc = json.loads(MAP.read_text())
    doc["features"] = [f for f in doc["features"] if f["properties"]["class"] == "building"]
    no_sidewalks.write_text(json.dumps(doc))
    _fails(
        capsys,
        ["evaluate", str(sessions[0]), "--maps", str(no_sidewalks), "-o", str(out)],
        "no sidewalk segments",
        out,
    )
    _fails(
        capsys,
        ["evaluate", str(sessions[0]), "--maps", str(MAP), "--jaywalk-weights", "1.5", "-o", str(out)],
        "must lie in [0, 1]",
        out,
    )
    _fails(
        capsys,
        ["evaluate", str(sessions[0]), "--maps", str(MAP), str(MAP), "--map-names", "a", "a", "-o", str(out)],
        "one distinct name per map",
        out,
    )
    _fails(capsys, ["simulate", "--route", "path9", "-o", str(out)], "unknown route", out)
    _fails(
        capsys,
        ["simulate", "--route", "path3", "--map", str(_far_map(tmp_path)), "-o", str(out)],
        "outside the map",
        out,
    )


def test_session_without_waypoints_is_refused(tmp_path, sessions):
    import shutil

    from curbside.errors import CurbsideInputError

    copy = tmp_path / "nowp"
    shutil.copytree(sessions[0], copy)
    (copy / "waypoints.csv").unlink()
    with pytest.raises(CurbsideInputError, match="no waypoints.csv"):
        runner.run_one(runner.RunSpec(str(copy), "gnss", metrics_map=str(MAP)))


def test_simulated_session_is_scored_against_its_own_route(sessions):
    result = runner.run_one(runner.RunSpec(str(sessions[0]), "gnss", map_name="osm", metrics_map=str(MAP)))
    m = result["metrics"]
    assert m["n_steps"] > 300 and m["n_missing"] == 0
    assert 0 < m["euclid_median_m"] < 60
    assert np.isfinite(result["ate_m"]) and np.isfinite(result["rte_m"])


def test_ipin_table_scores_methods_at_the_same_waypoints():
    from curbside.evaluate.benchmark import ipin_table

    h5 = Path(__file__).parent / "data" / "sessions" / "ipin2023-cut.h5"
    (table, how_sure), rows = ipin_table(h5)
    frame = pd.DataFrame(rows)
    assert set(frame["method"]) == {"gnss", "inertial", "paper", "fused"}
    counts = frame.groupby("trial")["n_waypoints"].nunique()
    assert (counts == 1).all()  # every method at the same waypoints of a trial
    assert [r[0] for r in table.rows] == ["GNSS", "RoNIN+PF", "paper PF", "curbside fused"]
    n_trials = frame["trial"].nunique()
    assert table.header[-2:] == ["trials above GNSS", "accuracy_m held"] and table.rows[0][-2] == "–"
    assert all(r[-2].endswith(f" of {n_trials}") for r in table.rows[1:])
    # how often each track's accuracy_m held the walker at those waypoints (the phone's own for GNSS)
    assert ((frame["held"] >= 0) & (frame["held"] <= frame["n_waypoints"])).all()
    assert all(0.0 <= float(r[-1]) <= 1.0 for r in table.rows)
    # held out: only the repetition04 trials RoNIN never saw (none in this cut)
    assert [r[0] for r in how_sure.rows] == [
        "curbside fused", "curbside fused - paper PF", "curbside fused - GNSS"]
    (held_out,), _ = ipin_table(h5, held_out=True)  # no trial scored: no intervals
    assert "0 held-out trials" in held_out.title


def test_accuracy_held_pools_the_waypoints_of_every_trial_run():
    from curbside.evaluate.benchmark import accuracy_held

    rows = [{"trial": "a", "method": "fused", "n_waypoints": 4, "median_m": 1.0, "held": 3},
            {"trial": "b", "method": "fused", "n_waypoints": 6, "median_m": 1.0, "held": 2},
            {"trial": "a", "method": "gnss", "n_waypoints": 4, "median_m": 1.0, "held": 4},
            {"trial": "c", "method": "gnss", "n_waypoints": 0, "median_m": None, "held": 0},
            {"trial": "a", "method": "old", "n_waypoints": 4, "median_m": 1.0}]  # a row without the count
    assert accuracy_held(rows) == {"fused": pytest.approx(0.5), "gnss": 1.0}
    assert accuracy_held([]) == {}


def test_trials_above_gnss_pairs_each_trial_run_with_gnss_on_the_same_run():
    from curbside.evaluate.benchmark import trials_above_gnss

    def row(trial, method, median):
        return {"trial": trial, "method": method, "n_waypoints": 5, "median_m": median}

    seed0 = [row("a", "gnss", 5.0), row("a", "fused", 6.0), row("b", "gnss", 5.0), row("b", "fused", 4.0),
             row("c", "gnss", None), row("c", "fused", 9.0)]  # c: no waypoint scored
    seed1 = [row("a", "gnss", 5.0), row("a", "fused", 4.0), row("b", "gnss", 5.0), row("b", "fused", 7.0)]
    assert trials_above_gnss(seed0) == {"fused": (1, 2)}
    assert trials_above_gnss(seed0 + seed1) == {"fused": (2, 4)}  # a at seed 0, b at seed 1
    assert trials_above_gnss([row("a", "fused", 1.0)]) == {}


def test_ipin_errors_scores_an_extra_run_at_the_same_waypoints():
    from curbside.evaluate.benchmark import ipin_errors
    from curbside.localize.runconfig import RunConfig

    h5 = Path(__file__).parent / "data" / "sessions" / "ipin2023-cut.h5"
    coarse = RunConfig.for_mode("fused").with_overrides({"filter.n_particles": 50})
    errors, rows, _ = ipin_errors(h5, trials=1, extra_runs={"coarse": coarse})
    assert set(errors) == {"gnss", "inertial", "paper", "fused", "coarse"}
    assert len(errors["coarse"]) == len(errors["fused"]) > 0
    assert not np.array_equal(errors["coarse"], errors["fused"])  # really run with its own config
    assert len({r["n_waypoints"] for r in rows}) == 1


def test_ipin_errors_track_with_the_given_ronin_weights():
    from curbside import settings
    from curbside.evaluate.benchmark import ipin_errors

    h5 = Path(__file__).parent / "data" / "sessions" / "ipin2023-cut.h5"
    ms_only = Path(__file__).parents[1] / "benchmarks" / "weights" / "ronin_ms_only.pt"
    bundled, _, _ = ipin_errors(h5, trials=1)
    same, _, _ = ipin_errors(h5, trials=1, ronin_weights=settings.ronin_default_weights)
    other, _, _ = ipin_errors(h5, trials=1, ronin_weights=ms_only)
    for method, errors in bundled.items():
        np.testing.assert_array_equal(same[method], errors)  # inferred once, shared: same figures
    np.testing.assert_array_equal(other["gnss"], bundled["gnss"])  # GNSS alone uses no velocity
    assert not np.array_equal(other["inertial"], bundled["inertial"])


def test_ipin_errors_on_training_trials_leaves_the_held_out_ones_unread(monkeypatch):
    from curbside.evaluate.benchmark import ipin_errors
    from curbside.localize.readers import ipin

    h5 = Path(__file__).parent / "data" / "sessions" / "ipin2023-cut.h5"
    real = ipin.list_trials(h5)
    monkeypatch.setattr(ipin, "list_trials", lambda _: ["IPIN2023_T3_TrialXX_repetition04", *real])
    _, rows, n_trials = ipin_errors(h5, trials=1, training=True)  # the made-up trial would not read
    assert n_trials == 1 and {r["trial"] for r in rows} == {real[0]}
    with pytest.raises(Exception, match="repetition04"):
        ipin_errors(h5, trials=1)


def test_simulate_a_custom_route(tmp_path):
    from curbside.localize.session import read_session

    out = tmp_path / "custom"
    argv = [
        "simulate",
        "--route",
        "custom",
        "--start",
        "-122.3980",
        "37.7878",
        "--length-m",
        "150",
        "--jaywalks",
        "1",
        "--seed",
        "4",
        "-o",
        str(out),
    ]
    assert main(argv) == 0
    session = read_session(out)
    sim = session.meta["simulation"]
    assert (sim["route"], sim["jaywalks"], sim["crosswalk_crossings"]) == ("custom", 1, 0)
    assert sim["length_m"] == pytest.approx(150, abs=0.5)
    assert main(["simulate", "--route", "custom", "-o", str(tmp_path / "x")]) == 2
    # --gnss persistent: the same walk and velocity, fixes from the persistent model
    assert main([*argv[:-1], str(tmp_path / "persistent"), "--gnss", "persistent"]) == 0
    persistent = read_session(tmp_path / "persistent")
    gnss = persistent.meta["simulation"]["config"]["gnss"]
    assert gnss["tau_s"] == 300 and gnss["continuous_axes"] is True
    assert session.meta["simulation"]["config"]["gnss"]["continuous_axes"] is False
    pd.testing.assert_frame_equal(persistent.velocity, session.velocity)
    moved_deg = np.abs(persistent.gnss["lat"].to_numpy()[:50] - session.gnss["lat"].to_numpy()[:50])
    assert moved_deg.max() > 1e-5  # about a metre


def test_snapshot_moments_are_a_bad_fix_and_a_turn(sessions):
    from curbside.evaluate.benchmark import snapshot_times
    from curbside.localize.session import read_session

    session = read_session(sessions[0])
    times = snapshot_times(session)
    t0, t1 = session.time_span()
    assert all(t0 <= t <= t1 for t in times)
    assert any(np.isclose(session.waypoints["t"], t).any() for t in times)
    assert any(np.isclose(session.gnss["t"], t).any() for t in times)


def _far_map(tmp_path: Path) -> Path:
    """The fixture map moved a degree east: no session lies on it."""
    far = tmp_path / "far.geojson"
    doc = json.loads(MAP.read_text())
    for f in doc["features"]:
        f["geometry"]["coordinates"] = json.loads(
            json.dumps(f["geometry"]["coordinates"]).replace("-122.", "-121.")
        )
    far.write_text(json.dumps(doc))
    return far


@pytest.mark.parametrize("method", ["gnss", "inertial", "paper", "fused"])
def test_a_session_off_the_map_is_refused_up_front_for_every_method(tmp_path, capsys, sessions, method,
                                                                     monkeypatch):
    monkeypatch.setattr(runner, "run_all", lambda *a, **k: pytest.fail("ran a session off the map"))
    far, out = _far_map(tmp_path), tmp_path / "r"
    argv = ["evaluate", str(sessions[0]), "--maps", str(MAP), str(far), "--methods", method, "-o", str(out)]
    _fails(capsys, argv, f"{sessions[0]}/meta.json: start pose", out)
    main(argv)
    err = capsys.readouterr().err
    assert "lies outside the map's extent" in err and str(far) in err


def test_a_session_without_ground_truth_is_refused_naming_its_file(tmp_path, capsys, sessions):
    import shutil

    copy, out = tmp_path / "nowp", tmp_path / "r"
    shutil.copytree(sessions[0], copy)
    (copy / "waypoints.csv").unlink()
    argv = ["evaluate", str(copy), "--maps", str(MAP), "--methods", "gnss", "-o", str(out)]
    _fails(capsys, argv, f"{copy / 'waypoints.csv'}: missing: no ground truth", out)
    pd.DataFrame({"t": [0.0], "lat": [37.79], "lon": [-122.4]}).to_csv(copy / "waypoints.csv", index=False)
    needle = f"{copy / 'waypoints.csv'}: ground truth needs at least two waypoints; it holds 1"
    _fails(capsys, argv, needle, out)


def test_worker_processes_start_with_ctrl_c_blocked_and_the_mask_comes_back():
    import signal

    from curbside.evaluate.dask_cluster import ctrl_c_blocked

    before = signal.pthread_sigmask(signal.SIG_BLOCK, [])
    handler = signal.getsignal(signal.SIGINT)
    with ctrl_c_blocked():
        # what the threads and worker processes started now inherit; the command still hears Ctrl-C (a
        # handler that holds it, not SIG_IGN, which the workers would inherit)
        assert signal.SIGINT in signal.pthread_sigmask(signal.SIG_BLOCK, [])
        assert callable(signal.getsignal(signal.SIGINT))
    assert signal.pthread_sigmask(signal.SIG_BLOCK, []) == before
    assert signal.getsignal(signal.SIGINT) is handler
