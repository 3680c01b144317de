"""What a review of ``localize serve`` on 127.0.0.1 found: an IMU stream too slow to track, session ids in
the log, ``null`` for an optional field, and a body not sent as JSON."""

from __future__ import annotations

import inspect
import logging
import math

import pytest
from serve_fixtures import client_for

from curbside.localize.serve import app as app_module
from curbside.localize.serve.common import session_label
from curbside.localize.serve.store import TrackStore

START = {"lat": 37.79, "lon": -122.39, "heading_deg": 0.0}
FAILED = ": the session cannot go on (open a new session)"


pytestmark = pytest.mark.usefixtures("cache_in_tmp")


@pytest.fixture
def client(tmp_path, ronin_model):
    with client_for(tmp_path, ronin_model) as client:
        yield client


def _rows(n: int, rate_hz: float, t0: float = 0.0, gyro: float = 0.01) -> list[dict]:
    """``n`` IMU rows at ``rate_hz`` from ``t0``: gravity with a little bounce, a slow turn."""
    return [
        {"t": t0 + k / rate_hz, "ax": 0.1, "ay": 0.2, "az": 9.8 + 0.5 * math.sin(k), "gx": gyro, "gy": gyro,
         "gz": gyro}
        for k in range(n)
    ]


def _new(client, **body) -> str:
    reply = client.post("/sessions", json={"start": START, **body})
    assert reply.status_code == 201, reply.text
    return reply.json()["id"]


def _curbside_warnings(caplog) -> list[str]:
    records = [r for r in caplog.records if r.name.startswith("curbside")]
    return [r.getMessage() for r in records if r.levelno >= logging.WARNING]


# -- 1, 2: an IMU stream too slow (or otherwise unusable) fails the session, and the reply says so ---------


def test_the_batch_that_shows_a_10_hz_stream_fails_the_session_and_says_so(client):
    session_id = _new(client)
    reply = client.post(f"/sessions/{session_id}/samples", json={"imu": _rows(201, 10.0)})
    assert reply.status_code == 422
    assert reply.json()["detail"] == f"imu: IMU rate 10.0 Hz is below the 20 Hz minimum for RoNIN{FAILED}"
    estimate = client.get(f"/sessions/{session_id}/estimate").json()
    assert estimate["status"] == "failed" and estimate["data_until"] is None  # its rows were not taken
    why = "IMU rate 10.0 Hz is below the 20 Hz minimum for RoNIN"
    assert estimate["warnings"] == [f"the session cannot go on: {why}"]
    later = client.post(f"/sessions/{session_id}/samples", json={"imu": _rows(50, 50.0, 30.0)})
    assert later.status_code == 422 and later.json()["detail"] == f"session: unusable: {why}"


def test_rows_refused_as_such_leave_the_session_as_it_was_even_when_they_are_slow(client):
    """Epoch milliseconds 100 ms apart look like a 0.01 Hz stream: they are refused for their unit, and
    the session goes on; the rate is judged only on rows the session would take."""
    session_id = _new(client)
    millis = [dict(row, t=1.7e12 + row["t"] * 1000.0) for row in _rows(30, 10.0)]
    reply = client.post(f"/sessions/{session_id}/samples", json={"imu": millis})
    assert reply.status_code == 422 and "not seconds" in reply.json()["detail"]
    assert FAILED not in reply.json()["detail"]
    assert client.get(f"/sessions/{session_id}/estimate").json()["status"] == "starting"
    assert client.post(f"/sessions/{session_id}/samples", json={"imu": _rows(150, 50.0)}).status_code == 200


def test_a_stream_the_ronin_start_up_decision_refuses_says_so_in_the_clients_words(client):
    session_id = _new(client)
    reply = client.post(f"/sessions/{session_id}/samples", json={"imu": _rows(150, 50.0, gyro=0.0)})
    assert reply.status_code == 422
    assert reply.json()["detail"] == f"imu: gyroscope columns are all zero: no gyroscope data{FAILED}"
    assert client.get(f"/sessions/{session_id}/estimate").json()["status"] == "failed"


def test_a_1_hz_stream_fails_with_a_warning_and_the_log_says_it_once(client, caplog):
    caplog.set_level(logging.INFO)
    session_id = _new(client)
    url = f"/sessions/{session_id}/samples"
    replies = [client.post(url, json={"imu": [row]}) for row in _rows(60, 1.0, 1.0)]
    refused = [k for k, reply in enumerate(replies) if reply.status_code != 200]
    assert refused and refused[0] == 10  # judged on 10 intervals and 2 s of rows, gaps included
    assert replies[10].status_code == 422
    why = "IMU rate 1.0 Hz is below the 20 Hz minimum for RoNIN"
    assert replies[10].json()["detail"] == f"imu: {why}{FAILED}"
    estimate = client.get(f"/sessions/{session_id}/estimate").json()
    assert estimate["status"] == "failed" and "IMU rate 1.0 Hz" in estimate["warnings"][0]
    assert client.delete(f"/sessions/{session_id}").json()["saved"] is False
    warnings = _curbside_warnings(caplog)
    assert len(warnings) == 1 and "IMU rate 1.0 Hz" in warnings[0], warnings
    # the same rows in one batch: refused at once
    other = _new(client)
    reply = client.post(f"/sessions/{other}/samples", json={"imu": _rows(60, 1.0, 1.0)})
    assert reply.status_code == 422 and reply.json()["detail"].endswith(FAILED)


