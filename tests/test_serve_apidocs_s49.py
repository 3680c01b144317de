"""The service's API reference and the review of 2026-12 (``localize serve`` on 127.0.0.1).

- ``/docs`` covers the WebSocket route (messages, errors, close codes, auth), lists each route's own
  errors (``/health`` claimed 401/404/409/410/413/422), renders ``double backticks`` as code (54 were
  shown raw), gives ``GET /tracks/{id}``'s answer a schema (it said "any"); offline, ``/docs/swagger``
  says it cannot load and links back to ``/docs`` (it was a blank page).
- A session ended by the WebSocket's ``end`` is listed as ``ended``, not ``deleted``.
- The JavaScript client of docs/service.md prints the track's URL (it printed the key, a 404).
- A session whose data ended before its start pose's ``t`` saves no track (it saved one row at ``t``).
- ``-v`` is ``localize``'s option, before ``serve``, as the docs now say.

Loopback only; no network.
"""

from __future__ import annotations

import json
import re
import shutil
import subprocess
import time
from pathlib import Path

import httpx
import pytest
from browser import chromium, console_errors
from fastapi.routing import APIRoute, APIWebSocketRoute
from fastapi.testclient import TestClient
from serve_fixtures import bare_client, client_for, live_service
from websockets.exceptions import ConnectionClosed
from websockets.sync.client import connect

from curbside.localize.live import IMU_QUAT_COLUMNS
from curbside.localize.serve.apidocs import api_reference_html, swagger_ui_html
from curbside.localize.serve.app import TrackRecord

REPO = Path(__file__).resolve().parents[1]
TOKEN = "s49-token-0123456789"


pytestmark = pytest.mark.usefixtures("cache_in_tmp")


@pytest.fixture
def bare(tmp_path) -> TestClient:
    return bare_client(tmp_path, TOKEN)


def _section(page: str, heading: str) -> str:
    """The part of the reference page from ``heading`` to the next heading."""
    start = page.index(heading)
    return page[start : page.index("<h", start + len(heading))]


def _walk(ipin_walk, until_s: float) -> dict:
    """The walk's first ``until_s`` seconds as a samples body."""
    imu = ipin_walk.imu[list(IMU_QUAT_COLUMNS)]
    t0 = float(imu["t"].iloc[0])
    gnss = ipin_walk.gnss[["t", "lat", "lon", "accuracy_m"]]
    return {"imu": imu[imu["t"] < t0 + until_s].to_dict("records"),
            "gnss": gnss[gnss["t"] < t0 + until_s].to_dict("records")}


# -- 1: the reference page ----------------------------------------------------------------------------


def test_the_reference_covers_every_route_the_websocket_too(bare):
    page = bare.get("/docs").text
    for route in bare.app.routes:
        if isinstance(route, APIRoute) and route.include_in_schema:
            for method in route.methods:
                assert f"{method}</span> {route.path}" in page, (method, route.path)
        elif isinstance(route, APIWebSocketRoute):
            assert f'WS</span> {route.path} <span class="tok"' in page, route.path
    stream = page[page.index("WS</span> /sessions/{session_id}/stream") : page.index("<h2>Schemas")]
    for schema in ("Samples", "Estimate", "TrackSummary", "ErrorMessage"):  # messages in and out
        assert f'<a href="#schema-{schema}">{schema}</a>' in stream, schema
    for code in ("1000", "1009", "1012", "401", "404", "410", "409", "422"):  # close codes, refusals
        assert f"<td><code>{code}</code></td>" in stream, code
    assert "<code>access_token</code>" in stream and "<code>Authorization</code>" in stream
    assert "<code>ended</code>" in stream


def test_each_route_lists_its_own_errors(bare):
    paths = bare.get("/openapi.json").json()["paths"]

    def errors(path: str, method: str) -> set[str]:
        return {s for s in paths[path][method]["responses"] if s[0] in "45"}

    assert errors("/health", "get") == {"500"}
    assert errors("/sessions/{session_id}/estimate", "get") == {"401", "404", "410", "500"}
    assert errors("/tracks", "get") == {"401", "500"}
    assert errors("/tracks/{session_id}", "get") == {"401", "404", "409", "500"}
    assert errors("/sessions", "post") == {"400", "401", "413", "415", "422", "500", "503"}
    assert {"409", "410", "413", "415", "422"} <= errors("/sessions/{session_id}/samples", "post")
    assert "416" in errors("/tracks/{session_id}/{name}", "head")
    schemas = bare.get("/openapi.json").json()["components"]["schemas"]
    assert "HTTPValidationError" not in schemas  # FastAPI's own 422, which no path parameter can get
    page = bare.get("/docs").text
    health = _section(page, "GET</span> /health</h3>")
    assert "<code>500</code>" in health and not re.search(r"<code>4\d\d</code>", health)
    estimate = _section(page, "GET</span> /sessions/{session_id}/estimate")
    assert "<td><code>410</code></td><td>the session has ended" in estimate
    assert "<code>413</code>" not in estimate and "<code>422</code>" not in estimate


