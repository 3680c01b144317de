"""``HEAD`` on every ``GET`` route of the service, and the docs' JavaScript client on a Node without
``WebSocket``.

Before, ``HEAD /health``, ``/tracks``, ``/tracks/{id}`` and ``/sessions/{id}/estimate`` were a 405
(only ``HEAD /tracks/{id}/{name}`` answered): a monitor's or a proxy's ``curl -I`` could not probe the
service. Now each answers the status and headers of its ``GET`` (``Content-Length`` included, the same
401 without the token) with no body, documented as its own short operation.

The JavaScript client of docs/service.md, run on Node 20 without ``--experimental-websocket``, opened
a session over HTTP and then crashed on ``new WebSocket``, leaving the session open until it expired.
Now it checks for ``WebSocket`` first and exits with one line.

Loopback only: the FastAPI test client in process, and uvicorn on 127.0.0.1.
"""

from __future__ import annotations

import http.client
import json
import re
import shutil
import subprocess
from pathlib import Path

import httpx
import pytest
from fastapi.testclient import TestClient
from serve_fixtures import bare_client, client_for, live_service

from curbside.localize.live import IMU_QUAT_COLUMNS
from curbside.localize.serve.store import TrackStore

REPO = Path(__file__).resolve().parents[1]
TOKEN = "head-s50-token-0123456789"
AUTH = {"Authorization": f"Bearer {TOKEN}"}
#: The headers a HEAD must share with its GET.
SAME = ("content-length", "content-type", "www-authenticate")
#: Each GET route of the schema without a HEAD before this change.
PATHS = ("/health", "/tracks", "/tracks/{session_id}", "/sessions/{session_id}/estimate")


pytestmark = pytest.mark.usefixtures("cache_in_tmp")


@pytest.fixture
def bare(tmp_path) -> TestClient:
    return bare_client(tmp_path, TOKEN)


def _saved(tmp_path, walk_result, session_id: str = "walked"):
    info = {"map": None, "created": "2024-01-01T00:00:00+00:00", "ended": "2024-01-01T00:01:00+00:00",
            "reason": "deleted", "start": None, "failed": None}
    return TrackStore(tmp_path / "data" / "tracks").save(session_id, walk_result, info)


def _same(got, head) -> None:
    assert head.status_code == got.status_code, (head.status_code, got.status_code, got.text)
    assert head.content == b""
    assert {k: head.headers.get(k) for k in SAME} == {k: got.headers.get(k) for k in SAME}
    assert int(got.headers["content-length"]) == len(got.content)


# -- 1: HEAD as GET, no body --------------------------------------------------------------------------


def test_head_answers_every_get_route_as_the_get_without_a_body(tmp_path, ronin_model, walk_result):
    _saved(tmp_path, walk_result)
    with client_for(tmp_path, ronin_model, token=TOKEN) as client:
        session_id = client.post("/sessions", headers=AUTH).json()["id"]
        paths = [p.replace("{session_id}", "walked" if p.startswith("/tracks") else session_id)
                 for p in PATHS]
        for path in [*paths, "/tracks/nobody", f"/tracks/{session_id}", "/sessions/nobody/estimate"]:
            for headers in (AUTH, {}, {"Authorization": "Bearer wrong"}):
                got, head = client.get(path, headers=headers), client.head(path, headers=headers)
                _same(got, head)
                if headers is not AUTH and path != "/health":
                    assert head.status_code == 401 and head.headers["www-authenticate"] == "Bearer", path
        assert client.head("/tracks/walked", headers=AUTH).status_code == 200
        assert client.head("/tracks/nobody", headers=AUTH).status_code == 404
        assert client.head(f"/tracks/{session_id}", headers=AUTH).status_code == 409  # still open
        client.delete(f"/sessions/{session_id}", headers=AUTH)  # its filter never started: no track
        ended = f"/sessions/{session_id}/estimate"
        _same(client.get(ended, headers=AUTH), client.head(ended, headers=AUTH))


def test_head_over_uvicorn_sends_the_length_and_no_body(tmp_path, ronin_model, walk_result):
    _saved(tmp_path, walk_result)
    with live_service(tmp_path, ronin_model) as (url, _):
        host, port = url.removeprefix("http://").split(":")
        for path in ("/health", "/tracks", "/tracks/walked", "/tracks/nobody", "/docs"):
            got = httpx.get(url + path)
            connection = http.client.HTTPConnection(host, int(port), timeout=30)
            connection.request("HEAD", path)
            head = connection.getresponse()
            assert head.status == got.status_code, path
            assert head.getheader("content-length") == got.headers["content-length"] == str(len(got.content))
            assert head.getheader("content-type") == got.headers["content-type"]
            assert head.read() == b""
            connection.request("GET", path)  # the same connection: nothing of a body was left in it
            assert connection.getresponse().read() == got.content
            connection.close()


