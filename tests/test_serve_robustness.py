"""The live tracking service under input and failures that once broke it: every one gets an answer.

A session whose end fails is answered and gone, and the shutdown always completes; a bug is a JSON 500;
times that are not seconds, negative seeds, absurd headings and ``end`` over HTTP are refused naming
the field; binary WebSocket frames are messages; a chunked body over the limit is a 413; refused
WebSockets log no error; fixes claiming an accuracy of 1e-300 m do not stop a session; the displacement
does not depend on how the velocities are chunked. Loopback only.
"""

from __future__ import annotations

import asyncio
import json
import logging
import math
import time

import numpy as np
import pytest
from fastapi.testclient import TestClient
from serve_fixtures import client_for, live_service
from websockets.exceptions import InvalidStatus
from websockets.sync.client import connect

from curbside.localize.live import IMU_QUAT_COLUMNS, LiveSession
from curbside.localize.serve import app as app_module
from curbside.localize.serve import service as service_module
from curbside.localize.serve.app import MAX_BODY_BYTES, create_app
from curbside.localize.serve.service import ServiceConfig, ServiceError, TrackingService
from curbside.localize.streams import DisplacementIntegrator

pytestmark = pytest.mark.usefixtures("cache_in_tmp")


def _rows(ipin_walk, until_t: float) -> tuple[np.ndarray, np.ndarray]:
    imu = ipin_walk.imu[list(IMU_QUAT_COLUMNS)].to_numpy(float)
    gnss = ipin_walk.gnss[["t", "lat", "lon", "accuracy_m"]].to_numpy(float)
    return imu[imu[:, 0] < until_t], gnss[gnss[:, 0] < until_t]


def _imu_row(t: float, **change) -> dict:
    return {"t": t, "ax": 0.1, "ay": 0.2, "az": 9.8, "gx": 0.01, "gy": 0.0, "gz": 0.0} | change


def _fix(t: float, accuracy_m: float = 5.0) -> dict:
    return {"t": t, "lat": 49.46126, "lon": 11.11101, "accuracy_m": accuracy_m}


# -- a session that cannot end ---------------------------------------------------------------------------


def test_a_session_whose_end_fails_is_answered_and_gone_and_the_shutdown_completes(
    tmp_path, ronin_model, ipin_walk, monkeypatch, caplog
):
    """``finish_streams`` raising (as scipy did for a row at t=1e20) used to leave DELETE unanswered,
    the session stuck "ending" for good and the shutdown waiting on it."""
    service = TrackingService(ServiceConfig(data_dir=tmp_path / "data"), ronin_model)
    imu, gnss = _rows(ipin_walk, 70.0)  # past the start pose's t (61.4 s): the filter starts on data
    broken: set[LiveSession] = set()
    finish = LiveSession.finish_streams

    def finish_streams(live: LiveSession) -> None:
        if live in broken:
            raise ValueError("Found zero norm quaternions in `quat`.")
        finish(live)

    monkeypatch.setattr(LiveSession, "finish_streams", finish_streams)

    async def scenario() -> None:
        await service.start()
        entries = [await service.create(ipin_walk.meta["start"], {"seed": 3}) for _ in range(3)]
        for entry in entries:
            await service.push(entry.id, imu, IMU_QUAT_COLUMNS, gnss)
        bad, good, left_open = entries
        broken.update({bad.live, left_open.live})
        with pytest.raises(ServiceError) as failed:
            await asyncio.wait_for(service.end(bad.id), 20.0)
        assert failed.value.status == 500 and "\n" not in failed.value.detail
        assert "finishing it failed (internal error (ValueError))" in failed.value.detail
        assert bad.id not in service.sessions  # gone: no slot held, nothing to expire
        with pytest.raises(ServiceError) as again:
            await service.end(bad.id)
        assert again.value.status in (404, 410)
        assert (await asyncio.wait_for(service.end(good.id), 20.0))["saved"]  # the others go on
        await asyncio.wait_for(service.stop(), 20.0)  # left_open fails to end at the shutdown
        assert not service.sessions

    with caplog.at_level(logging.ERROR, logger="curbside.localize.serve.service"):
        asyncio.run(scenario())
    assert any("end failed" in r.getMessage() for r in caplog.records)


def test_a_bug_in_a_route_is_a_json_500_without_the_traceback(tmp_path, ronin_model, monkeypatch):
    config = ServiceConfig(data_dir=tmp_path / "data")
    service = TrackingService(config, ronin_model)

    def estimate(session_id: str) -> dict:
        raise RuntimeError("secret internals")

    monkeypatch.setattr(service, "estimate", estimate)
    with TestClient(create_app(config, service), raise_server_exceptions=False) as client:
        session_id = client.post("/sessions", json={}).json()["id"]
        reply = client.get(f"/sessions/{session_id}/estimate")
        assert reply.status_code == 500
        assert reply.json() == {"detail": "internal error (RuntimeError); see the service log"}
        assert client.delete(f"/sessions/{session_id}").status_code == 200  # the service goes on


