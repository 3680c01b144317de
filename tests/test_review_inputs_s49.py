"""A reviewer's real inputs (session 49): buildings dropped without a word, a map without buildings, a
bbox just past the bundled extract offline, a decimal comma in --bbox, recording names in NFD, an
unquoted hint, and the MS-indoor HDF5 taken for IPIN trials. No network: Overpass is never reached.
"""

from __future__ import annotations

import logging
import shlex
import subprocess
import sys
import unicodedata
import zipfile
from pathlib import Path

import h5py
import numpy as np
import osmnx as ox
import pytest

from curbside import settings
from curbside.cli.localize import main as localize_main
from curbside.cli.osmseg import main as osmseg_main
from curbside.errors import CurbsideInputError
from curbside.localize.readers import read_any
from curbside.localize.readers.ipin import list_trials, read_trial
from curbside.osmseg import overpass as overpass_module
from curbside.osmseg.build import build_map

SESSIONS = Path(__file__).parent / "data" / "sessions"
EXPORT = SESSIONS / "sensorlogger-android"

_HEAD = """<?xml version="1.0" encoding="UTF-8"?>
<osm version="0.6" generator="hand">
<bounds minlat="37.7900" minlon="-122.4020" maxlat="37.7920" maxlon="-122.4000"/>
<node id="1" version="1" lat="37.791" lon="-122.4019"/>
<node id="2" version="1" lat="37.791" lon="-122.4001"/>
<way id="10" version="1"><nd ref="1"/><nd ref="2"/><tag k="highway" v="residential"/></way>
<node id="100" version="1" lat="37.7912" lon="-122.4015"/>
<node id="101" version="1" lat="37.7912" lon="-122.4005"/>
<node id="102" version="1" lat="37.7918" lon="-122.4005"/>
<node id="103" version="1" lat="37.7918" lon="-122.4015"/>
"""


def _osm(tmp_path: Path, body: str, name: str = "scene.osm") -> Path:
    path = tmp_path / name
    path.write_text(_HEAD + body + "</osm>\n")
    return path


def _way(way_id: int, refs: list[int], building: bool = True) -> str:
    nds = "".join(f'<nd ref="{r}"/>' for r in refs)
    tag = '<tag k="building" v="yes"/>' if building else ""
    return f'<way id="{way_id}" version="1">{nds}{tag}</way>\n'


def _warnings(caplog) -> list[str]:
    return [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]


# -- 1. buildings dropped, and maps without buildings, are said ----------------------------------------


def test_each_reason_a_building_is_dropped_is_one_warning_with_count_and_ids(tmp_path, caplog):
    body = "".join(_way(20 + i, [100, 101, 102, 103]) for i in range(6))  # six unclosed ways
    body += _way(30, [100, 101])  # two nodes
    body += _way(31, [100, 101, 100])  # closed, two distinct nodes
    body += _way(40, [100, 101, 102], building=False)  # an open outer ring
    body += ('<relation id="50" version="1"><member type="way" ref="40" role="outer"/>'
             '<tag k="type" v="multipolygon"/><tag k="building" v="yes"/></relation>\n')
    body += ('<relation id="51" version="1"><member type="way" ref="999" role="outer"/>'
             '<tag k="type" v="multipolygon"/><tag k="building" v="yes"/></relation>\n')
    with caplog.at_level(logging.WARNING):
        layers = build_map(osm_file=_osm(tmp_path, body))
    assert (layers.gdf["class"] == "building").sum() == 0
    lines = _warnings(caplog)
    dropped = [w for w in lines if "dropped" in w]
    assert len(dropped) == 4, lines
    assert "6 buildings dropped (way not closed: its last node is not its first): " in dropped[0]
    assert dropped[0].endswith(": w20, w21, w22, w23, ...; the map has no building there")
    assert "2 buildings dropped (way with fewer than three distinct nodes: no area): w30, w31" in dropped[1]
    assert "1 building dropped (multipolygon with none of its member ways in the file): r51" in dropped[2]
    assert "1 building dropped (multipolygon whose outer ways close no ring): r50" in dropped[3]
    assert sum("the map has no buildings" in w for w in lines) == 1


