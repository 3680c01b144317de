"""Three things a command's user sees: the session named as given in the pipeline's own messages, progress
bars on a terminal (and none off one) for the slow commands, and the replay page working out each map's
sidewalk places once."""

from __future__ import annotations

import io
import json
import logging
import re
import sys
from pathlib import Path

import pandas as pd
import pytest
from serve_fixtures import TRIAL
from viewer_fixtures import CROSSROADS, write_session

from curbside.cli.localize import main as localize_main
from curbside.errors import CurbsideInputError
from curbside.evaluate import routes
from curbside.evaluate.osmsource import load_osm
from curbside.localize import pipeline, view_data
from curbside.localize.pipeline import track_session
from curbside.localize.readers import ipin, read_any
from curbside.localize.session import Session, read_session
from curbside.osmseg import webmap
from curbside.osmseg.mapio import read_map
from curbside.projection import LocalFrame

NESTED = "data/walks/w1"
SESSIONS = Path(__file__).parent / "data" / "sessions"
IPIN = SESSIONS / "ipin2023-cut.h5"


class _Terminal(io.StringIO):
    """A stderr that says it is a terminal: tqdm draws its bars on it."""

    def isatty(self) -> bool:
        return True


def _stderr(monkeypatch, on_terminal: bool) -> _Terminal | None:
    """Make stderr a terminal, or leave pytest's (no terminal). Called in the test itself: pytest sets its
    own stderr again between a fixture and the test."""
    if not on_terminal:
        return None
    stderr = _Terminal()
    monkeypatch.setattr(sys, "stderr", stderr)
    return stderr


def _bar(desc: str) -> re.Pattern:
    """A tqdm bar of that description: ``DESC:  40%|####      | 2/5 ...``."""
    return re.compile(re.escape(desc) + r": +\d+%\|")


@pytest.fixture
def nested(tmp_path, monkeypatch) -> Path:
    """The crossroads walk as ``data/walks/w1``, relative to the working folder."""
    monkeypatch.chdir(tmp_path)
    write_session(tmp_path / NESTED)
    return tmp_path / NESTED


def _far_map(tmp_path: Path) -> Path:
    """The crossroads map moved a degree of longitude east: no walk on it."""
    doc = json.loads(CROSSROADS.read_text())
    for feature in doc["features"]:
        text = json.dumps(feature["geometry"]["coordinates"]).replace("-122.", "-121.")
        feature["geometry"]["coordinates"] = json.loads(text)
    far = tmp_path / "far.geojson"
    far.write_text(json.dumps(doc))
    return far


# -- the session named as given -------------------------------------------------------------------------


def test_the_pipeline_names_a_nested_session_as_given_off_the_map(nested, tmp_path):
    far = read_map(_far_map(tmp_path))
    with pytest.raises(CurbsideInputError) as start:
        track_session(read_session(NESTED), far, "gnss")
    assert str(start.value.source) == f"{NESTED}/meta.json" and "start pose" in start.value.problem
    with pytest.raises(CurbsideInputError) as fixes:
        track_session(read_session(NESTED), far, "gnss", use_start_pose=False)
    assert str(fixes.value.source) == f"{NESTED}/gnss.csv" and "no fix near the map" in fixes.value.problem


def test_pipeline_warnings_name_a_nested_session_as_given(nested, caplog):
    layers = read_map(CROSSROADS)
    with caplog.at_level(logging.WARNING):
        track_session(read_session(NESTED), layers, "inertial", particles=50, use_start_pose=False)
        pd.read_csv(nested / "gnss.csv").assign(accuracy_m=0.0).to_csv(nested / "gnss.csv", index=False)
        track_session(read_session(NESTED), layers, "fused", particles=50)
    text = caplog.text
    assert f"{NESTED}/gnss.csv: none of its" in text and f"{NESTED}: no start pose" in text
    assert " w1/" not in text and " w1:" not in text


