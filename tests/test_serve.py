"""The live tracking service: the same track as ``localize run``, bad input, isolation, expiry, restarts.

Loopback only: the FastAPI test client in process, and ``localize serve`` as a subprocess on a free
127.0.0.1 port for the restart and documentation-example tests.
"""

from __future__ import annotations

import copy
import io
import json
import math
import os
import re
import secrets
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import httpx
import numpy as np
import pandas as pd
import pyproj
import pytest
from serve_fixtures import TRIAL, client_for
from starlette.testclient import WebSocketDenialResponse

from curbside.cli.localize import main as localize_main
from curbside.localize.engine import StartPose
from curbside.localize.live import IMU_QUAT_COLUMNS, InferenceQueue, LiveSession, stream_session
from curbside.localize.pipeline import track_session
from curbside.localize.runconfig import RunConfig
from curbside.localize.session import write_session
from curbside.osmseg.mapio import read_map
from curbside.osmseg.places import sidewalk_places
from curbside.projection import LocalFrame

DATA = Path(__file__).parent / "data"
CROSSROADS = DATA / "maps" / "crossroads.geojson"
REPO = Path(__file__).parent.parent


pytestmark = pytest.mark.usefixtures("cache_in_tmp")


@pytest.fixture(scope="module")
def walk_on_map(ipin_walk):
    """The same walk moved onto the crossroads map, heading east along Market Street's north sidewalk."""
    start = ipin_walk.meta["start"]
    here = LocalFrame.around(start["lon"], start["lat"])
    x0, y0 = here.to_xy(start["lon"], start["lat"])
    x, y = here.to_xy(ipin_walk.gnss["lon"].to_numpy(), ipin_walk.gnss["lat"].to_numpy())
    turn = math.radians(start["heading_deg"] - 90.0)
    c, s = math.cos(turn), math.sin(turn)
    there = LocalFrame(pyproj.CRS("EPSG:32610"))
    nx, ny = 553062.0, 4182750.0
    lon, lat = there.to_lonlat(nx + c * (x - x0) - s * (y - y0), ny + s * (x - x0) + c * (y - y0))
    moved = copy.copy(ipin_walk)
    moved.gnss = ipin_walk.gnss.assign(lat=lat, lon=lon)
    moved.waypoints = None
    slon, slat = there.to_lonlat(nx, ny)
    moved.meta = {"start": {"lat": float(slat), "lon": float(slon), "heading_deg": 90.0, "t": start["t"]}}
    return moved


def batches(session, batch_s: float):
    """``{"imu": [...], "gnss": [...]}`` bodies of ``batch_s`` seconds, in time order."""
    imu = session.imu.to_dict("records")
    gnss = session.gnss.to_dict("records")
    t0, t1 = session.time_span()
    for lo in np.arange(t0, t1 + batch_s, batch_s):
        yield {
            "imu": [r for r in imu if lo <= r["t"] < lo + batch_s],
            "gnss": [r for r in gnss if lo <= r["t"] < lo + batch_s],
        }


def new_session(client, session, **config) -> str:
    reply = client.post("/sessions", json={"start": session.meta.get("start"), "config": config})
    assert reply.status_code == 201, reply.text
    return reply.json()["id"]


def replay(client, session_id: str, session, batch_s: float, settle_every_s: float = 0.0) -> list[dict]:
    """POST the session in ``batch_s`` batches as fast as the client goes; the replies.

    With ``settle_every_s``, wait after every that many seconds of data past the start pose until the
    filter has caught up with it (:func:`caught_up_estimate`), so that the replies after it carry
    estimates however slowly the inference thread runs on this machine.
    """
    estimates = []
    t0 = session.time_span()[0]
    settled_until = session.meta.get("start", {}).get("t", t0)
    for k, body in enumerate(batches(session, batch_s)):
        reply = client.post(f"/sessions/{session_id}/samples", json=body)
        assert reply.status_code == 200, reply.text
        estimates.append(reply.json())
        sent_until = t0 + (k + 1) * batch_s
        if settle_every_s and sent_until - settled_until >= settle_every_s:
            caught_up_estimate(client, session_id, sent_until)
            settled_until = sent_until
    return estimates