def test_a_50_hz_stream_with_an_early_gap_is_not_judged_slow(client):
    session_id = _new(client)
    rows = _rows(3, 50.0) + _rows(200, 50.0, 1.5)  # one 1.46 s gap among 202 intervals
    assert client.post(f"/sessions/{session_id}/samples", json={"imu": rows}).status_code == 200
    assert client.get(f"/sessions/{session_id}/estimate").json()["status"] != "failed"


# -- 3: no part of a session id in the log or in a detail ---------------------------------------------------


def test_the_log_names_a_session_by_a_label_of_its_track_key_never_by_its_id(client, caplog):
    caplog.set_level(logging.INFO)
    session_id = _new(client)
    late_fix = {"t": 0.5, "lat": START["lat"], "lon": START["lon"], "accuracy_m": 5.0}
    client.post(f"/sessions/{session_id}/samples", json={"imu": _rows(300, 50.0)})
    client.post(f"/sessions/{session_id}/samples", json={"gnss": [late_fix]})  # dropped: logged
    details = [client.post(f"/sessions/{session_id}/samples", json={"imu": _rows(30, 10.0, 10.0)}).text]
    summary = client.delete(f"/sessions/{session_id}").json()
    label = session_label(session_id)
    assert label == f"session {TrackStore.key(session_id)[:8]}" and summary["key"].startswith(label[-8:])
    logged = [r.getMessage() for r in caplog.records if r.name.startswith("curbside")]
    assert any(line.startswith(f"{label} ended (deleted)") for line in logged), logged
    assert any(line.startswith(f"{label}: 1 fix(es)") for line in logged), logged
    for text in [*logged, *details]:
        assert not any(session_id[i : i + 6] in text for i in range(len(session_id) - 5)), text


def test_uvicorn_websocket_lines_show_the_label_and_no_token():
    record = logging.LogRecord(
        "uvicorn.error", logging.INFO, __file__, 1, '%s - "WebSocket %s" [accepted]',
        ("127.0.0.1:50132", "/sessions/AbCdEf0123456789-_xyzXYZ0123456789/stream?access_token=s3cret"), None,
    )
    assert app_module._SessionIdFilter().filter(record)
    label = session_label("AbCdEf0123456789-_xyzXYZ0123456789")
    assert record.getMessage() == f'127.0.0.1:50132 - "WebSocket /sessions/<{label}>/stream" [accepted]'
    # the format the filter recognises is uvicorn's own
    from uvicorn.protocols.websockets import websockets_sansio_impl

    assert "'%s - \"WebSocket %s\" [accepted]'" in inspect.getsource(websockets_sansio_impl)


# -- 4: null is the same as absent -------------------------------------------------------------------------


def test_null_is_the_same_as_leaving_an_optional_field_out(client):
    assert client.post("/sessions", json={"config": None}).status_code == 201
    session_id = _new(client, config=None)
    assert client.get(f"/sessions/{session_id}/estimate").json()["status"] == "starting"
    reply = client.post(f"/sessions/{session_id}/samples", json={"imu": None, "gnss": None, "end": None})
    assert reply.status_code == 200 and reply.json()["data_until"] is None
    reply = client.post(f"/sessions/{session_id}/samples", json={"imu": _rows(10, 50.0), "gnss": None})
    assert reply.status_code == 200 and reply.json()["data_until"] == pytest.approx(0.18)
    schemas = client.get("/openapi.json").json()["components"]["schemas"]
    optional = (("NewSession", "start"), ("NewSession", "config"), ("Samples", "imu"), ("Samples", "end"))
    for model, field in optional:
        assert {"type": "null"} in schemas[model]["properties"][field]["anyOf"], (model, field)


# -- 5: a body not sent as JSON ----------------------------------------------------------------------------


def test_a_body_not_sent_as_json_gets_415_saying_so(tmp_path, ronin_model):
    with client_for(tmp_path, ronin_model, token="t0ken-0123456789") as client:
        auth = {"Authorization": "Bearer t0ken-0123456789"}
        reply = client.post("/sessions", content=b"{}", headers={**auth, "content-type": "text/plain"})
        assert reply.status_code == 415
        assert reply.json()["detail"] == (
            "the body must be JSON, sent as Content-Type: application/json (not text/plain)"
        )
        bare = client.post("/sessions", content=b"{}", headers=auth)  # no Content-Type at all
        assert bare.status_code == 415 and "(not no Content-Type)" in bare.json()["detail"]
        unauthorised = client.post("/sessions", content=b"{}", headers={"content-type": "text/plain"})
        assert unauthorised.status_code == 401  # the token first
        for media in ("application/json; charset=utf-8", "application/vnd.curbside+json"):
            reply = client.post("/sessions", content=b"{}", headers={**auth, "content-type": media})
            assert reply.status_code == 201, media
        no_body = client.post("/sessions", headers={**auth, "content-type": "text/plain"})
        assert no_body.status_code == 201
        session_id = no_body.json()["id"]
        reply = client.post(
            f"/sessions/{session_id}/samples", content=b'{"imu": []}',
            headers={**auth, "content-type": "application/x-www-form-urlencoded"},
        )
        assert reply.status_code == 415 and "x-www-form-urlencoded" in reply.json()["detail"]
        paths = client.get("/openapi.json").json()["paths"]
        assert "415" in paths["/sessions"]["post"]["responses"]
        assert "415" in paths["/sessions/{session_id}/samples"]["post"]["responses"]
