"""Output safety (curbside.io): which folders a command may write, what it may replace, and write errors."""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path

import pytest

from curbside.errors import CurbsideInputError
from curbside.io import (
    MARKER,
    atomic_path,
    check_output_file,
    check_output_folder,
    note_written,
    output_folder,
    read_marker,
    written_by_curbside,
)


def _write(folder_ctx, files: dict[str, str]) -> None:
    with folder_ctx as tmp:
        for rel, text in files.items():
            (tmp / rel).parent.mkdir(parents=True, exist_ok=True)
            (tmp / rel).write_text(text)


def _tree(folder: Path) -> dict[str, str]:
    return {p.relative_to(folder).as_posix(): p.read_text() for p in sorted(folder.rglob("*")) if p.is_file()}


def test_new_folder_gets_the_files_and_a_marker_listing_them(tmp_path):
    dst = tmp_path / "a" / "b" / "out"
    _write(output_folder(dst, "test cmd"), {"track.csv": "1", "figs/f.png": "2"})
    assert _tree(dst) == {MARKER: (dst / MARKER).read_text(), "figs/f.png": "2", "track.csv": "1"}
    marker = read_marker(dst)
    assert marker["command"] == "test cmd" and marker["files"] == ["figs/f.png", "track.csv"]
    assert [p.name for p in dst.parent.iterdir()] == ["out"]  # no staging debris


def test_non_empty_folder_curbside_did_not_write_is_refused_and_untouched(tmp_path):
    """Issue 10: ``localize run -o DIR`` deleted everything in DIR, including the map it was reading."""
    dst = tmp_path / "work"
    dst.mkdir()
    (dst / "map.geojson").write_text("my map")
    with pytest.raises(CurbsideInputError, match="not empty .* not written by curbside; pass --overwrite"):
        _write(output_folder(dst, "test"), {"track.csv": "1"})
    assert _tree(dst) == {"map.geojson": "my map"}


def test_overwrite_replaces_only_the_commands_files(tmp_path):
    dst = tmp_path / "work"
    dst.mkdir()
    (dst / "map.geojson").write_text("my map")
    (dst / "track.csv").write_text("an old track of mine")
    _write(output_folder(dst, "test", overwrite=True), {"track.csv": "new"})
    tree = _tree(dst)
    assert tree["map.geojson"] == "my map" and tree["track.csv"] == "new"
    assert read_marker(dst)["files"] == ["track.csv"]


def test_previous_output_is_updated_stale_outputs_removed_user_files_kept(tmp_path):
    dst = tmp_path / "run"
    _write(output_folder(dst, "test"), {"track.csv": "1", "particles.npz": "p", "figs/a.png": "a"})
    (dst / "notes.txt").write_text("mine")
    (dst / "figs" / "mine.png").write_text("mine too")
    _write(output_folder(dst, "test"), {"track.csv": "2"})  # no --overwrite needed: curbside wrote it
    tree = _tree(dst)
    assert tree["track.csv"] == "2" and "particles.npz" not in tree and "figs/a.png" not in tree
    assert tree["notes.txt"] == "mine" and tree["figs/mine.png"] == "mine too"


def test_empty_folder_and_dot(tmp_path, monkeypatch):
    """Issue 10: ``-o .`` gave an internal error."""
    here = tmp_path / "here"
    here.mkdir()
    monkeypatch.chdir(here)
    _write(output_folder(".", "test"), {"a.csv": "1"})
    _write(output_folder(".", "test"), {"a.csv": "2"})  # a previous output: fine again
    assert _tree(here)["a.csv"] == "2"
    (here / "mine.txt").write_text("x")
    _write(output_folder(".", "test"), {"a.csv": "3"})
    assert _tree(here)["mine.txt"] == "x"
    other = tmp_path / "other"
    other.mkdir()
    (other / "mine.txt").write_text("x")
    monkeypatch.chdir(other)
    with pytest.raises(CurbsideInputError, match="not empty"):
        check_output_folder(".")


def test_a_file_in_the_way(tmp_path):
    blocker = tmp_path / "taken"
    blocker.write_text("a file")
    with pytest.raises(CurbsideInputError, match="exists and is not a folder"):
        check_output_folder(blocker)
    with pytest.raises(CurbsideInputError, match="is a file, not a folder"):
        check_output_folder(blocker / "sub" / "out")
    with pytest.raises(CurbsideInputError, match="is a file, not a folder"):
        check_output_file(blocker / "map.geojson")
    assert blocker.read_text() == "a file"


def test_output_file_where_the_folder_has_a_folder_is_refused(tmp_path):
    dst = tmp_path / "out"
    (dst / "track.csv").mkdir(parents=True)  # a folder named like an output file
    with pytest.raises(CurbsideInputError, match="is a folder where the output has a file"):
        _write(output_folder(dst, "test", overwrite=True), {"track.csv": "1"})
    assert (dst / "track.csv").is_dir()