def caught_up_estimate(client, session_id: str, data_end_t: float, timeout_s: float = 30.0) -> dict:
    """The session's estimate once the filter has reached the last few seconds of the data sent.

    A replay posts faster than real time, so its replies can all come before the first velocities are
    back from the inference thread; poll instead of reading the last reply.
    """
    deadline = time.monotonic() + timeout_s
    while True:
        estimate = client.get(f"/sessions/{session_id}/estimate").json()
        if estimate["t"] is not None and estimate["t"] >= data_end_t - 4.0:
            return estimate
        assert time.monotonic() < deadline, f"the filter did not catch up with the data: {estimate}"
        time.sleep(0.05)


def saved_track(client, session_id: str) -> pd.DataFrame:
    reply = client.get(f"/tracks/{session_id}/track.csv")
    assert reply.status_code == 200, reply.text
    return pd.read_csv(io.StringIO(reply.text))


# -- the same track as localize run --------------------------------------------------------------------


@pytest.fixture(scope="module")
def batch_run(tmp_path_factory):
    """``localize run`` on the walk, seed 3: its track.csv and run.json."""
    out = tmp_path_factory.mktemp("run") / "out"
    assert localize_main(["run", TRIAL, "--seed", "3", "-o", str(out)]) == 0
    return pd.read_csv(out / "track.csv"), json.loads((out / "run.json").read_text())


def test_streamed_in_small_batches_the_service_gives_the_localize_run_track(
    tmp_path, ronin_model, ipin_walk, batch_run
):
    batch_track, batch_info = batch_run
    with client_for(tmp_path, ronin_model, inference_wait_s=0.0) as client:  # replies faster than real time
        session_id = new_session(client, ipin_walk, seed=3)
        estimates = replay(client, session_id, ipin_walk, 0.2, settle_every_s=10.0)
        summary = client.delete(f"/sessions/{session_id}").json()
        live_track = saved_track(client, session_id)
        info = client.get(f"/tracks/{session_id}").json()["run"]
    pd.testing.assert_frame_equal(live_track, batch_track)
    assert info["config"] == batch_info["config"]
    assert (info["velocity_source"], info["step_source"]) == ("ronin", "detected")
    assert live_unseen(estimates) == info["unseen_velocity_from_s"] == batch_info["unseen_velocity_from_s"]
    assert summary["saved"] and summary["updates"] == len(batch_track) > 20
    # every estimate sent while streaming is the track's row at its time, before the walk ended
    live = [e for e in estimates if e["t"] is not None]
    assert len(live) > 20  # estimates come while the walk goes on
    rows = batch_track.set_index("t")
    for e in live:
        as_written = [float(f"{e[k]:.10g}") for k in ("t", "lat", "lon", "n_eff")]  # track.csv's format
        assert as_written[1:] == rows.loc[as_written[0], ["lat", "lon", "n_eff"]].tolist()


def live_unseen(estimates: list[dict]) -> float | None:
    """The last estimate's ``unseen_velocity_from_s``."""
    return estimates[-1]["unseen_velocity_from_s"]


def test_estimates_say_since_when_the_unseen_velocity_motion_model_applies(tmp_path, ronin_model, ipin_walk):
    with client_for(tmp_path, ronin_model, inference_wait_s=0.0) as client:
        session_id = new_session(client, ipin_walk, seed=3, unseen_velocity={"mode": "on"})
        estimates = replay(client, session_id, ipin_walk, 0.5)
        for _ in range(100):  # the velocity model may still be catching up with the data
            latest = client.get(f"/sessions/{session_id}/estimate").json()
            if latest["t"] is not None:
                break
            time.sleep(0.1)
        client.delete(f"/sessions/{session_id}")
        info = client.get(f"/tracks/{session_id}").json()["run"]
        start_t = saved_track(client, session_id)["t"].iat[0]
    assert all(e["unseen_velocity_from_s"] is None for e in estimates if e["t"] is None)
    assert {e["unseen_velocity_from_s"] for e in estimates if e["t"] is not None} <= {start_t}
    assert latest["unseen_velocity_from_s"] == info["unseen_velocity_from_s"] == start_t