def test_run_is_refused_naming_the_session_as_given_with_the_extent_checked_once(
    nested, tmp_path, capsys, monkeypatch
):
    far = _far_map(tmp_path)
    assert localize_main(["run", NESTED, "--map", str(far), "--mode", "gnss", "-o", "out"]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"localize: error: {NESTED}/meta.json: start pose") and err.count("\n") == 1
    checks = []
    check = pipeline._check_extent
    monkeypatch.setattr(pipeline, "_check_extent", lambda *a, **k: checks.append(1) or check(*a, **k))
    assert localize_main(["run", NESTED, "--map", str(CROSSROADS), "--mode", "gnss", "-o", "out"]) == 0
    assert len(checks) == 1  # the pipeline's own check; the command no longer repeats it


def test_a_refused_run_names_the_map_and_says_nothing_else_first(nested, tmp_path, capsys, caplog):
    far = _far_map(tmp_path)
    argv = ["run", NESTED, "--map", str(far), "--mode", "inertial", "--no-start-pose", "-o", "out"]
    with caplog.at_level(logging.WARNING):
        assert localize_main(argv) == 2
    err = capsys.readouterr().err
    assert err == (f"localize: error: {NESTED}/gnss.csv: the session lies outside the map's extent ({far}) "
                   "(no fix near the map)\n")
    assert not [r for r in caplog.records if r.levelno == logging.WARNING]  # no warning before the refusal
    with pytest.raises(CurbsideInputError, match=re.escape("extent (far.geojson)")):
        track_session(read_session(NESTED), read_map(far), "gnss", map_name="far.geojson")


def test_waypoints_that_cannot_be_scored_name_an_export_as_given(tmp_path, monkeypatch, caplog):
    export = str(SESSIONS / "sensorlogger-android")  # a folder, but no waypoints.csv in it

    def unscorable(*_args, **_kwargs):
        raise CurbsideInputError("track", "too short")

    monkeypatch.setattr("curbside.evaluate.metrics.waypoint_errors", unscorable)  # imported when the run runs
    assert localize_main(["run", export, "--mode", "gnss", "-o", str(tmp_path / "out")]) == 0
    warned = [r.getMessage() for r in caplog.records if "at waypoints" in r.getMessage()]
    assert warned == [f"{export}: error at waypoints not scored (too short); the track is written without it"]


def test_a_session_is_still_made_positionally():
    imu = pd.DataFrame({"t": [0.0, 0.01], "ax": 0.0, "ay": 0.0, "az": 9.8, "gx": 0.0, "gy": 0.0, "gz": 0.0})
    session = Session("w1", imu)
    assert session.imu is imu and session.source == "w1"
    assert Session("w1", source="data/w1").source == "data/w1"


def test_convert_all_names_a_trial_as_file_and_trial(tmp_path, monkeypatch, capsys):
    read_trial = ipin.read_trial

    def without_imu(path, name):
        session = read_trial(path, name)
        session.imu = None
        return session

    monkeypatch.setattr(ipin, "read_trial", without_imu)
    assert localize_main(["convert", str(IPIN), str(tmp_path / "all"), "--all", "--steps"]) == 2
    trial = ipin.list_trials(IPIN)[0]
    assert capsys.readouterr().err.startswith(f"localize: error: {IPIN}::{trial}: --steps/--pdr need IMU")


def test_source_is_the_session_as_loaded_or_its_name():
    assert read_any(TRIAL).source == TRIAL
    memory = Session(name="walk")
    assert memory.source == "walk" and memory.file_source("gnss.csv") == "walk"
    assert Session(name="walk", source="x.h5::T").file_source("meta.json") == "x.h5::T"


def test_a_session_folder_names_its_files_under_the_path_given(nested):
    session = read_session(NESTED)
    assert session.name == "w1" and session.source == NESTED
    assert session.file_source("velocity.csv") == f"{NESTED}/velocity.csv"


# -- progress on a terminal only -----------------------------------------------------------------------


