"""The tracking service removes finished tracks: ``DELETE /tracks/{id}`` and the opt-in retention limits
(``localize serve --keep-tracks-days`` / ``--max-tracks``), and never a folder it did not write.

Loopback only: the FastAPI test client in process.
"""

from __future__ import annotations

import json
import os
import shutil
import time
from pathlib import Path
from types import SimpleNamespace

import pytest
from serve_fixtures import client_for

from curbside.io import MARKER
from curbside.localize.live import stream_session
from curbside.localize.runconfig import RunConfig
from curbside.localize.serve import service as service_module
from curbside.localize.serve.store import TrackStore
from curbside.localize.track import write_track

TOKEN = "retention-token-0123456789"
AUTH = {"Authorization": f"Bearer {TOKEN}"}
DAY_S = 86400.0


@pytest.fixture(autouse=True)
def _cache_in_tmp(tmp_path, monkeypatch):
    monkeypatch.setattr("curbside.settings.cache_dir", tmp_path / "cache")


@pytest.fixture(scope="module")
def walk_result(ipin_walk, ronin_model):
    """The real walk's track, as a session of the service would leave it."""
    return stream_session(ipin_walk, None, RunConfig.for_mode("fused"), ronin_model)


def _info() -> dict:
    return {"map": None, "created": "2024-01-01T00:00:00+00:00", "ended": "2024-01-01T00:01:00+00:00",
            "reason": "deleted", "start": None, "failed": None}


def _age(folder: Path, days: float) -> None:
    """Make every file of ``folder`` look ``days`` old."""
    then = time.time() - days * DAY_S
    for path in [*folder.iterdir(), folder]:
        os.utime(path, (then, then), follow_symlinks=False)


def _snapshot(folder: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir())}


def _look_alikes(root: Path, walk_result, source: Path) -> dict[str, Path]:
    """Folders in the tracks folder, named as tracks, that the service did not write: a copy of a
    service track without its marker, a ``localize run`` output, and a link to a service track."""
    folders = {}
    copied = root / TrackStore.key("copied")
    shutil.copytree(source, copied)
    (copied / MARKER).unlink()
    folders["copied"] = copied
    run = write_track(walk_result, root / TrackStore.key("run"), {"session": "walk.h5", "map": None})
    folders["run"] = run
    linked = root / TrackStore.key("linked")
    elsewhere = root.parent / "elsewhere"
    shutil.copytree(source, elsewhere)
    linked.symlink_to(elsewhere, target_is_directory=True)
    folders["linked"] = elsewhere
    return folders


# -- DELETE /tracks/{id} ------------------------------------------------------------------------------


def test_delete_removes_a_finished_track_and_then_it_is_404(tmp_path, ronin_model, ipin_walk):
    with client_for(tmp_path, ronin_model, token=TOKEN) as client:
        reply = client.post("/sessions", json={"start": ipin_walk.meta["start"]}, headers=AUTH)
        session_id = reply.json()["id"]
        imu = ipin_walk.imu.to_dict("records")
        gnss = ipin_walk.gnss.to_dict("records")
        reply = client.post(f"/sessions/{session_id}/samples", json={"imu": imu, "gnss": gnss}, headers=AUTH)
        assert reply.status_code == 200, reply.text
        reply = client.delete(f"/tracks/{session_id}", headers=AUTH)
        assert reply.status_code == 409 and "still open" in reply.json()["detail"]
        summary = client.delete(f"/sessions/{session_id}", headers=AUTH).json()
        assert summary["saved"]
        folder = tmp_path / "data" / "tracks" / summary["key"]
        assert [t["key"] for t in client.get("/tracks", headers=AUTH).json()] == [summary["key"]]

        assert client.delete(f"/tracks/{session_id}").status_code == 401  # the token guards it
        assert folder.is_dir()
        reply = client.delete(f"/tracks/{session_id}", headers=AUTH)
        assert reply.status_code == 200, reply.text
        assert reply.json()["key"] == summary["key"] and reply.json()["updates"] == summary["updates"]
        assert not folder.exists()
        assert client.get("/tracks", headers=AUTH).json() == []
        assert client.get(f"/tracks/{session_id}", headers=AUTH).status_code == 404
        assert client.get(f"/tracks/{session_id}/track.csv", headers=AUTH).status_code == 404
        assert client.get(f"/sessions/{session_id}/estimate", headers=AUTH).status_code == 404  # was 410
        assert client.delete(f"/tracks/{session_id}", headers=AUTH).status_code == 404
        assert client.delete("/tracks/no-such-session", headers=AUTH).status_code == 404


def test_a_folder_the_service_did_not_write_is_never_deleted(tmp_path, ronin_model, walk_result):
    root = tmp_path / "data" / "tracks"
    store = TrackStore(root)
    own = store.save("own", walk_result, _info())
    folders = _look_alikes(root, walk_result, own)
    before = {name: _snapshot(folder) for name, folder in folders.items()}
    (own / "notes.txt").write_text("the operator's", encoding="utf-8")  # a file the service did not write
    with client_for(tmp_path, ronin_model) as client:
        assert len(client.get("/tracks").json()) == 4  # all four look like tracks
        for name in folders:
            reply = client.delete(f"/tracks/{name}")
            assert reply.status_code == 409 and "not written by the service" in reply.json()["detail"], name
        assert {name: _snapshot(folder) for name, folder in folders.items()} == before
        assert (root / TrackStore.key("linked")).is_symlink()
        # the service's own track goes, the operator's file (and so its folder) stays
        assert client.delete("/tracks/own").status_code == 200
        assert client.get("/tracks/own").status_code == 404
        assert sorted(p.name for p in own.iterdir()) == ["notes.txt"]
        assert len(client.get("/tracks").json()) == 3