def test_double_backticks_render_as_code(bare):
    page = bare.get("/docs").text
    assert "``" not in page
    assert "Keep the returned <code>id</code>" in page and "One <code>imu.csv</code> row." in page
    schema = {"info": {"title": "t", "description": "a ``<b>`` tag"}, "paths": {}}
    assert "a <code>&lt;b&gt;</code> tag" in api_reference_html(schema)  # escaped, then code


def test_get_track_answers_with_a_schema(bare):
    answer = bare.get("/openapi.json").json()["paths"]["/tracks/{session_id}"]["get"]["responses"]["200"]
    assert answer["content"]["application/json"]["schema"] == {"$ref": "#/components/schemas/TrackRecord"}
    section = _section(bare.get("/docs").text, "GET</span> /tracks/{session_id} ")
    assert '<a href="#schema-TrackRecord">TrackRecord</a>' in section and ">any<" not in section


def test_a_saved_track_reads_as_its_schema_says(tmp_path, ronin_model, ipin_walk):
    with client_for(tmp_path, ronin_model) as client:
        session_id = client.post("/sessions", json={"start": ipin_walk.meta["start"]}).json()["id"]
        client.post(f"/sessions/{session_id}/samples", json=_walk(ipin_walk, 16.0))
        assert client.delete(f"/sessions/{session_id}").json()["saved"]
        record = TrackRecord.model_validate(client.get(f"/tracks/{session_id}").json())
    assert record.track["type"] == "FeatureCollection" and record.run["service"]["reason"] == "deleted"


def _blocked_cdn(driver) -> None:
    driver.execute_cdp_cmd("Network.enable", {})
    driver.execute_cdp_cmd("Network.setBlockedURLs", {"urls": ["*cdn.jsdelivr.net*", "*tiangolo.com*"]})


def test_offline_swagger_says_so_and_links_back(bare, tmp_path):
    page = tmp_path / "swagger.html"
    page.write_text(bare.get("/docs/swagger").text, encoding="utf-8")
    with chromium(1200, 900) as driver:
        _blocked_cdn(driver)  # offline: the CDN does not answer
        driver.get(page.as_uri())
        time.sleep(0.5)
        note = driver.execute_script("const n = document.getElementById('swagger-note');"
                                     "return n && [n.innerText, n.querySelector('a').getAttribute('href')];")
        errors = console_errors(driver)
    assert note is not None, "a blank page"
    assert "could not be loaded" in note[0] and note[1] == "/docs"
    assert not [e for e in errors if "SwaggerUIBundle" in e]


def test_swagger_starts_once_its_script_has_loaded(tmp_path):
    bundle = tmp_path / "bundle.js"
    bundle.write_text("window.SwaggerUIBundle = (c) => { document.getElementById('swagger-ui').textContent ="
                      " 'UI of ' + c.url + ' ' + c.presets.length; };"
                      "SwaggerUIBundle.presets = {apis: 1}; SwaggerUIBundle.SwaggerUIStandalonePreset = 2;")
    page = tmp_path / "swagger.html"
    page.write_text(swagger_ui_html("/openapi.json", "t", js_url=bundle.as_uri(), css_url="style.css"))
    with chromium(1200, 900) as driver:
        driver.get(page.as_uri())
        time.sleep(0.3)
        assert driver.execute_script("return document.getElementById('swagger-ui').textContent") == (
            "UI of /openapi.json 2")


# -- 2: the WebSocket's end ---------------------------------------------------------------------------


def test_a_session_ended_over_the_websocket_is_listed_as_ended(tmp_path, ronin_model, ipin_walk):
    with client_for(tmp_path, ronin_model) as client:
        session_id = client.post("/sessions", json={"start": ipin_walk.meta["start"]}).json()["id"]
        with client.websocket_connect(f"/sessions/{session_id}/stream") as ws:
            ws.send_text(json.dumps({**_walk(ipin_walk, 16.0), "end": True}))
            summary = ws.receive_json()
        assert summary["reason"] == "ended" and summary["saved"]
        assert [t["reason"] for t in client.get("/tracks").json()] == ["ended"]
        assert client.get(f"/tracks/{session_id}").json()["run"]["service"]["reason"] == "ended"