@pytest.mark.parametrize("on_terminal", [True, False])
def test_run_shows_ronin_progress_on_a_terminal_only(tmp_path, monkeypatch, capsys, on_terminal):
    stderr = _stderr(monkeypatch, on_terminal)
    assert localize_main(["run", TRIAL, "--mode", "inertial", "-o", str(tmp_path / "run")]) == 0
    assert json.loads((tmp_path / "run" / "run.json").read_text())["velocity_source"] == "ronin"
    shown = stderr.getvalue() if stderr is not None else capsys.readouterr().err
    assert bool(_bar("RoNIN").search(shown)) is on_terminal


def test_simulate_shows_the_route_search_on_a_terminal(tmp_path, monkeypatch):
    terminal = _stderr(monkeypatch, True)
    argv = ["simulate", "--route", "custom", "--start", "-122.4025", "37.7930", "--length-m", "120",
            "-o", str(tmp_path / "s")]
    assert localize_main(argv) == 0
    assert _bar("custom: route search").search(terminal.getvalue())


@pytest.fixture(scope="module")
def walk_graph():
    osm = load_osm()
    return routes.build_walk_graph(osm), LocalFrame(osm.crs)


def test_the_route_search_bar_is_for_a_terminal_and_asked_for(walk_graph, monkeypatch, capsys):
    graph, frame = walk_graph
    spec = routes.RouteSpec("custom", (-122.4025, 37.7930), 120.0, 0, 0, "custom")
    routes.generate_route(graph, spec, frame, seed=1, progress=True)  # pytest's stderr: no terminal
    assert "route search" not in capsys.readouterr().err
    stderr = _stderr(monkeypatch, True)
    routes.generate_route(graph, spec, frame, seed=1)  # e.g. the benchmark's routes: no bar of their own
    assert "route search" not in stderr.getvalue()


@pytest.fixture(scope="module")
def gnss_run(tmp_path_factory) -> Path:
    """A ``gnss`` run of the crossroads walk: its track names sidewalk segments."""
    root = tmp_path_factory.mktemp("view")
    session = write_session(root / "walk")
    out = root / "gnss"
    argv = ["run", str(session), "--map", str(CROSSROADS), "--mode", "gnss", "-o", str(out)]
    assert localize_main(argv) == 0
    return out


@pytest.mark.parametrize("on_terminal", [True, False])
def test_view_shows_its_steps_on_a_terminal_only(gnss_run, tmp_path, monkeypatch, capsys, on_terminal):
    stderr = _stderr(monkeypatch, on_terminal)
    assert localize_main(["view", str(gnss_run), "-o", str(tmp_path / "v.html")]) == 0
    shown = stderr.getvalue() if stderr is not None else capsys.readouterr().err
    for step in ("reading runs", "reading maps", "writing the page"):
        assert bool(_bar(f"localize view: {step}").search(shown)) is on_terminal


# -- the sidewalk places, once a page ------------------------------------------------------------------


@pytest.mark.parametrize("given_map", [False, True])
def test_the_view_reads_the_map_and_works_out_its_places_once(gnss_run, tmp_path, monkeypatch, given_map):
    places, reads = [], []
    sidewalk_places = webmap.sidewalk_places

    def counted_places(layers):
        places.append(layers)
        return sidewalk_places(layers)

    def counted_read(path):
        reads.append(path)
        return read_map(path)

    monkeypatch.setattr(webmap, "sidewalk_places", counted_places)
    monkeypatch.setattr(view_data, "read_map", counted_read, raising=False)  # absent before: never counted
    monkeypatch.chdir(CROSSROADS.parent)
    map_option = ["--map", CROSSROADS.name] if given_map else []  # relative: run.json names it absolute
    assert localize_main(["view", str(gnss_run), *map_option, "-o", str(tmp_path / "v.html")]) == 0
    assert len(places) == 1
    assert len(reads) == 1
    page = (tmp_path / "v.html").read_text(encoding="utf-8")
    data = json.JSONDecoder().raw_decode(page, re.search(r"const VIEW = ", page).end())[0]
    assert data["runs"][0]["segment_names"] and '"place":' in page  # the panel's names, the map's tooltips
