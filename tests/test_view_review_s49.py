"""Second review, session 49: replay pages of several runs (extra-run colours that stay apart for every
reader, runs of different sessions said and named) and output records that keep every command's files
(running into a simulated session folder no longer makes it a run folder)."""

from __future__ import annotations

import itertools
import json
import logging
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from browser import chromium, console_errors, wait_for_mark
from matplotlib.colors import to_rgb
from test_io import _tree, _write
from viewer_fixtures import CROSSROADS, FRAME, START_XY, write_session

from curbside.cli.localize import main as localize_main
from curbside.errors import CurbsideInputError
from curbside.io import (
    MARKER,
    check_output_folder,
    command_files,
    note_written,
    output_folder,
    read_marker,
    written_by_curbside,
)
from curbside.localize.paths import expand_sessions
from curbside.localize.readers import read_any
from curbside.localize.view import EXTRA_COLOURS, ViewRun, label_runs, run_colours, view_page
from curbside.osmseg.style import BACKGROUND, CLASS_STYLE, GNSS_FIX_COLOUR, METHOD_COLOURS

SF_MAP = Path(__file__).parent / "data" / "evaluate" / "sf-path3.geojson"

# Machado, Oliveira and Fernandes (2009), severity 1: linear-RGB simulation of dichromacy; and normal vision.
VISION = {
    "normal": np.eye(3),
    "deuteranopia": np.array([[0.367322, 0.860646, -0.227968], [0.280085, 0.672501, 0.047413],
                              [-0.011820, 0.042940, 0.968881]]),
    "protanopia": np.array([[0.152286, 1.052583, -0.204868], [0.114503, 0.786281, 0.099216],
                            [-0.003882, -0.048116, 1.051998]]),
    "tritanopia": np.array([[1.255528, -0.076749, -0.178779], [-0.078411, 0.930809, 0.147602],
                            [0.004733, 0.691367, 0.303900]]),
}
#: CIE76 colour difference below which two thin lines or small dots are hard to tell apart.
MIN_DELTA_E = 20.0


def _seen(colour: str, matrix: np.ndarray) -> np.ndarray:
    """CIELAB (D65) of ``colour`` as a reader with ``matrix``'s vision sees it."""
    srgb = np.array(to_rgb(colour))
    linear = np.clip(matrix @ np.where(srgb <= 0.04045, srgb / 12.92, ((srgb + 0.055) / 1.055) ** 2.4), 0, 1)
    xyz = np.array([[0.4124, 0.3576, 0.1805], [0.2126, 0.7152, 0.0722], [0.0193, 0.1192, 0.9505]]) @ linear
    f = xyz / np.array([0.95047, 1.0, 1.08883])
    f = np.where(f > 0.008856, np.cbrt(f), 7.787 * f + 16 / 116)
    return np.array([116 * f[1] - 16, 500 * (f[0] - f[1]), 200 * (f[1] - f[2])])


def _delta_e(a: str, b: str, vision: str) -> float:
    return float(np.linalg.norm(_seen(a, VISION[vision]) - _seen(b, VISION[vision])))


# --- 1. the colours of extra runs --------------------------------------------------------------------------

#: What an extra run's track, estimate and cloud lie beside: every method's track, the fixes, the ground
#: truth's black line, and the map's fills under them.
NEIGHBOURS = {
    **METHOD_COLOURS,
    "GNSS fixes": GNSS_FIX_COLOUR,
    "ground truth": "#000000",
    **{cls: str(style["facecolor"]) for cls, style in CLASS_STYLE.items()},
    "background": BACKGROUND,
}