def test_the_pages_answer_head_too(bare):
    for path in ("/docs", "/docs/swagger", "/openapi.json"):
        got, head = bare.get(path), bare.head(path)
        assert head.status_code == got.status_code == 200 and head.content == b"", path
        assert head.headers["content-length"] == got.headers["content-length"]


# -- 2: the schema and the reference page ------------------------------------------------------------


def test_each_head_is_a_short_operation_of_its_own_with_the_get_s_errors(bare):
    paths = bare.get("/openapi.json").json()["paths"]
    page = bare.get("/docs").text
    ids = [op["operationId"] for item in paths.values() for op in item.values()]
    assert len(ids) == len(set(ids))
    for path in PATHS:
        get, head = paths[path]["get"], paths[path]["head"]
        assert set(head["responses"]) == set(get["responses"]), path
        assert all("content" not in answer for answer in head["responses"].values()), path
        assert head["responses"]["200"]["description"].endswith("no body")
        assert head["description"] != get.get("description") and "without the body" in head["description"]
        assert head["summary"].startswith("Head ") and head.get("security") == get.get("security")
        assert head["tags"] == get["tags"]
        for status in get["responses"]:
            if status[0] in "45":
                assert head["responses"][status]["description"] == get["responses"][status]["description"]
        section = page[re.search(f"HEAD</span> {re.escape(path)}[ <]", page).start() :]
        section = section[: section.index("<h3", 10)]
        assert "without the body" in section and "<code>200</code>" in section
        assert "<a href" not in section  # no body, no schema
    assert "HEAD</span> /health</h3>" in page  # no token mark: /health needs none
    assert list(paths["/health"]) == ["get", "head"]


# -- 3: the JavaScript client on a Node without WebSocket ---------------------------------------------


def _doc_example(name: str) -> str:
    text = (REPO / "docs" / "service.md").read_text(encoding="utf-8")
    match = re.search(rf"<!-- example: {re.escape(name)} -->\n```\w+\n(.*?)```", text, re.S)
    assert match, name
    return match.group(1)


def _node_without_websocket() -> list[str] | None:
    """The command of a Node with no global ``WebSocket`` (Node 20 by default; Node 22 and later with
    ``--no-experimental-websocket``), or ``None`` where there is none."""
    if shutil.which("node") is None:
        return None
    for command in (["node"], ["node", "--no-experimental-websocket"]):
        probe = subprocess.run([*command, "-e", "process.exit(typeof WebSocket === 'undefined' ? 0 : 1)"],
                               capture_output=True, timeout=60)
        if probe.returncode == 0:
            return command
    return None


@pytest.mark.skipif(shutil.which("node") is None, reason="node is not installed")
def test_the_javascript_client_without_websocket_says_so_and_opens_no_session(tmp_path, ronin_model,
                                                                            ipin_walk):
    node = _node_without_websocket()
    if node is None:
        pytest.skip("this node cannot run without WebSocket")
    (tmp_path / "client.mjs").write_text(_doc_example("client.mjs"))
    imu = ipin_walk.imu[list(IMU_QUAT_COLUMNS)]
    imu = imu[imu["t"] < imu["t"].iloc[0] + 8.0]
    gnss = ipin_walk.gnss[["t", "lat", "lon", "accuracy_m"]]
    walk = {"start": ipin_walk.meta["start"], "imu": imu.to_dict("records"),
            "gnss": gnss[gnss["t"] < imu["t"].iloc[-1]].to_dict("records")}
    (tmp_path / "walk.json").write_text(json.dumps(walk))
    args = [str(tmp_path / "client.mjs"), "URL", str(tmp_path / "walk.json"), "1000"]
    with live_service(tmp_path, ronin_model) as (url, _):
        args[1] = url
        without = subprocess.run([*node, *args], capture_output=True, text=True, timeout=120)
        sessions_after_without = httpx.get(f"{url}/health").json()["sessions"]
        with_it = subprocess.run(["node", "--experimental-websocket", *args], capture_output=True, text=True,
                                 timeout=120)
        tracks = httpx.get(f"{url}/tracks").json()
    assert without.returncode != 0 and without.stdout == ""
    assert without.stderr.strip().count("\n") == 0, without.stderr  # one line, no stack trace
    assert "Node 22" in without.stderr and "--experimental-websocket" in without.stderr
    assert sessions_after_without == 0
    assert with_it.returncode == 0, with_it.stderr
    assert "ended: " in with_it.stdout and len(tracks) <= 1