def test_outer_ways_of_a_building_relation_are_not_dropped_buildings(tmp_path, caplog):
    # Old-style tagging: the open outer ways carry building=yes too; together they close the ring.
    body = _way(40, [100, 101, 102]) + _way(41, [102, 103, 100])
    body += ('<relation id="50" version="1"><member type="way" ref="40" role="outer"/>'
             '<member type="way" ref="41" role="outer"/>'
             '<tag k="type" v="multipolygon"/><tag k="building" v="yes"/></relation>\n')
    with caplog.at_level(logging.WARNING):
        layers = build_map(osm_file=_osm(tmp_path, body))
    assert (layers.gdf["class"] == "building").sum() == 1
    assert _warnings(caplog) == []


def test_a_map_without_buildings_builds_with_one_warning(tmp_path, caplog):
    out = tmp_path / "map.geojson"
    with caplog.at_level(logging.WARNING):
        assert osmseg_main(["build", "--osm", str(_osm(tmp_path, "")), "-o", str(out)]) == 0
    lines = _warnings(caplog)
    assert len(lines) == 1 and "the map has no buildings" in lines[0] and "building likelihood" in lines[0]
    assert out.is_file()


def test_a_map_with_a_building_has_no_warning(tmp_path, caplog):
    with caplog.at_level(logging.WARNING):
        build_map(osm_file=_osm(tmp_path, _way(20, [100, 101, 102, 103, 100])))
    assert _warnings(caplog) == []


# -- 2. a bbox just past the bundled extract, offline ----------------------------------------------------


@pytest.fixture
def offline(tmp_path, monkeypatch) -> None:
    """No Overpass answers and none is cached (nothing leaves the machine)."""
    monkeypatch.setattr(settings, "cache_dir", tmp_path / "cache")
    monkeypatch.setattr(ox.settings, "overpass_url", "http://127.0.0.1:9/api")
    monkeypatch.setattr(overpass_module, "overpass_reachable", lambda url, timeout_s: False)