def test_the_shutdown_completes_when_a_session_never_finishes(tmp_path, ronin_model, ipin_walk, monkeypatch):
    monkeypatch.setattr(service_module, "STOP_WAIT_S", 0.5)
    monkeypatch.setattr(LiveSession, "drained", property(lambda live: False))  # its windows never return
    service = TrackingService(ServiceConfig(data_dir=tmp_path / "data"), ronin_model)
    imu, gnss = _rows(ipin_walk, 60.0)

    async def scenario() -> None:
        await service.start()
        entry = await service.create(ipin_walk.meta["start"], {})
        await service.push(entry.id, imu, IMU_QUAT_COLUMNS, gnss)
        deleting = asyncio.create_task(service.end(entry.id))
        await asyncio.sleep(0.1)
        await asyncio.wait_for(service.stop(), 10.0)
        with pytest.raises(ServiceError) as stopped:
            await asyncio.wait_for(deleting, 5.0)  # answered, not left waiting
        assert stopped.value.status == 503

    asyncio.run(scenario())


# -- refused input names the field -------------------------------------------------------------------------


def test_times_that_are_not_seconds_are_refused_in_every_stream_and_the_start(
    tmp_path, ronin_model, ipin_walk
):
    """A row at t=1e20 used to be taken, then break the session's end (the test above)."""
    with client_for(tmp_path, ronin_model) as client:
        start = ipin_walk.meta["start"]
        reply = client.post("/sessions", json={"start": start | {"t": 1.7e12}})
        assert reply.status_code == 422
        assert reply.json()["detail"].startswith("start.t: t=1700000000000.0 is not seconds on a clock")
        session_id = client.post("/sessions", json={"start": start}).json()["id"]
        path = f"/sessions/{session_id}/samples"
        for body, where in [
            ({"imu": [_imu_row(1e20)]}, "imu[0].t"),
            ({"imu": [_imu_row(50.0), _imu_row(-1e10)]}, "imu[1].t"),
            ({"gnss": [_fix(50.0), _fix(1.7e18)]}, "gnss[1].t"),
        ]:
            reply = client.post(path, json=body)
            assert reply.status_code == 422, reply.text
            detail = reply.json()["detail"]
            assert detail.startswith(f"{where}: t=") and "|t| must be under 1e10 s" in detail, detail
        rows = [_imu_row(50.0 + i / 50) for i in range(50)]
        assert client.post(path, json={"imu": rows}).status_code == 200  # nothing was changed
        assert client.delete(f"/sessions/{session_id}").status_code == 200  # it ends, as any session


def test_config_start_and_end_refusals_name_the_field_in_plain_numbers(tmp_path, ronin_model, ipin_walk):
    with client_for(tmp_path, ronin_model) as client:
        for seed in (-1, "-1", 1.5):
            reply = client.post("/sessions", json={"config": {"seed": seed}})
            assert reply.status_code == 422, reply.text
            assert reply.json()["detail"].startswith("config.seed: must be a non-negative integer")
        for key, words in [
            ("filter.nope", "config.filter.nope: no parameter"),
            ("nope.key", "config.nope.key: no section"),
            ("mode", "config.mode: unknown mode"),
        ]:
            reply = client.post("/sessions", json={"config": {key: "x"}})
            assert reply.status_code == 422 and reply.json()["detail"].startswith(words), reply.text
        reply = client.post("/sessions", json={"start": ipin_walk.meta["start"] | {"heading_deg": 1e308}})
        assert reply.status_code == 422 and reply.json()["detail"].startswith("start.heading_deg: ")
        session_id = client.post("/sessions", json={"start": ipin_walk.meta["start"]}).json()["id"]
        path = f"/sessions/{session_id}/samples"
        reply = client.post(path, json={"imu": [_imu_row(50.0)], "end": True})
        assert reply.status_code == 422
        assert reply.json()["detail"] == (
            "end is for the WebSocket; end an HTTP session with DELETE /sessions/{id}"
        )
        reply = client.post(path, json={"imu": [_imu_row(50.0)], "gnss": [_fix(120.0)]})
        assert reply.status_code == 422
        assert reply.json()["detail"].startswith("gnss[0].t: 120.0 is 70 s ahead of the IMU")


# -- transport --------------------------------------------------------------------------------------------


def test_a_binary_websocket_frame_is_a_message_and_the_connection_stays(tmp_path, ronin_model):
    with client_for(tmp_path, ronin_model) as client:
        session_id = client.post("/sessions", json={}).json()["id"]
        with client.websocket_connect(f"/sessions/{session_id}/stream") as ws:
            ws.send_bytes(json.dumps({"imu": [_imu_row(1.0)]}).encode())
            assert ws.receive_json()["data_until"] == 1.0
            ws.send_bytes(b"\xff\xfe not UTF-8")
            assert ws.receive_json()["status"] == 400
            ws.send_bytes(b'{"end": true}')
            assert ws.receive_json()["reason"] == "ended"