def test_live_estimates_trail_the_data_by_the_fix_look_ahead_and_delay(ipin_walk, ronin_model):
    live = LiveSession(RunConfig.for_mode("fused"), start=StartPose(**ipin_walk.meta["start"]))
    queue = InferenceQueue(ronin_model)
    imu, gnss = ipin_walk.imu[list(IMU_QUAT_COLUMNS)].to_numpy(), ipin_walk.gnss.to_numpy()
    lags = []
    for lo in np.arange(50.0, 82.0, 0.2):
        live.push(
            imu[(imu[:, 0] >= lo) & (imu[:, 0] < lo + 0.2)],
            gnss[(gnss[:, 0] >= lo) & (gnss[:, 0] < lo + 0.2)],
            IMU_QUAT_COLUMNS,
        )
        queue.collect(live)
        queue.run()
        if live.advance() or live.rows:
            lags.append(live.received_until - live.rows[-1].t)
    assert len(lags) > 50
    assert max(lags) < 4.0  # the 2 s fix look-ahead, the 1 s fix delay, a footstep interval


def test_a_live_session_on_a_map_equals_localize_run_and_names_the_sidewalk(
    tmp_path, ronin_model, walk_on_map
):
    layers = read_map(CROSSROADS)
    config = RunConfig.for_mode("fused", seed=1)
    batch = track_session(walk_on_map, layers, config=config).track
    pd.testing.assert_frame_equal(
        stream_session(walk_on_map, layers, config, ronin_model, chunk_s=1.3).track, batch
    )
    with client_for(tmp_path, ronin_model, map_path=str(CROSSROADS)) as client:
        session_id = new_session(client, walk_on_map, seed=1)
        replay(client, session_id, walk_on_map, 0.5)
        last = caught_up_estimate(client, session_id, walk_on_map.time_span()[1])
        client.delete(f"/sessions/{session_id}")
        live = saved_track(client, session_id)
    pd.testing.assert_frame_equal(
        live, pd.read_csv(io.StringIO(batch.to_csv(index=False, float_format="%.10g")))
    )
    assert last["segment_id"] == "s0" and last["segment_prob"] > 0.9
    row = batch.iloc[(batch["t"] - last["t"]).abs().argmin()]  # the service says what track.csv says
    assert last["accuracy_m"] == pytest.approx(row["accuracy_m"]) and 0 < last["accuracy_m"] < 20
    assert (last["street"], last["side"], last["place"]) == (
        "Market Street",
        "north",
        "Market Street, north side",
    )


def test_ending_before_the_last_velocities_are_back_still_gives_the_batch_track(
    ipin_walk, ronin_model, batch_run
):
    live = LiveSession(RunConfig.for_mode("fused", seed=3), start=StartPose(**ipin_walk.meta["start"]))
    queue = InferenceQueue(ronin_model)
    live.push(ipin_walk.imu[list(IMU_QUAT_COLUMNS)].to_numpy(), ipin_walk.gnss.to_numpy(), IMU_QUAT_COLUMNS)
    queue.collect(live)
    live.finish_streams()
    queue.collect(live)
    late = queue.take()  # still at the inference thread when the session ends
    live.advance()
    assert not live.drained and len(live.rows) == 0  # the start heading waits for the motion to come
    queue.deliver(late, queue.infer(late))
    live.advance()
    assert live.drained
    track = pd.read_csv(io.StringIO(live.result().track.to_csv(index=False, float_format="%.10g")))
    pd.testing.assert_frame_equal(track, batch_run[0])


def test_sidewalk_segments_are_named_by_compass_side():
    places = sidewalk_places(read_map(CROSSROADS))
    # Market Street runs east-west, 2nd Street north-south; s7 has no street name
    assert {k: p.label for k, p in places.items()} == {
        "s0": "Market Street, north side",
        "s2": "Market Street, south side",
        "s4": "Market Street, north side",
        "s6": "Market Street, south side",
        "s1": "2nd Street, east side",
        "s3": "2nd Street, east side",
        "s5": "2nd Street, west side",
        "s7": "unnamed street, west side",
    }


# -- bad input -----------------------------------------------------------------------------------------


def _imu_row(t: float, **change) -> dict:
    row = {"t": t, "ax": 0.1, "ay": 0.2, "az": 9.8, "gx": 0.01, "gy": 0.0, "gz": 0.02, "qx": 0.0, "qy": 0.0}
    return row | {"qz": 0.0, "qw": 1.0} | change


def _imu(t: float, n: int = 5, **change) -> dict:
    return {"imu": [_imu_row(t + i / 50, **change) for i in range(n)]}