# -- retention ----------------------------------------------------------------------------------------


def test_retention_removes_old_tracks_only_at_start_and_periodically(
    tmp_path, ronin_model, walk_result, monkeypatch
):
    root = tmp_path / "data" / "tracks"
    store = TrackStore(root)
    folders = {name: store.save(name, walk_result, _info()) for name in ("old", "older", "young", "younger")}
    for name, days in (("old", 8.0), ("older", 30.0), ("young", 6.0), ("younger", 0.0)):
        _age(folders[name], days)
    foreign = _look_alikes(root, walk_result, folders["young"])
    for folder in [*foreign.values(), root / TrackStore.key("linked")]:
        _age(folder, 30.0)
    before = {name: _snapshot(folder) for name, folder in foreign.items()}
    monkeypatch.setattr(service_module, "RETENTION_PERIOD_S", 0.05)
    with client_for(tmp_path, ronin_model, keep_tracks_days=7.0) as client:
        # at start, before the first request
        assert not folders["old"].exists() and not folders["older"].exists()
        assert folders["young"].is_dir() and folders["younger"].is_dir()
        assert client.get("/tracks/young").status_code == 200
        assert client.get("/tracks/old").status_code == 404
        assert len(client.get("/tracks").json()) == 5  # young, younger and the three look-alikes
        # and periodically, while it runs
        _age(folders["young"], 7.5)
        deadline = time.monotonic() + 10.0
        while folders["young"].exists():
            assert time.monotonic() < deadline, "the periodic retention pass did not remove the track"
            time.sleep(0.05)
        assert client.get("/tracks/young").status_code == 404
        assert folders["younger"].is_dir() and len(client.get("/tracks").json()) == 4
    assert {name: _snapshot(folder) for name, folder in foreign.items()} == before


def test_max_tracks_keeps_the_newest_and_ignores_folders_it_did_not_write(tmp_path, walk_result):
    root = tmp_path / "tracks"
    writer = TrackStore(root)
    folders = [writer.save(f"walk-{k}", walk_result, _info()) for k in range(5)]
    for k, folder in enumerate(folders):
        _age(folder, 5 - k)  # walk-0 oldest
    foreign = _look_alikes(root, walk_result, folders[4])
    _age(foreign["copied"], 100.0)
    store = TrackStore(root, max_count=2)
    assert store.retain() == [TrackStore.key(f"walk-{k}") for k in range(3)]
    assert [f.exists() for f in folders] == [False, False, False, True, True]
    assert all(folder.is_dir() for folder in foreign.values())
    assert {t["key"] for t in store.list()} == {f.name for f in folders[3:]} | {
        TrackStore.key(name) for name in foreign
    }
    assert store.retain() == []  # a second pass finds nothing more to remove
    assert json.loads((foreign["run"] / "run.json").read_text())["session"] == "walk.h5"


# -- the command line ---------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("args", "problem"),
    [
        (["--keep-tracks-days", "0"], "must be positive"),
        (["--keep-tracks-days=-3"], "must be positive"),
        (["--keep-tracks-days", "nan"], "must be finite"),
        (["--keep-tracks-days", "inf"], "must be finite"),
        (["--keep-tracks-days", "a week"], "not a number"),
        (["--max-tracks", "0"], "must be at least 1"),
        (["--max-tracks", "2.5"], "not an integer"),
    ],
)
def test_bad_retention_values_are_a_one_line_usage_error(args, problem, capsys):
    from curbside.cli.localize import main

    with pytest.raises(SystemExit) as stopped:
        main(["serve", *args])
    assert stopped.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and args[0].split("=")[0] in err[0] and problem in err[0]


def test_retention_options_reach_the_service_and_its_start_line(monkeypatch, capsys):
    from curbside.cli import localize_serve
    from curbside.cli.localize import main

    seen = []

    def fake_service(config):
        seen.append(config)
        return SimpleNamespace(places={})

    monkeypatch.setattr(localize_serve, "_check_port", lambda host, port: None)
    monkeypatch.setattr("torch.set_num_threads", lambda n: None)
    monkeypatch.setattr("uvicorn.run", lambda *args, **kwargs: None)
    monkeypatch.setattr("curbside.localize.serve.app.create_app", lambda config, service: None)
    monkeypatch.setattr(service_module, "TrackingService", fake_service)
    assert main(["serve", "--keep-tracks-days", "7", "--max-tracks", "500"]) == 0
    assert main(["serve"]) == 0
    assert [(c.keep_tracks_days, c.max_tracks) for c in seen] == [(7.0, 500), (None, None)]
    out = capsys.readouterr().out.splitlines()
    assert "(kept: 7 days, at most the newest 500)" in out[0] and "kept" not in out[1]