# -- 4: data that never reaches the start -------------------------------------------------------------


def test_a_session_whose_data_ends_before_its_start_saves_no_track(tmp_path, ronin_model, ipin_walk):
    start = ipin_walk.meta["start"]
    t0 = float(ipin_walk.imu["t"].iloc[0])
    assert start["t"] > t0 + 10.0  # the walk's start pose is 11 s in
    with client_for(tmp_path, ronin_model) as client:
        session_id = client.post("/sessions", json={"start": start}).json()["id"]
        estimate = client.post(f"/sessions/{session_id}/samples", json=_walk(ipin_walk, 4.0)).json()
        assert estimate["status"] == "starting" and estimate["data_until"] < start["t"]
        summary = client.delete(f"/sessions/{session_id}").json()
        assert summary == {**summary, "saved": False, "updates": 0, "t_start": None, "t_end": None}
        assert client.get(f"/tracks/{session_id}").status_code == 404
        assert client.get("/tracks").json() == []


# -- 3: the JavaScript client, against a live service -------------------------------------------------


def _doc_example(name: str) -> str:
    text = (REPO / "docs" / "service.md").read_text(encoding="utf-8")
    match = re.search(rf"<!-- example: {re.escape(name)} -->\n```\w+\n(.*?)```", text, re.S)
    assert match, name
    return match.group(1)


@pytest.mark.skipif(shutil.which("node") is None, reason="node is not installed")
def test_the_javascript_client_prints_a_track_url_that_opens(tmp_path, ronin_model, ipin_walk):
    (tmp_path / "client.mjs").write_text(_doc_example("client.mjs"))
    walk = {"start": ipin_walk.meta["start"], **_walk(ipin_walk, 16.0)}
    (tmp_path / "walk.json").write_text(json.dumps(walk))
    with live_service(tmp_path, ronin_model) as (url, _):
        done = subprocess.run(
            ["node", "--experimental-websocket", str(tmp_path / "client.mjs"), url,
             str(tmp_path / "walk.json"), "1000"],
            capture_output=True, text=True, timeout=120,
        )
        assert done.returncode == 0, done.stderr
        printed = re.search(r"the track: (\S+)", done.stdout)
        assert printed, done.stdout
        answer = httpx.get(printed.group(1))
        key = httpx.get(f"{url}/tracks").json()[0]["key"]
        by_key = httpx.get(f"{url}/tracks/{key}")
    assert answer.status_code == 200 and answer.text.startswith("t,")
    assert by_key.status_code == 404  # the key names a track; the session's id reads it


def test_the_service_stopping_closes_a_websocket_with_1012(tmp_path, ronin_model, ipin_walk):
    with live_service(tmp_path, ronin_model) as (url, server):
        session_id = httpx.post(f"{url}/sessions", json={"start": ipin_walk.meta["start"]}).json()["id"]
        with connect(f"{url.replace('http', 'ws')}/sessions/{session_id}/stream", open_timeout=10) as ws:
            ws.send(json.dumps(_walk(ipin_walk, 16.0)))
            assert "detail" not in json.loads(ws.recv(timeout=30))
            server.should_exit = True
            with pytest.raises(ConnectionClosed) as closed:
                ws.recv(timeout=30)
    assert closed.value.rcvd.code == 1012
    saved = next((tmp_path / "data" / "tracks").glob("*/run.json"))
    assert json.loads(saved.read_text())["service"]["reason"] == "shutdown"


# -- 5: -v ----------------------------------------------------------------------------------------------


def test_verbose_is_localize_s_option_and_the_docs_say_so(monkeypatch, capsys):
    from curbside.cli import localize_serve
    from curbside.cli.localize import main

    seen = []
    monkeypatch.setattr(localize_serve, "_serve", lambda args: seen.append(args.verbose) or 0)
    assert main(["-v", "serve"]) == 0 and seen == [1]
    with pytest.raises(SystemExit) as refused:
        main(["serve", "-v"])
    assert refused.value.code == 2 and "unrecognized arguments: -v" in capsys.readouterr().err
    text = (REPO / "docs" / "service.md").read_text(encoding="utf-8")
    assert "localize -v serve" in text and "localize [-v] serve [--map MAP]" in text
    bare_v = [m.start() for m in re.finditer(r"\(`-v`\)", text)]
    assert not bare_v, "a `-v` that does not say where it goes"