def _fix(t: float, lat: float = 49.4613, lon: float = 11.1109) -> dict:
    return {"gnss": [{"t": t, "lat": lat, "lon": lon, "accuracy_m": 5.0}]}


#: name: (status, body for rows due at ``t``, words of the reason)
BAD = {
    "malformed JSON": (400, lambda t: b'{"imu": [', "malformed JSON"),
    "NaN": (422, lambda t: json.dumps(_imu(t, ax=math.nan)).encode(), "imu[0].ax: "),
    "unknown field": (422, lambda t: {"imu": [_imu_row(t, accel_x=1.0)]}, "imu[0].accel_x: Extra inputs"),
    "partial quaternion": (422, lambda t: {"imu": [_imu_row(t, qx=None)]}, "qx, qy, qz, qw"),
    "acceleration in g": (422, lambda t: _imu(t, 50, az=1.0), "in g"),
    "gravity removed": (422, lambda t: _imu(t, 50, az=0.3), "gravity removed"),
    "deg/s": (422, lambda t: _imu(t, gz=90.0), "rad/s"),
    "not a unit quaternion": (422, lambda t: _imu(t, qx=0.0, qy=0.0, qz=0.0, qw=57.0), "unit quaternion"),
    "time backwards in a batch": (422, lambda t: {"imu": [_imu_row(t), _imu_row(t - 1)]}, "must increase"),
    "time backwards across batches": (422, lambda t: _imu(t - 5.0), "not after the previous row"),
    "time jump": (422, lambda t: _imu(t + 1e5), "jumps"),
    "lat out of range": (422, lambda t: _fix(t, lat=123.0), "ranges"),
    "lat/lon in radians": (422, lambda t: _fix(t, 0.8633, 0.1939), "km from"),
    "fix ahead of the IMU": (422, lambda t: _fix(t + 500.0), "ahead of the IMU"),
    "too many rows": (422, lambda t: _imu(t, 12_001), "at most 12000"),
}


def test_every_bad_input_gets_a_4xx_with_one_line_and_the_sessions_go_on(
    tmp_path, ronin_model, ipin_walk, batch_run
):
    walk_batches = list(batches(ipin_walk, 1.0))
    with client_for(tmp_path, ronin_model) as client:
        session_id, other = new_session(client, ipin_walk, seed=3), new_session(client, ipin_walk, seed=3)
        for body in walk_batches[:18]:  # 18 s: the filter runs
            for sid in (session_id, other):
                assert client.post(f"/sessions/{sid}/samples", json=body).status_code == 200
        t_next = walk_batches[18]["imu"][0]["t"]
        for name, (status, make, words) in BAD.items():
            body = make(t_next)
            if isinstance(body, bytes):
                reply = client.post(
                    f"/sessions/{session_id}/samples",
                    content=body,
                    headers={"content-type": "application/json"},
                )
            else:
                reply = client.post(f"/sessions/{session_id}/samples", json=body)
            detail = reply.json()["detail"]
            assert reply.status_code == status, (name, reply.text)
            assert words in detail and "\n" not in detail, (name, detail)
        huge = b'{"imu": [' + b",".join([json.dumps(_imu_row(t_next)).encode()] * 1_000_000) + b"]}"
        reply = client.post(
            f"/sessions/{session_id}/samples", content=huge, headers={"content-type": "application/json"}
        )
        assert reply.status_code == 413 and "send fewer rows" in reply.json()["detail"]
        assert client.post("/sessions/nope/samples", json={}).status_code == 404
        assert client.post("/sessions", json={"config": {"filter.n_particles": 10**7}}).status_code == 422
        assert (
            "no parameter" in client.post("/sessions", json={"config": {"filter.nope": 1}}).json()["detail"]
        )
        for body in walk_batches[18:]:  # both sessions go on with the walk
            for sid in (session_id, other):
                assert client.post(f"/sessions/{sid}/samples", json=body).status_code == 200
        for sid in (session_id, other):  # and the refused batches changed nothing
            client.delete(f"/sessions/{sid}")
            pd.testing.assert_frame_equal(saved_track(client, sid), batch_run[0])
    with client_for(tmp_path / "m", ronin_model, map_path=str(CROSSROADS)) as mapped:
        reply = mapped.post("/sessions", json={"start": {"lat": 37.70, "lon": -122.39, "heading_deg": 0.0}})
        assert reply.status_code == 422 and "outside the map" in reply.json()["detail"]


