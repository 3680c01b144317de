"""The tracking service removes finished tracks: ``DELETE /tracks/{id}`` and the opt-in retention limits
(``localize serve --keep-tracks-days`` / ``--max-tracks``), and never a folder it did not write. The
first pass does not hold the start up, the count holds as each track is written, and a download under
way when its track goes still gets the whole file.

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
from fastapi.testclient import TestClient
from serve_fixtures import client_for

from curbside.io import MARKER
from curbside.localize.serve import service as service_module
from curbside.localize.serve import track_keeping
from curbside.localize.serve.app import create_app
from curbside.localize.serve.download import OpenFileResponse
from curbside.localize.serve.store import TrackStore, run_for
from curbside.localize.track import write_track

TOKEN = "retention-token-0123456789"
AUTH = {"Authorization": f"Bearer {TOKEN}"}
DAY_S = 86400.0


pytestmark = pytest.mark.usefixtures("cache_in_tmp")


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


def _wait_until(condition, what: str, timeout_s: float = 10.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not condition():
        assert time.monotonic() < deadline, what
        time.sleep(0.02)


def test_retention_removes_old_tracks_soon_after_start_and_periodically(
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
    monkeypatch.setattr(track_keeping, "RETENTION_PERIOD_S", 0.05)
    with client_for(tmp_path, ronin_model, keep_tracks_days=7.0) as client:
        # at start
        _wait_until(lambda: not folders["old"].exists() and not folders["older"].exists(), "no first pass")
        assert folders["young"].is_dir() and folders["younger"].is_dir()
        assert client.get("/tracks/young").status_code == 200
        assert client.get("/tracks/old").status_code == 404
        assert len(client.get("/tracks").json()) == 5  # young, younger and the three look-alikes
        # and periodically, while it runs
        _age(folders["young"], 7.5)
        _wait_until(lambda: not folders["young"].exists(), "the periodic pass did not remove the track")
        assert client.get("/tracks/young").status_code == 404
        assert folders["younger"].is_dir() and len(client.get("/tracks").json()) == 4
    assert {name: _snapshot(folder) for name, folder in foreign.items()} == before


def _walk(client, ipin_walk) -> str:
    """A session fed the whole walk (not yet ended); its id."""
    session_id = client.post("/sessions", json={"start": ipin_walk.meta["start"]}).json()["id"]
    rows = {"imu": ipin_walk.imu.to_dict("records"), "gnss": ipin_walk.gnss.to_dict("records")}
    assert client.post(f"/sessions/{session_id}/samples", json=rows).status_code == 200
    return session_id


def test_the_service_answers_and_writes_tracks_while_its_first_pass_removes_a_backlog(
    tmp_path, ronin_model, walk_result, ipin_walk, monkeypatch
):
    store = TrackStore(tmp_path / "data" / "tracks")
    backlog = [store.save(f"old-{k}", walk_result, _info()) for k in range(6)]
    for folder in backlog:
        _age(folder, 30.0)
    real_delete = TrackStore.delete

    def delete(self, key, why="deleted"):  # a slow file system: 0.5 s a track
        time.sleep(0.5)
        return real_delete(self, key, why)

    monkeypatch.setattr(TrackStore, "delete", delete)
    with client_for(tmp_path, ronin_model, keep_tracks_days=7.0) as client:
        assert client.get("/health").status_code == 200
        session_id = _walk(client, ipin_walk)
        summary = client.delete(f"/sessions/{session_id}").json()
        assert summary["saved"] and client.get(f"/tracks/{session_id}/run.json").status_code == 200
        assert sum(folder.exists() for folder in backlog) >= 2  # the pass goes on
        _wait_until(lambda: not any(folder.exists() for folder in backlog), "the backlog stays")
        assert [t["key"] for t in client.get("/tracks").json()] == [summary["key"]]


def test_max_tracks_holds_as_each_track_is_written(tmp_path, ronin_model, walk_result, ipin_walk):
    store = TrackStore(tmp_path / "data" / "tracks")
    older = [store.save(f"walk-{k}", walk_result, _info()) for k in range(3)]
    for k, folder in enumerate(older):
        _age(folder, 3 - k)
    with client_for(tmp_path, ronin_model, max_tracks=2) as client:  # the periodic pass: once a minute
        _wait_until(lambda: not older[0].exists(), "no first pass")
        session_id = _walk(client, ipin_walk)
        summary = client.delete(f"/sessions/{session_id}").json()
        listed = [t["key"] for t in client.get("/tracks").json()]  # at once, not at the next pass
        assert sorted(listed) == sorted([older[2].name, summary["key"]]) and not older[1].exists()


def test_a_store_keeps_its_count_at_each_save_without_removing_a_newer_track(tmp_path, walk_result):
    root = tmp_path / "tracks"
    writer = TrackStore(root)
    unchecked = [writer.save(f"before-{k}", walk_result, _info()) for k in range(3)]
    for k, folder in enumerate(unchecked):
        _age(folder, 10 - k)
    store = TrackStore(root, max_count=2)  # knows none of the three yet
    new = []
    for k in range(3):
        time.sleep(0.02)  # each written after the one before, on any file system's clock
        new.append(store.save(f"new-{k}", walk_result, _info()))
    assert [f.exists() for f in new] == [False, True, True] and all(f.exists() for f in unchecked)
    assert store.retain() == [f.name for f in unchecked]
    assert {t["key"] for t in store.list()} == {f.name for f in new[1:]}
    store.max_count = 1  # a save removes one track for the one it adds, the rest is the pass's
    time.sleep(0.02)
    store.save("one-more", walk_result, _info())
    assert [f.exists() for f in new] == [False, False, True] and len(store.list()) == 2


def test_a_save_never_removes_the_track_it_wrote(tmp_path, walk_result):
    # On a file system whose clock is coarse (1-2 s), or after a clock step, the new run.json can tie
    # with or read older than a track already there; the save then removed the track it had just written.
    store = TrackStore(tmp_path / "tracks", max_count=1)
    old = store.save("b-old", walk_result, _info())
    store._own[old.name] = time.time() + 60.0  # its run.json reads newer than the next one
    new = store.save("a-new", walk_result, _info())
    assert new.exists() and not old.exists()


def test_a_pass_counts_the_tracks_as_they_are_when_it_removes(tmp_path, walk_result):
    root = tmp_path / "tracks"
    writer = TrackStore(root)
    folders = [writer.save(f"walk-{k}", walk_result, _info()) for k in range(6)]
    for k, folder in enumerate(folders):
        _age(folder, 6 - k)  # walk-0 oldest
    store = TrackStore(root, max_count=3)
    steps = store.retention_pass()
    assert [next(steps) for _ in folders] == [None] * 6  # each folder checked
    store.delete(folders[5].name)  # a DELETE /tracks/{id} between two steps
    assert list(steps) == [folders[0].name, folders[1].name]
    assert [f.exists() for f in folders] == [False, False, True, True, True, False]
    assert run_for(store.retention_pass(), 0.0) is False and run_for(store.retention_pass(), 10.0) is True


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


# -- downloads while a track goes -----------------------------------------------------------------------


def _deleting_once_sending(app, service, session_id: str):
    """``app`` where ``DELETE /tracks/{session_id}`` runs when a track file's reply starts: after the
    route has returned its response, before the response has sent a byte of the file."""

    async def wrapped(scope, receive, send):
        if scope["type"] != "http" or scope["path"].count("/") < 3:
            await app(scope, receive, send)
            return

        async def send_after_deleting(message):
            if message["type"] == "http.response.start" and service.store.folder(session_id) is not None:
                await service.delete_track(session_id)
            await send(message)

        await app(scope, receive, send_after_deleting)

    return wrapped


@pytest.mark.parametrize(
    ("headers", "status", "part"),
    [({}, 200, slice(None)), ({"Range": "bytes=100-"}, 206, slice(100, None)),
     ({"Range": "bytes=-50"}, 206, slice(-50, None))],
)
def test_a_download_under_way_sends_the_whole_file_when_its_track_is_deleted(
    tmp_path, ronin_model, walk_result, headers, status, part, monkeypatch
):
    monkeypatch.setattr(OpenFileResponse, "chunk_size", 1000)  # the deletion comes before the first chunk
    folder = TrackStore(tmp_path / "data" / "tracks").save("walked", walk_result, _info())
    expected = {name: (folder / name).read_bytes()[part] for name in ("track.csv", "track.geojson")}
    config = service_module.ServiceConfig(data_dir=tmp_path / "data")
    service = service_module.TrackingService(config, ronin_model)
    app = create_app(config, service)
    with TestClient(_deleting_once_sending(app, service, "walked")) as client:
        reply = client.get("/tracks/walked/track.csv", headers=headers)
        assert not folder.exists()  # deleted while the reply was under way
        assert reply.status_code == status, reply.text
        assert reply.content == expected["track.csv"]
        assert int(reply.headers["content-length"]) == len(expected["track.csv"])
        assert client.get("/tracks/walked/track.csv").status_code == 404
        assert client.get("/tracks").json() == []


def test_a_track_file_gone_before_it_is_opened_is_a_404(tmp_path, ronin_model, walk_result, monkeypatch):
    store = TrackStore(tmp_path / "data" / "tracks")
    store.save("walked", walk_result, _info())
    with client_for(tmp_path, ronin_model) as client:
        service = client.app.state.service
        found = service.track_folder

        def found_then_deleted(session_id):  # DELETE /tracks/{id} between the check and the opening
            folder = found(session_id)
            service.store.delete(TrackStore.key(session_id))
            return folder

        monkeypatch.setattr(service, "track_folder", found_then_deleted)
        reply = client.get("/tracks/walked/run.json")
        assert reply.status_code == 404 and reply.json() == {"detail": "no such track (deleted)"}


def test_a_track_file_is_sent_whole_or_as_one_byte_range(tmp_path, ronin_model, walk_result, monkeypatch):
    folder = TrackStore(tmp_path / "data" / "tracks").save("walked", walk_result, _info())
    data = (folder / "track.csv").read_bytes()
    size = len(data)
    monkeypatch.setattr(OpenFileResponse, "chunk_size", 1000)  # several chunks per reply
    asked = {
        "bytes=10-19": (206, data[10:20]), "bytes=1500-": (206, data[1500:]), "bytes=-7": (206, data[-7:]),
        f"bytes=10-{size + 100}": (206, data[10:]), f"bytes={size}-": (416, b""), "bytes=-0": (416, b""),
        "bytes=0-9,20-29": (206, data[:30]), "items=0-9": (200, data), "bytes=9-0": (200, data),
        "": (200, data),
    }
    with client_for(tmp_path, ronin_model) as client:
        for header, (status, body) in asked.items():
            reply = client.get("/tracks/walked/track.csv", headers={"Range": header} if header else {})
            assert (reply.status_code, reply.content) == (status, body), header
            assert int(reply.headers["content-length"]) == len(body), header
            assert reply.headers["content-type"] == "text/csv; charset=utf-8"
        assert reply.headers["accept-ranges"] == "bytes"
        assert client.get("/tracks/walked/track.csv", headers={"Range": "bytes=1-"}).headers[
            "content-range"] == f"bytes 1-{size - 1}/{size}"
        assert client.get("/tracks/walked/track.csv", headers={"Range": "bytes=999999-"}).headers[
            "content-range"] == f"bytes */{size}"
        etag = reply.headers["etag"]
        for if_range, status in ((etag, 206), ('"another-version"', 200)):
            headers = {"Range": "bytes=5-", "If-Range": if_range}
            reply = client.get("/tracks/walked/track.csv", headers=headers)
            assert reply.status_code == status and reply.content == data[5 if status == 206 else 0:]
        geojson = client.get("/tracks/walked/track.geojson")
        assert geojson.headers["content-type"] == "application/geo+json" and json.loads(geojson.content)
