"""The commands never write over their inputs, a user's file, a device or another command's output."""

from __future__ import annotations

import shutil
import stat
from pathlib import Path

import pytest

from curbside.cli.localize import main as localize_main
from curbside.cli.osmseg import main as osmseg_main

DATA = Path(__file__).parent / "data"
OSM = DATA / "osm" / "crossroads-crossing-nodes.osm"
GPX = DATA / "sessions" / "walk.gpx"
IPIN_TRIAL = f"{DATA / 'sessions' / 'ipin2023-cut.h5'}::IPIN2023_T3_TrainingTrial01_repetition01"


@pytest.fixture(autouse=True)
def _cache_in_tmp(tmp_path, monkeypatch):
    monkeypatch.setenv("CURBSIDE_CACHE_DIR", str(tmp_path / "cache"))


def _one_line_error(capsys) -> str:
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err
    return err


def test_osmseg_build_never_writes_over_its_input_or_a_users_file(tmp_path, capsys):
    osm = shutil.copy(OSM, tmp_path / "area.osm")
    before = Path(osm).read_bytes()
    assert osmseg_main(["build", "--osm", str(osm), "-o", str(tmp_path / "area.osm")]) == 2
    assert "name it .geojson" in _one_line_error(capsys)
    as_json = tmp_path / "area.json"
    shutil.copy(osm, as_json)
    assert osmseg_main(["build", "--osm", str(as_json), "-o", str(as_json), "--overwrite"]) == 2
    assert "also an input" in _one_line_error(capsys)
    assert Path(osm).read_bytes() == before and as_json.read_bytes() == before
    mine = tmp_path / "map.geojson"
    mine.write_text('{"type": "FeatureCollection", "features": []}')
    assert osmseg_main(["build", "--osm", str(osm), "-o", str(mine)]) == 2
    assert "not written by curbside" in _one_line_error(capsys)
    assert mine.read_text() == '{"type": "FeatureCollection", "features": []}'
    assert osmseg_main(["build", "--osm", str(osm), "-o", str(mine), "--overwrite"]) == 0
    assert osmseg_main(["build", "--osm", str(osm), "-o", str(mine)]) == 0  # curbside's map now


def test_pages_figures_and_reports_curbside_wrote_are_replaced_without_overwrite(tmp_path, capsys):
    map_file = tmp_path / "map.geojson"
    assert osmseg_main(["build", "--osm", str(OSM), "-o", str(map_file)]) == 0
    for name in ("map.png", "map.html"):
        for _ in range(2):
            assert osmseg_main(["show", str(map_file), "-o", str(tmp_path / name)]) == 0
    figures = tmp_path / "figures.json"
    for _ in range(2):
        assert osmseg_main(["compare", str(map_file), str(map_file), "--json", str(figures)]) == 0
    for _ in range(2):
        assert osmseg_main(["edit", str(map_file), "-o", str(tmp_path / "edit.html")]) == 0
    capsys.readouterr()
    page = tmp_path / "notes.html"
    page.write_text("<html>my notes</html>")
    assert osmseg_main(["show", str(map_file), "-o", str(page)]) == 2
    assert "--overwrite" in _one_line_error(capsys) and page.read_text() == "<html>my notes</html>"


def test_links_and_devices_are_not_written_through(tmp_path, capsys):
    map_file = tmp_path / "map.geojson"
    assert osmseg_main(["build", "--osm", str(OSM), "-o", str(map_file)]) == 0
    link = tmp_path / "link.png"
    link.symlink_to(tmp_path / "target.png")
    assert osmseg_main(["show", str(map_file), "-o", str(link), "--overwrite"]) == 2
    assert "symbolic link" in _one_line_error(capsys) and link.is_symlink()
    assert localize_main(["view", str(tmp_path), "-o", "/dev/null.html"]) == 2  # not a run folder
    capsys.readouterr()
    assert osmseg_main(["compare", str(map_file), str(map_file), "--json", "/dev/null", "--overwrite"]) == 2
    assert "name the file .json" in _one_line_error(capsys)
    assert stat.S_ISCHR(Path("/dev/null").lstat().st_mode)


def test_a_run_into_a_session_folder_is_refused_and_the_session_kept(tmp_path, capsys):
    session = tmp_path / "walk"
    assert localize_main(["convert", str(GPX), str(session)]) == 0
    before = sorted(p.name for p in session.iterdir())
    capsys.readouterr()
    assert localize_main(["run", str(session), "--mode", "gnss", "-o", str(session)]) == 2
    assert "holds the output of 'localize convert'" in _one_line_error(capsys)
    assert sorted(p.name for p in session.iterdir()) == before
    assert localize_main(["run", str(session), "--mode", "gnss", "-o", str(session), "--overwrite"]) == 0
    assert set(before) <= {p.name for p in session.iterdir()}  # nothing of the session deleted
    # still the conversion's folder too (the marker keeps each command's files): it converts again,
    # replacing its own files and keeping the run's
    assert localize_main(["convert", str(GPX), str(session)]) == 0
    assert {"track.csv", "run.json", *before} <= {p.name for p in session.iterdir()}


def test_ronin_writes_its_velocity_but_never_over_a_session_input(tmp_path, capsys):
    session = tmp_path / "trial"
    assert localize_main(["convert", IPIN_TRIAL, str(session)]) == 0
    gnss = (session / "gnss.csv").read_bytes()
    assert localize_main(["ronin", str(session), "-o", str(session / "gnss.csv")]) == 2
    assert "also an input" in _one_line_error(capsys) and (session / "gnss.csv").read_bytes() == gnss
    for _ in range(2):
        assert localize_main(["ronin", str(session)]) == 0
    assert (session / "velocity.csv").is_file()
    mine = tmp_path / "own"
    mine.mkdir()
    (mine / "velocity.csv").write_text("t,ve,vn\n")
    capsys.readouterr()
    assert localize_main(["ronin", str(session), "-o", str(mine / "velocity.csv")]) == 2
    assert "not written by curbside" in _one_line_error(capsys)