# -- isolation, token, expiry, WebSocket -------------------------------------------------------------------


def test_ids_are_unguessable_and_a_token_guards_every_route(tmp_path, ronin_model, ipin_walk):
    with client_for(tmp_path, ronin_model, token="s3cret-token-0123456789") as client:
        assert client.post("/sessions", json={}).status_code == 401
        reply = client.post("/sessions", json={}, headers={"Authorization": "Bearer wrong"})
        assert reply.status_code == 401 and reply.headers["www-authenticate"] == "Bearer"
        assert client.get("/health").status_code == 200  # liveness needs no token
        auth = {"Authorization": "Bearer s3cret-token-0123456789"}
        ids = [client.post("/sessions", json={}, headers=auth).json()["id"] for _ in range(3)]
        assert len(set(ids)) == 3 and all(len(i) >= 32 and re.fullmatch(r"[\w-]+", i) for i in ids)
        assert client.get(f"/sessions/{ids[0]}/estimate").status_code == 401
        assert client.get(f"/sessions/{ids[0]}/estimate", headers=auth).status_code == 200
        guess = secrets.token_urlsafe(24)
        assert client.get(f"/sessions/{guess}/estimate", headers=auth).status_code == 404
        # a WebSocket without the token is refused at the handshake
        with (
            pytest.raises(WebSocketDenialResponse) as denied,
            client.websocket_connect(f"/sessions/{ids[0]}/stream"),
        ):
            pass
        assert denied.value.status_code == 401
        with client.websocket_connect(
            f"/sessions/{ids[0]}/stream?access_token=s3cret-token-0123456789"
        ) as ws:
            ws.send_text("{}")
            assert ws.receive_json()["status"] == "starting"


def test_idle_sessions_expire_and_their_tracks_are_kept(tmp_path, ronin_model, ipin_walk):
    with client_for(tmp_path, ronin_model, idle_timeout_s=2.0) as client:
        session_id = new_session(client, ipin_walk)
        replay(client, session_id, ipin_walk, 4.0)
        deadline = time.monotonic() + 20.0
        while client.get("/health").json()["sessions"]:  # (asking for the estimate would keep it alive)
            assert time.monotonic() < deadline
            time.sleep(0.2)
        assert client.get(f"/sessions/{session_id}/estimate").status_code == 410
        listed = client.get("/tracks").json()
        assert [t["reason"] for t in listed] == ["expired"] and listed[0]["updates"] > 20
        assert session_id not in json.dumps(listed)  # the listing shows hashes, never ids


def test_websocket_round_trip_gives_the_same_track(tmp_path, ronin_model, ipin_walk, batch_run):
    with client_for(tmp_path, ronin_model, inference_wait_s=0.0) as client:
        session_id = new_session(client, ipin_walk, seed=3)
        with client.websocket_connect(f"/sessions/{session_id}/stream") as ws:
            ws.send_text("not json")
            assert ws.receive_json()["status"] == 400  # the connection stays open
            answers = []
            for body in batches(ipin_walk, 0.7):
                ws.send_json(body)
                answers.append(ws.receive_json())
            ws.send_json({"imu": [_imu_row(1.0)]})
            assert "time must increase" in ws.receive_json()["detail"]
            ws.send_json({"end": True})
            summary = ws.receive_json()
        assert summary["saved"] and all(a["status"] in ("starting", "tracking") for a in answers)
        pd.testing.assert_frame_equal(saved_track(client, session_id), batch_run[0])