def test_unwritable_paths_are_input_errors(tmp_path, monkeypatch):
    def denied(*args, **kwargs):
        raise PermissionError(13, "Permission denied")

    monkeypatch.setattr(tempfile, "mkdtemp", denied)
    with pytest.raises(CurbsideInputError, match=r"cannot write here \(Permission denied\)"):
        _write(output_folder(tmp_path / "out", "test"), {"a": "1"})
    message = r"cannot write here \(Permission denied\)"
    with pytest.raises(CurbsideInputError, match=message), atomic_path(tmp_path / "map.geojson") as tmp:
        tmp.write_text("x")


@pytest.mark.skipif(not Path("/proc/self").is_dir(), reason="needs /proc (Linux)")
def test_a_path_on_a_file_system_that_refuses_writes():
    with pytest.raises(CurbsideInputError, match="cannot write here"):
        _write(output_folder("/proc/curbside-test/out", "test"), {"a": "1"})


@pytest.mark.skipif(os.geteuid() == 0, reason="root may write anywhere")
def test_read_only_folder_is_refused_early(tmp_path):
    locked = tmp_path / "locked"
    locked.mkdir()
    locked.chmod(0o500)
    try:
        with pytest.raises(CurbsideInputError, match="no write permission"):
            check_output_folder(locked / "out")
        with pytest.raises(CurbsideInputError, match="no write permission"):
            check_output_file(locked / "map.geojson")
    finally:
        locked.chmod(0o700)


def test_failure_inside_the_block_leaves_nothing(tmp_path):
    dst = tmp_path / "out"
    _write(output_folder(dst, "test"), {"track.csv": "1"})
    before = _tree(dst)
    with pytest.raises(RuntimeError), output_folder(dst, "test") as tmp:
        (tmp / "track.csv").write_text("half")
        raise RuntimeError("boom")
    assert _tree(dst) == before
    assert not any(p.name.startswith(".curbside-staging") for p in dst.iterdir())


def test_atomic_file_never_replaces_a_folder(tmp_path):
    folder = tmp_path / "maps"
    folder.mkdir()
    (folder / "keep.txt").write_text("k")
    with pytest.raises(CurbsideInputError, match="is a folder; give a file name"), atomic_path(folder) as tmp:
        tmp.write_text("geojson")
    assert _tree(folder) == {"keep.txt": "k"}
    with pytest.raises(CurbsideInputError, match="is a folder"):
        check_output_file(folder)


def test_atomic_folder_follows_the_folder_rules(tmp_path):
    """Code that still writes folders with atomic_path (reports, tracks) gets the same protection."""
    user = tmp_path / "mine"
    user.mkdir()
    (user / "data.csv").write_text("d")
    with pytest.raises(CurbsideInputError, match="not empty"), atomic_path(user) as tmp:
        tmp.mkdir()
        (tmp / "report.md").write_text("r")
    assert _tree(user) == {"data.csv": "d"}
    report = tmp_path / "report"
    for text in ("v1", "v2"):
        with atomic_path(report) as tmp:
            tmp.mkdir()
            (tmp / "report.md").write_text(text)
    assert _tree(report)["report.md"] == "v2"


def test_nested_outputs_and_noted_files(tmp_path):
    dst = tmp_path / "all"
    with output_folder(dst, "outer") as tmp:
        _write(output_folder(tmp / "trial1", "inner"), {"imu.csv": "i"})
    assert read_marker(dst / "trial1")["files"] == ["imu.csv"]
    assert read_marker(dst)["files"] == ["trial1/.curbside-output", "trial1/imu.csv"]
    session = dst / "trial1"
    (session / "velocity.csv").write_text("v")
    note_written(session / "velocity.csv")
    assert read_marker(session)["files"] == ["imu.csv", "velocity.csv"]
    _write(output_folder(session, "inner"), {"imu.csv": "new imu"})
    assert "velocity.csv" not in _tree(session)  # derived from the old imu.csv: removed with it
    unmarked = tmp_path / "plain"
    unmarked.mkdir()
    (unmarked / "imu.csv").write_text("the user's own")
    (unmarked / "velocity.csv").write_text("v")
    note_written(unmarked / "velocity.csv", "localize ronin")
    doc = read_marker(unmarked)
    assert (doc["command"], doc["files"]) == ("localize ronin", ["velocity.csv"])
    assert written_by_curbside(unmarked / "velocity.csv") and not written_by_curbside(unmarked / "imu.csv")
    with pytest.raises(CurbsideInputError, match="holds the output of 'localize ronin'"):
        check_output_folder(unmarked, command="localize run")


def _files(folder):
    return {k: v for k, v in _tree(folder).items() if k != MARKER}


def test_another_commands_folder_is_refused_and_kept_whole_with_overwrite(tmp_path):
    # `localize run S -o S` on a session folder that `localize convert` wrote used to delete its inputs.
    session = tmp_path / "session"
    _write(output_folder(session, "localize convert"), {"imu.csv": "i", "gnss.csv": "g"})
    with pytest.raises(CurbsideInputError, match="holds the output of 'localize convert'"):
        _write(output_folder(session, "localize run"), {"track.csv": "t"})
    assert _files(session) == {"imu.csv": "i", "gnss.csv": "g"}
    _write(output_folder(session, "localize run", overwrite=True), {"track.csv": "t"})
    assert _files(session) == {"imu.csv": "i", "gnss.csv": "g", "track.csv": "t"}
    assert read_marker(session)["commands"]["localize run"] == ["track.csv"]  # the run's own files only
    _write(output_folder(session, "localize run"), {"run.json": "r"})  # the run's stale track.csv goes
    assert _files(session) == {"imu.csv": "i", "gnss.csv": "g", "run.json": "r"}