@pytest.mark.parametrize("vision", sorted(VISION))
def test_extra_run_colours_stay_apart_from_the_methods_the_fixes_and_each_other(vision):
    """Review: a second fused run was drawn in #0072b2, ΔE 15.5 from the fixes' blue (normal vision) and
    12.3 from the fused purple under deuteranopia."""
    for extra in EXTRA_COLOURS:
        for name, colour in NEIGHBOURS.items():
            assert _delta_e(extra, colour, vision) >= MIN_DELTA_E, (vision, extra, name)
    for a, b in itertools.combinations(EXTRA_COLOURS, 2):
        assert _delta_e(a, b, vision) >= MIN_DELTA_E, (vision, a, b)


def _run(mode: str, session=None, key: str = "", label: str | None = None) -> ViewRun:
    lon, lat = FRAME.to_lonlat(START_XY[0] + np.arange(5.0), np.full(5, START_XY[1]))
    track = pd.DataFrame({"t": np.arange(5.0), "lat": lat, "lon": lon})
    return ViewRun(label=label or mode, track=track, session=session, session_key=key, mode=mode)


def test_a_second_run_of_a_method_takes_the_first_extra_colour_and_a_crowd_is_warned(caplog):
    runs = [_run("fused"), _run("fused"), _run("gnss"), _run("fused")]
    assert run_colours(runs) == [METHOD_COLOURS["fused"], *EXTRA_COLOURS[:1], METHOD_COLOURS["gnss"],
                                 EXTRA_COLOURS[1]]
    with caplog.at_level(logging.WARNING, logger="curbside.localize.view"):
        colours = run_colours([_run("fused") for _ in range(len(EXTRA_COLOURS) + 2)])
    assert len(set(colours)) == len(EXTRA_COLOURS) + 1
    assert any("share" in r.getMessage() and "colours" in r.getMessage() for r in caplog.records)


# --- 1. runs of different sessions on one page ------------------------------------------------------------


def _run_folder(root: Path, name: str, session: Path, mode: str = "fused") -> Path:
    """A run folder by hand (a track along the walk, run.json naming the session): no filter to wait for."""
    folder = root / name
    folder.mkdir()
    walk = read_any(session).waypoints
    t = np.linspace(walk["t"].iat[0], walk["t"].iat[-1], 20)
    pd.DataFrame({"t": t, "lat": np.interp(t, walk["t"], walk["lat"]),
                  "lon": np.interp(t, walk["t"], walk["lon"])}).to_csv(folder / "track.csv", index=False)
    (folder / "run.json").write_text(json.dumps({"session": str(session), "mode": mode}))
    return folder


@pytest.fixture(scope="module")
def two_sessions(tmp_path_factory) -> tuple[Path, list[Path]]:
    root = tmp_path_factory.mktemp("two-sessions")
    walks = [write_session(root / name, seed) for seed, name in enumerate(("walk", "again"))]
    return root, walks


