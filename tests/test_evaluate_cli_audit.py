"""An outside audit of ``localize simulate``, ``localize evaluate`` and ``localize benchmark``: help a
stranger can act on, and bad input refused with one line and exit status 2, before minutes of work,
never with a traceback or exit status 1, and never leaving a half-written output."""

from __future__ import annotations

import json
import logging
from pathlib import Path

import h5py
import numpy as np
import pandas as pd
import pytest

from curbside.cli.localize import main
from curbside.errors import CurbsideInputError
from curbside.evaluate import dask_cluster, runner, simulate, suite, suite_report
from curbside.evaluate.figures import fig_per_path
from curbside.evaluate.report import html_document

MAP = Path(__file__).parent / "data" / "evaluate" / "sf-path3.geojson"
IPIN_CUT = Path(__file__).parent / "data" / "sessions" / "ipin2023-cut.h5"  # no held-out trial


@pytest.fixture(scope="module")
def session(tmp_path_factory) -> Path:
    """One simulated walk of the benchmark's path 3 (the fixture map is clipped around it)."""
    folder = tmp_path_factory.mktemp("walks") / "path3-s1"
    assert main(["simulate", "--route", "path3", "--seed", "1", "--map", str(MAP), "-o", str(folder)]) == 0
    return folder


def _refused(capsys, argv: list[str], needle: str) -> str:
    try:
        rc = main(argv)
    except SystemExit as exc:  # argparse usage errors
        rc = exc.code
    err = capsys.readouterr().err
    assert rc == 2, err
    assert needle in err and "Traceback" not in err, err
    assert len(err.strip().splitlines()) == 1, err
    return err


def _no_work(*_args, **_kwargs):
    raise AssertionError("the work started before the bad input was refused")


def _shifted_map(tmp_path: Path, name: str, dlon: float) -> Path:
    """The fixture map moved ``dlon`` degrees east."""
    doc = json.loads(MAP.read_text())

    def shift(coords):
        if isinstance(coords[0], (int, float)):
            return [coords[0] + dlon, *coords[1:]]
        return [shift(c) for c in coords]

    for feature in doc["features"]:
        feature["geometry"]["coordinates"] = shift(feature["geometry"]["coordinates"])
    out = tmp_path / name
    out.write_text(json.dumps(doc))
    return out


@pytest.mark.parametrize(
    ("command", "phrases"),
    [
        ("simulate", ["longitude then latitude in degrees", "localize simulate --route path3"]),
        ("evaluate", ["standard deviation (m)", "only the first K IPIN trials (default: all)",
                      "SESSIONS first"]),
        ("benchmark", ["localize benchmark --subsets paper6 --seeds 1", "test (the scored ones)"]),
    ],
)
def test_help_gives_examples_units_and_defaults(capsys, command, phrases):
    with pytest.raises(SystemExit) as exc:
        main([command, "--help"])
    assert exc.value.code == 0
    text = " ".join(capsys.readouterr().out.split())  # argparse wraps lines
    assert "examples: localize " + command in text
    for phrase in phrases:
        assert phrase in text


def test_custom_start_must_be_finite(tmp_path, capsys):
    argv = ["simulate", "--route", "custom", "--start", "nan", "37.79", "--length-m", "300"]
    _refused(capsys, [*argv, "-o", str(tmp_path / "w")], "argument --start: must be finite")


def test_custom_start_far_from_the_extract_says_where_its_footways_are(tmp_path, capsys):
    argv = ["simulate", "--route", "custom", "--start", "0", "0", "--length-m", "300"]
    err = _refused(capsys, [*argv, "-o", str(tmp_path / "w")],
                   "--start: no footway of the OSM extract within 80 m of (0, 0)")
    assert "the extract's footways span lon -122." in err
    assert not (tmp_path / "w").exists()