def test_an_existing_file_is_replaced_only_when_curbside_wrote_it(tmp_path):
    mine = tmp_path / "notes.geojson"
    mine.write_text('{"type": "FeatureCollection", "features": []}')
    with pytest.raises(CurbsideInputError, match="not written by curbside; pass --overwrite"):
        check_output_file(mine)
    assert check_output_file(mine, overwrite=True) == mine
    ours = tmp_path / "map.geojson"
    ours.write_text('{"type":"FeatureCollection","curbside":{"source":"osm"},"features":[]}')
    page = tmp_path / "map.html"
    page.write_text('<!doctype html><html><head><meta name="generator" content="curbside 0.2">')
    figure = tmp_path / "map.png"
    figure.write_bytes(b"\x89PNG\r\n\x1a\n....tEXtSoftware\x00curbside 0.2....IDAT")
    for path in (ours, page, figure):
        assert check_output_file(path) == path
    with pytest.raises(CurbsideInputError, match="also an input"):
        check_output_file(ours, inputs=(tmp_path / "other.osm", ours))


def test_links_devices_and_folders_are_not_output_files(tmp_path):
    target = tmp_path / "map.geojson"
    target.write_text('{"type":"FeatureCollection","curbside":{},"features":[]}')
    link = tmp_path / "link.geojson"
    link.symlink_to(target)
    with pytest.raises(CurbsideInputError, match="symbolic link"):
        check_output_file(link, overwrite=True)
    with pytest.raises(CurbsideInputError, match="not a regular file"):
        check_output_file("/dev/null", overwrite=True)
    with pytest.raises(CurbsideInputError, match="is a folder"):
        check_output_file(tmp_path, overwrite=True)


def test_marker_cannot_make_curbside_delete_outside_the_folder(tmp_path):
    dst = tmp_path / "out"
    _write(output_folder(dst, "test"), {"a.csv": "1"})
    victim = tmp_path / "victim.txt"
    victim.write_text("precious")
    doc = json.loads((dst / MARKER).read_text())
    doc["files"] += ["../victim.txt", str(victim)]
    (dst / MARKER).write_text(json.dumps(doc))
    _write(output_folder(dst, "test"), {"b.csv": "2"})
    assert victim.read_text() == "precious"
    assert "a.csv" not in _tree(dst)


# --- every command that writes: one line, exit 2, nothing touched ------------------------------------------


def _one_line_error(capsys, message: str) -> None:
    err = capsys.readouterr().err.strip()
    assert message in err and len(err.splitlines()) == 1 and "Traceback" not in err, err


@pytest.mark.parametrize(
    "argv",
    [
        ["simulate", "--route", "path1", "-o", "{out}"],
        ["simulate", "--benchmark", "sf6", "-o", "{out}"],
        ["evaluate", "{data}/sessions", "--maps", "{data}/maps/none.geojson", "-o", "{out}"],
        ["convert", "{data}/sessions/walk.gpx", "{out}"],
    ],
    ids=["simulate", "simulate-benchmark", "evaluate", "convert"],
)
def test_folder_writing_commands_refuse_a_users_folder(tmp_path, capsys, test_data, argv):
    from curbside.cli.localize import main

    out = tmp_path / "mine"
    out.mkdir()
    (out / "notes.txt").write_text("keep me")
    assert main([a.format(out=out, data=test_data) for a in argv]) == 2
    _one_line_error(capsys, "pass --overwrite")
    assert _tree(out) == {"notes.txt": "keep me"}


@pytest.mark.parametrize(
    ("prog", "argv"),
    [
        ("osmseg", ["build", "-o", "{dir}"]),
        ("osmseg", ["show", "{data}/maps/none.geojson", "-o", "{dir}/../x.png/sub.png"]),
        ("localize", ["ronin", "{data}/sessions", "-o", "{dir}"]),
        ("localize", ["train-ronin", "-o", "{dir}"]),
        ("localize", ["convert", "{data}/sessions/walk.gpx", "{dir}/../x.png/sub"]),
    ],
    ids=["build-onto-folder", "show-under-file", "ronin-onto-folder", "train-onto-folder",
         "convert-under-file"],
)
def test_unwritable_outputs_exit_2(tmp_path, capsys, test_data, prog, argv):
    from curbside.cli.localize import main as localize
    from curbside.cli.osmseg import main as osmseg

    folder = tmp_path / "maps"
    folder.mkdir()
    (folder / "keep.txt").write_text("k")
    (tmp_path / "x.png").write_text("a file")
    main = {"osmseg": osmseg, "localize": localize}[prog]
    assert main([a.format(dir=folder, data=test_data) for a in argv]) == 2
    _one_line_error(capsys, "error:")
    assert _tree(folder) == {"keep.txt": "k"}