def test_runs_of_two_sessions_are_warned_said_on_the_page_and_named(two_sessions):
    """Review: runs of different sessions shared one fix colour and one ground-truth colour, unsaid."""
    root, (walk, again) = two_sessions
    runs = [_run_folder(root, "r-walk", walk), _run_folder(root, "r-again", again)]
    page = root / "two.html"
    done = subprocess.run([sys.executable, "-m", "curbside.cli.localize", "view", *map(str, runs), "-o",
                           str(page)], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    warnings = [line for line in done.stderr.splitlines() if line.strip()]
    assert len(warnings) == 1 and "2 sessions (walk, again)" in warnings[0], warnings
    doc = _page_data(page)
    assert "2 sessions (walk, again)" in doc["note"] and "each run plays on its own session" in doc["note"]
    assert [r["label"] for r in doc["runs"]] == ["curbside fused · walk", "curbside fused · again"]
    assert doc["runs"][1]["colour"] == EXTRA_COLOURS[0]


def test_runs_of_one_session_get_no_note(two_sessions, caplog):
    root, (walk, _) = two_sessions
    runs = [_run_folder(root, "one-gnss", walk, "gnss"), _run_folder(root, "one-fused", walk)]
    page = root / "one.html"
    with caplog.at_level(logging.WARNING):
        assert localize_main(["view", *map(str, runs), "-o", str(page)]) == 0
    assert not caplog.records
    doc = _page_data(page)
    assert doc["note"] is None and [r["label"] for r in doc["runs"]] == ["GNSS", "curbside fused"]


def _page_data(page: Path) -> dict:
    text = page.read_text(encoding="utf-8")
    start = text.index("const VIEW = ") + len("const VIEW = ")
    return json.JSONDecoder().raw_decode(text[start:])[0]


def test_the_page_shows_the_note_and_whose_fix_each_is(two_sessions):
    _, walks = two_sessions
    sessions = [read_any(w) for w in walks]
    runs = label_runs([_run("fused", s, str(w)) for s, w in zip(sessions, walks, strict=True)])
    page = two_sessions[0] / "browser.html"
    page.write_text(view_page(runs, maps={}), encoding="utf-8")
    with chromium(1200, 800) as driver:
        driver.get(page.as_uri())
        wait_for_mark(driver, "curbside:slider-ready")
        driver.execute_script("curbsideView.setIndex(3)")
        time.sleep(0.2)
        note = driver.find_element("id", "view-note")
        assert note.is_displayed() and "2 sessions (walk, again)" in note.text
        gnss = driver.find_element("id", "gnss-now").text
        assert gnss.startswith("walk: GNSS fix") and "; again: GNSS fix" in gnss, gnss
        assert console_errors(driver) == []


# --- 2. output records keep every command's files -----------------------------------------------------------


def _files(folder: Path) -> dict[str, str]:
    return {rel: text for rel, text in _tree(folder).items() if rel != MARKER}


SESSION = {"gnss.csv": "g", "steps.csv": "s", "velocity.csv": "v", "waypoints.csv": "w"}
RUN = {"track.csv": "t", "run.json": "r", "track.geojson": "j"}


def test_a_run_into_a_session_keeps_the_sessions_record_and_each_replaces_its_own(tmp_path):
    """Review: `localize run COPY -o COPY --overwrite` made COPY a run folder; `localize simulate -o COPY`
    was then refused."""
    copy = tmp_path / "copy"
    _write(output_folder(copy, "localize simulate"), SESSION)
    _write(output_folder(copy, "localize run", overwrite=True), RUN)
    doc = read_marker(copy)
    assert command_files(doc) == {"localize simulate": sorted(SESSION), "localize run": sorted(RUN)}
    assert doc["command"] == "localize simulate" and doc["files"] == sorted({*SESSION, *RUN})
    assert all(written_by_curbside(copy / name) for name in (*SESSION, *RUN))
    check_output_folder(copy, command="localize simulate")  # used to say: holds the output of 'localize run'
    check_output_folder(copy, command="localize run")
    # simulate again, without steps.csv: only its own stale file goes; the run's files stay
    again = {"gnss.csv": "g2", "velocity.csv": "v2", "waypoints.csv": "w2"}
    _write(output_folder(copy, "localize simulate"), again)
    assert _files(copy) == {**again, **RUN}
    # run again, without track.geojson: only the run's stale file goes; the session stays
    _write(output_folder(copy, "localize run"), {"track.csv": "t2", "run.json": "r2"})
    assert _files(copy) == {**again, "track.csv": "t2", "run.json": "r2"}
    assert command_files(read_marker(copy)) == {"localize simulate": sorted(again),
                                                "localize run": ["run.json", "track.csv"]}


def test_a_file_written_again_by_another_command_is_its_and_noted_files_go_to_the_folders_maker(tmp_path):
    folder = tmp_path / "s"
    _write(output_folder(folder, "localize convert"), {"imu.csv": "i", "shared.csv": "a"})
    _write(output_folder(folder, "localize run", overwrite=True), {"track.csv": "t", "shared.csv": "b"})
    assert command_files(read_marker(folder)) == {"localize convert": ["imu.csv"],
                                                  "localize run": ["shared.csv", "track.csv"]}
    (folder / "velocity.csv").write_text("v")  # localize ronin, from imu.csv
    note_written(folder / "velocity.csv", "localize ronin")
    assert command_files(read_marker(folder))["localize convert"] == ["imu.csv", "velocity.csv"]
    _write(output_folder(folder, "localize run"), {"track.csv": "t2"})  # the run's next output keeps it
    assert _files(folder) == {"imu.csv": "i", "velocity.csv": "v", "track.csv": "t2"}
    _write(output_folder(folder, "localize convert"), {"imu.csv": "i2"})  # a new imu.csv: velocity.csv goes
    assert _files(folder) == {"imu.csv": "i2", "track.csv": "t2"}


def test_older_markers_still_read_and_several_other_commands_are_named(tmp_path):
    folder = tmp_path / "old"
    folder.mkdir()
    (folder / "imu.csv").write_text("i")
    (folder / MARKER).write_text(json.dumps({"command": "localize convert", "files": ["imu.csv"]}))
    _write(output_folder(folder, "localize run", overwrite=True), {"track.csv": "t"})
    records = command_files(read_marker(folder))
    assert records == {"localize convert": ["imu.csv"], "localize run": ["track.csv"]}
    with pytest.raises(CurbsideInputError, match="holds the output of 'localize convert' and 'localize run', "
                                                 "not of 'localize evaluate'"):
        check_output_folder(folder, command="localize evaluate")


def test_a_commands_record_cannot_make_curbside_delete_outside_the_folder(tmp_path):
    folder = tmp_path / "out"
    _write(output_folder(folder, "test"), {"a.csv": "1"})
    victim = tmp_path / "victim.txt"
    victim.write_text("precious")
    doc = json.loads((folder / MARKER).read_text())
    doc["commands"]["test"] += ["../victim.txt", str(victim)]
    (folder / MARKER).write_text(json.dumps(doc))
    _write(output_folder(folder, "test"), {"b.csv": "2"})
    assert victim.read_text() == "precious" and _files(folder) == {"b.csv": "2"}


def test_localize_simulate_writes_again_into_its_session_after_a_run_into_it(tmp_path, capsys):
    """The review's commands, end to end."""
    copy = tmp_path / "copy"
    simulate = ["simulate", "--route", "path3", "--map", str(SF_MAP), "-o", str(copy)]
    assert localize_main(simulate) == 0
    session_files = set(command_files(read_marker(copy))["localize simulate"])
    assert localize_main(["run", str(copy), "--map", str(SF_MAP), "--mode", "gnss", "-o", str(copy),
                          "--overwrite"]) == 0
    assert set(command_files(read_marker(copy))["localize simulate"]) == session_files
    capsys.readouterr()
    assert localize_main([*simulate[:-2], "--seed", "2", "-o", str(copy)]) == 0, capsys.readouterr().err
    assert {"track.csv", "run.json"} <= set(command_files(read_marker(copy))["localize run"])
    assert (copy / "track.csv").is_file()


def test_a_run_inside_its_session_folder_is_not_read_as_part_of_the_session(tmp_path, two_sessions):
    """`localize run S -o S/sub` is accepted: the session reads the same and a folder of sessions still
    finds S alone, since a session's files are read by name at its top level only (a Sensor Logger
    export's recordings by their motion files, which a run does not write)."""
    _, (walk, _) = two_sessions
    session = tmp_path / "sessions" / "walk"
    session.parent.mkdir()
    session.mkdir()
    for path in walk.iterdir():
        (session / path.name).write_bytes(path.read_bytes())
    before = read_any(session)
    assert localize_main(["run", str(session), "--map", str(CROSSROADS),
                          "--mode", "gnss", "-o", str(session / "sub")]) == 0
    after = read_any(session)
    assert after.tables().keys() == before.tables().keys()
    for name, table in before.tables().items():
        pd.testing.assert_frame_equal(after.tables()[name], table)
    assert expand_sessions([session.parent]) == [session]