def test_custom_start_given_lat_first_is_refused_with_the_order(tmp_path, capsys):
    argv = ["simulate", "--route", "custom", "--start", "37.79", "-122.40", "--length-m", "300"]
    _refused(capsys, [*argv, "-o", str(tmp_path / "w")], "give LON then LAT")


def test_simulate_refuses_a_bad_map_before_the_walk(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(simulate, "simulate_session", _no_work)
    bad = tmp_path / "bad.geojson"
    bad.write_text("hello")
    _refused(capsys, ["simulate", "--route", "path3", "--map", str(bad), "-o", str(tmp_path / "w")],
             "bad.geojson: not readable as GeoJSON")
    assert not (tmp_path / "w").exists()


def test_evaluate_names_a_folder_given_as_a_map(tmp_path, capsys, session):
    _refused(capsys, ["evaluate", str(session), "--maps", str(tmp_path), "-o", str(tmp_path / "r")],
             "is a folder, not a map file")


@pytest.mark.parametrize(("content", "needle"), [("text", "not a readable HDF5 file"),
                                                  ("no-trials", "no trial groups")])
def test_evaluate_refuses_a_bad_ipin_file_before_any_run(tmp_path, capsys, monkeypatch, session, content,
                                                         needle):
    monkeypatch.setattr(runner, "run_all", _no_work)
    h5 = tmp_path / "ipin.h5"
    if content == "text":
        h5.write_text("not HDF5")
    else:
        with h5py.File(h5, "w") as f:
            f.create_group("something")
    argv = ["evaluate", str(session), "--maps", str(MAP), "--methods", "gnss", "--ipin", str(h5)]
    _refused(capsys, [*argv, "-o", str(tmp_path / "r")], needle)
    assert not (tmp_path / "r").exists()


def test_a_scheduler_address_is_checked_when_parsed(tmp_path, capsys, session):
    argv = ["evaluate", str(session), "--maps", str(MAP), "--scheduler", "notanaddress"]
    _refused(capsys, [*argv, "-o", str(tmp_path / "r")], "argument --scheduler: expected HOST:PORT")


def test_an_unreachable_scheduler_is_bad_input_not_an_internal_error(session):
    import dask

    spec = runner.RunSpec(str(session), "gnss", metrics_map=str(MAP))
    with dask.config.set({"distributed.comm.timeouts.connect": "1s"}), \
            pytest.raises(CurbsideInputError, match="--scheduler: cannot reach a dask scheduler"):
        runner.run_all([spec], scheduler="tcp://127.0.0.1:1")


def _held_out_ipin(path: Path) -> Path:
    """An HDF5 file with one (empty) held-out trial: enough for the up-front checks."""
    with h5py.File(path, "w") as f:
        group = f.create_group("IPIN2023_T3_TestingTrial01_repetition04")
        for name in ("acce", "gyro", "rotvec"):
            group.create_dataset(name, data=np.zeros((0, 4)))
    return path


@pytest.mark.parametrize(
    ("which", "needle"),
    [("text", "not a readable HDF5 file"), ("cut", "none of its 2 trials is a held-out one (repetition04)")],
)
def test_benchmark_refuses_a_bad_ipin_file_before_any_walk(tmp_path, capsys, monkeypatch, which, needle):
    monkeypatch.setattr(suite, "run_suite", _no_work)
    h5 = IPIN_CUT
    if which == "text":
        h5 = tmp_path / "ipin.h5"
        h5.write_text("not HDF5")
    _refused(capsys, ["benchmark", "--ipin", str(h5), "-o", str(tmp_path / "b")], needle)
    assert not (tmp_path / "b").exists()


def test_benchmark_datasf_pattern_that_matched_nothing(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(suite, "run_suite", _no_work)
    pattern = str(tmp_path / "datasf" / "*.topojson")
    _refused(capsys, ["benchmark", "--datasf-tiles", pattern, "-o", str(tmp_path / "b")],
             "no such DataSF tile file (a pattern that matched no file)")


def test_ipin_ronin_weights_without_their_config_name_the_weights(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(suite, "run_suite", _no_work)
    weights = tmp_path / "mine.pt"
    weights.write_bytes(b"\x80\x02weights")
    argv = ["benchmark", "--ipin", str(_held_out_ipin(tmp_path / "t.h5")), "--ipin-ronin", str(weights)]
    _refused(capsys, [*argv, "-o", str(tmp_path / "b")], "mine.pt: its config mine.json is not beside it")


def test_benchmark_output_that_cannot_be_made_is_bad_input(capsys):
    # /proc refuses a new folder even to root, whom the early permission check lets through
    _refused(capsys, ["benchmark", "-o", "/proc/curbside-audit-benchmark"], "cannot write here")


def test_benchmark_refuses_a_report_folder_it_did_not_write_before_any_work(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(suite, "run_suite", _no_work)
    out = tmp_path / "b"
    (out / "report").mkdir(parents=True)
    (out / "report" / "mine.txt").write_text("mine")
    (out / "notes.txt").write_text("notes")
    _refused(capsys, ["benchmark", "-o", str(out), "--overwrite"], "curbside did not write")
    assert (out / "report" / "mine.txt").read_text() == "mine"
    assert sorted(p.name for p in out.rglob("*")) == ["mine.txt", "notes.txt", "report"]


def test_benchmark_map_of_another_area_is_refused_before_any_walk(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(suite, "simulate_suite", _no_work)
    far = _shifted_map(tmp_path, "far.geojson", 1.0)
    err = _refused(capsys, ["benchmark", "--map", str(far), "-o", str(tmp_path / "b")],
                   "does not cover the benchmark's walks in downtown San Francisco")
    assert "far.geojson" in err
    assert not (tmp_path / "b").exists()


def test_benchmark_map_that_misses_a_walk_is_refused_before_any_tracking(tmp_path, monkeypatch, session):
    near = _shifted_map(tmp_path, "near.geojson", 0.005)  # 440 m east: still downtown, off path 3
    monkeypatch.setattr(suite, "simulate_suite", lambda *args, **kwargs: {"paper6": [session]})
    monkeypatch.setattr(suite, "run_all", _no_work)
    config = suite.SuiteConfig(subsets=("paper6",), seeds=1)
    with pytest.raises(CurbsideInputError, match="outside the map's extent.*near.geojson"):
        suite.run_suite(tmp_path / "b", config, map_path=near, workers=1)


def test_a_run_off_its_map_names_the_map(tmp_path, session):
    far = _shifted_map(tmp_path, "far.geojson", 1.0)
    spec = runner.RunSpec(str(session), "fused", str(far), "far", str(MAP))
    with pytest.raises(CurbsideInputError, match="outside the map's extent.*far.geojson"):
        runner.run_one(spec)


def test_ctrl_c_noise_of_the_dask_workers_is_dropped():
    quiet = dask_cluster.HeartbeatAtShutdown()
    message = ("Async instruction for <Task cancelled name=\"execute('run_one-1')\" coro=<Worker.execute()>> "
               "ended with CancelledError")
    record = logging.LogRecord("distributed.worker.state_machine", logging.WARNING, __file__, 1, message,
                               None, None)
    assert not quiet.filter(record)


def test_fig5_labels_both_axes():
    pooled = pd.DataFrame({"path": ["path1", "path1"], "method": ["gnss", "fused"],
                           "euclid_mean_m": [12.0, 4.0]})
    base = {"map": "osm", "jaywalk_weight": 0.4, "particles": 500, "gnss_sigma_factor": None}
    ax = fig_per_path(pooled, base).axes[0]
    assert ax.get_xlabel() == "route"
    assert ax.get_ylabel() == "mean Euclidean error (m)"


def test_benchmark_session_names_do_not_wrap_in_the_html_tables():
    page = html_document("curbside benchmark", suite_report._STYLE, "")
    assert "td{white-space:nowrap}" in page and "td:first-child{text-align:left}" in page