# -- a real server: restarts and the documentation's clients ----------------------------------------------


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class Server:
    """``localize serve`` in a subprocess on a free loopback port."""

    def __init__(self, data_dir: Path, *args: str) -> None:
        self.port = _free_port()
        self.url = f"http://127.0.0.1:{self.port}"
        cmd = [
            sys.executable,
            "-m",
            "curbside.cli.localize",
            "serve",
            "--port",
            str(self.port),
            "--data-dir",
            str(data_dir),
            *args,
        ]
        env = os.environ | {"PYTHONPATH": str(REPO)}
        self.proc = subprocess.Popen(cmd, cwd=REPO, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
        deadline = time.monotonic() + 60.0
        while True:
            try:
                if httpx.get(f"{self.url}/health", timeout=1.0).status_code == 200:
                    return
            except httpx.TransportError:
                pass
            if self.proc.poll() is not None or time.monotonic() > deadline:
                raise RuntimeError(f"server did not start: {self.proc.stdout.read().decode()}")
            time.sleep(0.2)

    def stop(self) -> str:
        self.proc.send_signal(signal.SIGINT)
        out, _ = self.proc.communicate(timeout=60)
        return out.decode()


def test_restart_keeps_every_finished_track(tmp_path, ipin_walk):
    server = Server(tmp_path / "data")
    with httpx.Client(base_url=server.url) as http:
        ids = [http.post("/sessions", json={"start": ipin_walk.meta["start"]}).json()["id"] for _ in range(2)]
        for body in batches(ipin_walk, 2.0):
            for session_id in ids:
                assert http.post(f"/sessions/{session_id}/samples", json=body).status_code == 200
        assert http.delete(f"/sessions/{ids[0]}").json()["saved"]
        before = http.get(f"/tracks/{ids[0]}/track.csv").text
    server.stop()  # ids[1] is still open: the shutdown saves it
    server = Server(tmp_path / "data")
    try:
        with httpx.Client(base_url=server.url) as http:
            assert sorted(t["reason"] for t in http.get("/tracks").json()) == ["deleted", "shutdown"]
            assert http.get(f"/tracks/{ids[0]}/track.csv").text == before
            track = http.get(f"/tracks/{ids[1]}").json()
            assert track["run"]["service"]["reason"] == "shutdown" and len(track["track"]["features"]) > 20
            assert http.get(f"/sessions/{ids[0]}/estimate").status_code == 410
    finally:
        server.stop()


def _doc_example(name: str) -> str:
    text = (REPO / "docs" / "service.md").read_text(encoding="utf-8")
    match = re.search(rf"<!-- example: {re.escape(name)} -->\n```\w+\n(.*?)```", text, re.S)
    assert match, name
    return match.group(1)


@pytest.fixture(scope="module")
def docs_server(tmp_path_factory, walk_on_map):
    folder = tmp_path_factory.mktemp("docs")
    write_session(walk_on_map, folder / "walk")
    server = Server(folder / "data", "--map", str(CROSSROADS))
    yield server, folder
    server.stop()


def test_the_python_client_of_the_docs_runs(docs_server):
    server, folder = docs_server
    (folder / "client.py").write_text(_doc_example("client.py"))
    done = subprocess.run(
        [sys.executable, str(folder / "client.py"), server.url, str(folder / "walk"), "10"],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert done.returncode == 0, done.stderr
    assert "Market Street, north side" in done.stdout and "/track.csv" in done.stdout


@pytest.mark.skipif(shutil.which("node") is None, reason="node is not installed")
def test_the_javascript_client_of_the_docs_runs(docs_server, walk_on_map):
    server, folder = docs_server
    (folder / "client.mjs").write_text(_doc_example("client.mjs"))
    ipin_walk = {
        "start": walk_on_map.meta["start"],
        "imu": walk_on_map.imu.to_dict("records"),
        "gnss": walk_on_map.gnss.to_dict("records"),
    }
    (folder / "walk.json").write_text(json.dumps(ipin_walk))
    done = subprocess.run(
        [
            "node",
            "--experimental-websocket",
            str(folder / "client.mjs"),
            server.url,
            str(folder / "walk.json"),
            "10",
        ],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert done.returncode == 0, done.stderr
    assert "Market Street, north side" in done.stdout and "ended: " in done.stdout


def test_serve_unseen_velocity_flag_reaches_every_session_config(monkeypatch):
    from curbside.cli import localize_serve
    from curbside.cli.common import config_overrides
    from curbside.cli.localize import main
    seen = []
    monkeypatch.setattr(localize_serve, "_serve", lambda args: seen.append(config_overrides(args)) or 0)
    assert main(["serve", "--unseen-velocity", "--set", "filter.n_particles=300"]) == 0
    assert main(["serve"]) == 0
    assert main(["serve", "--unseen-velocity", "auto"]) == 0
    on, auto = {"unseen_velocity.mode": "on"}, {"unseen_velocity.mode": "auto"}
    assert seen == [{**on, "filter.n_particles": "300"}, {}, auto]