def test_a_bbox_just_past_the_bundled_extract_says_how_far_and_what_builds_offline(offline, tmp_path, capsys):
    out = tmp_path / "map.geojson"
    bbox = ["-122.4126", "37.78", "-122.385", "37.802"]
    assert osmseg_main(["build", "--bbox", *bbox, "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and not out.exists()
    assert "cannot be reached" in err and "9 m past its west bound" in err
    extract = " ".join(f"{v:.10g}" for v in settings.default_extract_bbox)
    assert f"bounds (W S E N: {extract}) builds offline" in err


def test_a_bbox_past_two_sides_names_both(offline, tmp_path, capsys):
    out = tmp_path / "map.geojson"
    assert osmseg_main(["build", "--bbox", "-122.39", "37.79", "-122.38", "37.81", "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert "past its east bound and " in err and "past its north bound" in err
    assert "e.g. --bbox -122.39 37.79 -122.385 37.802" in err


def test_a_bbox_away_from_the_extract_keeps_the_plain_message(offline, tmp_path, capsys):
    out = tmp_path / "map.geojson"
    assert osmseg_main(["build", "--bbox", "-122.5", "37.70", "-122.49", "37.71", "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert "cannot reach the Overpass server" in err and "bundled" not in err


# -- 3. a decimal comma in --bbox ---------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("bbox", "message"),
    [
        (["-122,401", "37.79", "-122.40", "37.80"], "'-122,401' has a decimal comma: use a decimal point "
                                                    "(-122.401)"),
        (["-122.401", "37,79", "-122.40", "37.80"], "'37,79' has a decimal comma: use a decimal point "
                                                    "(37.79)"),
        (["-122.401,37.79,-122.40,37.80"], "'-122.401,37.79,-122.40,37.80': separate the numbers with "
                                           "spaces, not commas"),
    ],
)
def test_a_decimal_comma_in_bbox_is_named(tmp_path, capsys, bbox, message):
    with pytest.raises(SystemExit) as stop:
        osmseg_main(["build", "--bbox", *bbox, "-o", str(tmp_path / "map.geojson")])
    assert stop.value.code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"argument --bbox: {message}" in err


def test_other_bbox_errors_are_argparses(tmp_path, capsys):
    with pytest.raises(SystemExit):
        osmseg_main(["build", "--bbox", "-122.4", "37.79", "-122.40", "-o", str(tmp_path / "m.geojson")])
    assert "argument --bbox: expected 4 arguments" in capsys.readouterr().err


# -- 4 and 5. recording names in NFD, and the hint to pick one ----------------------------------------------


def _zip_of(tmp_path: Path, folders: list[str], name: str = "walks.zip") -> Path:
    path = tmp_path / name
    with zipfile.ZipFile(path, "w") as zf:
        for folder in folders:
            for file in EXPORT.iterdir():
                zf.write(file, f"{folder}/{file.name}")
    return path


def test_a_recording_named_in_nfd_is_picked_by_the_name_typed(tmp_path, capsys):
    nfd = unicodedata.normalize("NFD", "Straße ü")
    path = _zip_of(tmp_path, [nfd, "other"])
    typed = unicodedata.normalize("NFC", "Straße ü")
    session = read_any(f"{path}::{typed}")
    assert session.name == typed
    assert read_any(f"{path}::{nfd}").name == typed  # a name pasted from macOS works too
    with pytest.raises(CurbsideInputError, match="no such recording; it holds: Straße ü, other") as refused:
        read_any(f"{path}::Strasse")
    assert nfd not in str(refused.value)
    assert localize_main(["convert", str(path), "--list"]) == 0
    assert capsys.readouterr().out.splitlines() == [typed, "other"]


def test_folders_that_differ_only_in_unicode_form_are_refused(tmp_path):
    path = _zip_of(tmp_path, [unicodedata.normalize("NFD", "ü"), "ü"])
    with pytest.raises(CurbsideInputError, match="differ only in how their letters are encoded"):
        read_any(path)


def test_the_hint_to_pick_a_recording_pastes_into_a_shell(tmp_path):
    path = _zip_of(tmp_path, ["Montag Spaziergang", "dienstag"], name="my walks.zip")
    with pytest.raises(CurbsideInputError, match="pick one as") as refused:
        read_any(path)
    hint = str(refused.value).split("pick one as ", 1)[1]
    assert hint == shlex.quote(f"{path}::Montag Spaziergang")
    # what a shell makes of it is one argument, which reads
    argv = subprocess.run([sys.executable, "-c", "import sys; print(sys.argv[1])", *shlex.split(hint)],
                          capture_output=True, text=True, check=True).stdout.strip()
    assert read_any(argv).name == "Montag Spaziergang"


# -- 6. the MS-indoor HDF5 ----------------------------------------------------------------------------------


def _ms_indoor(tmp_path: Path) -> Path:
    """A file in the layout of ``ms-indoor-2020.h5``: ``/<site>/<floor>/<path>/{acce,gyro,magn,rotvec,
    waypoints}``."""
    path = tmp_path / "ms-indoor-mini.h5"
    t = np.arange(0.1, 5.0, 0.02)
    with h5py.File(path, "w") as f:
        g = f.create_group("site1/B1/5dda14979191710006b5720e")
        g.attrs["device"] = "OPPO PBCM10 Android 8.1.0 API 27"
        for name in ("acce", "gyro", "magn"):
            g[name] = np.column_stack([t, np.zeros((len(t), 2)), np.full(len(t), 9.8)])
        g["rotvec"] = np.column_stack([t, np.zeros((len(t), 3)), np.ones(len(t))])
        g["waypoints"] = np.array([[0.0, 10.0, 20.0], [4.9, 14.0, 23.0]])
    return path


def test_the_ms_indoor_file_is_refused_alike_by_list_all_and_trial(tmp_path, capsys):
    path = _ms_indoor(tmp_path)
    with pytest.raises(CurbsideInputError, match="is an MS-indoor file") as listed:
        list_trials(path)
    assert "--ms-indoor" in str(listed.value)
    with pytest.raises(CurbsideInputError, match="is an MS-indoor file"):
        read_trial(path, "site1/B1/5dda14979191710006b5720e")
    for argv in (
        ["convert", str(path), "--list"],
        ["convert", str(path), str(tmp_path / "all"), "--all"],
        ["convert", f"{path}::site1/B1/5dda14979191710006b5720e", str(tmp_path / "one")],
        ["convert", str(path), str(tmp_path / "bare")],
    ):
        assert localize_main(argv) == 2, argv
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "is an MS-indoor file" in err, argv
    assert not any((tmp_path / d).exists() for d in ("all", "one", "bare"))


def test_the_real_ms_indoor_file_is_refused(shared_data):
    path = shared_data / "imu" / "ms-indoor-2020.h5"
    if not path.is_file():
        pytest.skip("no ms-indoor-2020.h5")
    with pytest.raises(CurbsideInputError, match="is an MS-indoor file"):
        read_any(f"{path}::site1/B1/5dda14979191710006b5720e")


def test_ipin_trials_still_list_and_read():
    h5 = SESSIONS / "ipin2023-cut.h5"
    trials = list_trials(h5)
    assert read_trial(h5, trials[0]).meta["source"]["format"] == "ipin2023-h5"