def test_a_chunked_body_over_the_limit_is_a_413(tmp_path, ronin_model):
    row = json.dumps(_imu_row(1.0)).encode()
    body = b'{"imu": [' + b",".join([row] * (MAX_BODY_BYTES // len(row) + 1)) + b"]}"

    def chunks():  # no Content-Length: the limit is found as the body streams in
        for i in range(0, len(body), 65536):
            yield body[i : i + 65536]

    with client_for(tmp_path, ronin_model) as client:
        session_id = client.post("/sessions", json={}).json()["id"]
        headers = {"content-type": "application/json"}
        reply = client.post(f"/sessions/{session_id}/samples", content=chunks(), headers=headers)
        assert reply.status_code == 413 and "send fewer rows" in reply.json()["detail"]
        small = [b'{"imu": [', row, b"]}"]
        reply = client.post(f"/sessions/{session_id}/samples", content=iter(small), headers=headers)
        assert reply.status_code == 200 and reply.json()["data_until"] == 1.0


def test_a_refused_websocket_gets_its_status_and_logs_no_error(tmp_path, ronin_model, caplog):
    """uvicorn's websockets-sansio protocol logs "ASGI callable returned without completing
    handshake." after every denial response unless the service filters it out."""
    # Straight to caplog's handler: an earlier uvicorn in the same process may have configured its
    # loggers not to propagate.
    error_log = logging.getLogger("uvicorn.error")
    error_log.addHandler(caplog.handler)
    try:
        with (live_service(tmp_path, ronin_model, log_level="info") as (url, _),
              caplog.at_level(logging.INFO, logger="uvicorn.error")):
            with pytest.raises(InvalidStatus) as refused:
                connect(f"{url.replace('http', 'ws')}/sessions/nope/stream", open_timeout=10)
            time.sleep(0.5)  # the server logs after the reply
    finally:
        error_log.removeHandler(caplog.handler)
    assert refused.value.response.status_code == 404
    assert json.loads(refused.value.response.body) == {"detail": "no such session"}
    assert not [r.getMessage() for r in caplog.records if r.levelno >= logging.ERROR]


def test_the_denial_filter_drops_only_the_handshake_error_of_a_refused_websocket():
    # Deterministic half of the test above: whether uvicorn's records reach caplog in a long pytest run
    # depends on what configured logging before it.
    handshake = logging.LogRecord("uvicorn.error", logging.ERROR, __file__, 1,
                                  "ASGI callable returned without completing handshake.", None, None)
    other = logging.LogRecord("uvicorn.error", logging.ERROR, __file__, 1, "Exception in ASGI application",
                              None, None)
    log_filter = app_module._DeniedHandshakeFilter()
    assert log_filter.filter(handshake) and log_filter.filter(other)  # not refused by us: kept
    token = app_module._denied.set(True)
    try:
        assert not log_filter.filter(handshake) and log_filter.filter(other)
    finally:
        app_module._denied.reset(token)


# -- what the filter is given ---------------------------------------------------------------------------


def test_fixes_claiming_an_accuracy_of_1e_300_m_do_not_stop_the_session(tmp_path, ronin_model, ipin_walk):
    """Every such fix used to fail the session with "internal error (ZeroDivisionError)"; the filter
    takes an accuracy under its floor as the floor."""
    gnss = ipin_walk.gnss.assign(accuracy_m=1e-300).to_dict("records")
    imu = ipin_walk.imu.to_dict("records")
    with client_for(tmp_path, ronin_model, inference_wait_s=0.0) as client:
        session_id = client.post("/sessions", json={"start": ipin_walk.meta["start"]}).json()["id"]
        for lo in np.arange(50.0, 82.0, 2.0):
            body = {
                "imu": [r for r in imu if lo <= r["t"] < lo + 2.0],
                "gnss": [r for r in gnss if lo <= r["t"] < lo + 2.0],
            }
            reply = client.post(f"/sessions/{session_id}/samples", json=body)
            assert reply.status_code == 200 and reply.json()["status"] != "failed", reply.text
        deadline = time.monotonic() + 60.0
        while (estimate := client.get(f"/sessions/{session_id}/estimate").json())["updates"] < 20:
            assert time.monotonic() < deadline and estimate["status"] != "failed", estimate
            time.sleep(0.1)
        summary = client.delete(f"/sessions/{session_id}").json()
    assert estimate["status"] == "tracking" and not estimate["warnings"], estimate
    assert math.isfinite(estimate["accuracy_m"]) and summary["saved"]


def test_the_displacement_is_the_same_bits_however_the_velocities_are_chunked():
    """``d0 + cumsum(chunk)`` rounded differently from one running sum: the live service's track
    differed from ``localize run``'s in the last printed digit of a few rows."""
    rng = np.random.default_rng(1)
    t = np.cumsum(rng.uniform(0.05, 0.15, 500))
    velocity = rng.normal(size=(500, 2))
    whole = DisplacementIntegrator(1.0)
    whole.push(t, velocity)
    for size in (1, 7, 64):
        chunked = DisplacementIntegrator(1.0)
        for lo in range(0, len(t), size):
            chunked.push(t[lo : lo + size], velocity[lo : lo + size])
        assert np.array_equal(chunked.knots.rows(), whole.knots.rows()), size
