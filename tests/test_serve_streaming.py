"""What an audit of the live service as a navigation app would use it found, each fixed and kept fixed.

Small batches of real walking are not refused for their units; fixes that go on while the IMU stops
(a phone app in the background) are taken as ``localize run`` takes them; an estimate says why it is
not coming (no IMU, no usable fix) or why it names no sidewalk (off the map); wrong JSON types and
non-finite configuration values are refused; ``POST /sessions`` needs no body; a configuration no
session may have stops the service at start; a track being written holds no other request up; the
listing of tracks reads no file. Loopback only (the FastAPI test client in process).
"""

from __future__ import annotations

import copy
import threading
import time

import numpy as np
import pandas as pd
import pytest
from serve_fixtures import client_for

from curbside.errors import CurbsideInputError
from curbside.localize.engine import StartPose
from curbside.localize.live import IMU_COLUMNS, IMU_QUAT_COLUMNS, LiveLimits, LiveSession, stream_session
from curbside.localize.pipeline import track_session
from curbside.localize.runconfig import RunConfig
from curbside.localize.serve import store as store_module
from curbside.localize.serve.service import ServiceConfig, TrackingService

MAP_OFF_LAT, MAP_OFF_LON = 37.7906, -122.3400  # 5 km east of the crossroads test map, in the bay


pytestmark = pytest.mark.usefixtures("cache_in_tmp")


def _swinging_imu(t0: float, n: int, units: float = 1.0) -> np.ndarray:
    """``n`` 50 Hz rows whose ``|a|`` swings 9.81 +- 6.5 m/s² at 2 Hz (a phone in a swinging hand),
    with troughs at ``t0 + k / 2``; ``units`` scales the accelerations (1 / 9.81: in g)."""
    t = t0 + np.arange(n) / 50.0
    norm = 9.81 - 6.5 * np.cos(2 * np.pi * 2.0 * (t - t0))
    zeros = np.zeros_like(t)
    return np.column_stack([t, zeros, zeros, norm * units, 0.02 + zeros, zeros, 0.01 + zeros])


def test_a_short_batch_of_walking_is_judged_with_the_rows_before_it_not_alone():
    # 0.9 s of swinging rows, then the 5 rows (0.1 s) around a trough: alone, their median |a| is 3.9
    live = LiveSession(RunConfig.for_mode("fused"), start=StartPose(49.46, 11.11, 0.0))
    rows = _swinging_imu(10.0, 100)
    live.push(rows[:48], None, IMU_COLUMNS)
    trough = rows[48:53]
    assert np.median(np.linalg.norm(trough[:, 1:4], axis=1)) < 4.0
    live.push(trough, None, IMU_COLUMNS)  # refused before: "median |a| is 3.87 m/s² ... gravity removed?"
    for k in range(53, 100, 5):
        live.push(rows[k : k + 5], None, IMU_COLUMNS)
    # accelerations in g are still refused, from the first 25 rows of a session
    in_g = LiveSession(RunConfig.for_mode("fused"), start=StartPose(49.46, 11.11, 0.0))
    rows_g = _swinging_imu(10.0, 50, units=1 / 9.81)
    for k in range(0, 20, 5):
        in_g.push(rows_g[k : k + 5], None, IMU_COLUMNS)
    with pytest.raises(CurbsideInputError, match="in g, not m/s²"):
        in_g.push(rows_g[20:25], None, IMU_COLUMNS)


def test_a_whole_real_walk_in_tenth_of_a_second_batches_is_taken(shared_data):
    from curbside.localize.readers import read_any

    walk = read_any(f"{shared_data / 'ipin2023' / 'ipin2023-t3.h5'}::TrainingTrial01_repetition01")
    imu = walk.imu[list(IMU_QUAT_COLUMNS)].to_numpy(float)
    live = LiveSession(RunConfig.for_mode("fused"), start=StartPose(**walk.meta["start"]))
    # 7 of its 2,320 batches of 5 rows were refused (the first at t=24.4 s, median |a| 2.06 m/s²)
    for k in range(0, len(imu), 5):
        live.push(imu[k : k + 5], None, IMU_QUAT_COLUMNS)
    assert live.last_imu_t == imu[-1, 0]


def test_fixes_going_on_while_the_imu_stops_give_the_localize_run_track(ipin_walk, ronin_model):
    # The IMU stops for 12 s (a phone app in the background) while the fixes go on. With a clock-skew
    # limit of 5 s, the stream used to refuse the fixes 5 s past the last IMU row ("ahead of the IMU"),
    # as the service, with its 60 s, refused those of a 75 s gap: every batch from then on.
    walk = copy.copy(ipin_walk)
    walk.imu = ipin_walk.imu[(ipin_walk.imu["t"] < 64.0) | (ipin_walk.imu["t"] > 76.0)].reset_index(drop=True)
    walk.waypoints = None
    config = RunConfig.for_mode("fused", seed=3)
    batch = track_session(walk, None, config=config).track
    limits = LiveLimits(max_clock_skew_s=5.0)
    live = stream_session(walk, None, config, ronin_model, chunk_s=3.0, limits=limits).track
    pd.testing.assert_frame_equal(live, batch)
    # a fix whose own clock jumps far ahead (another clock, a glitch) is still refused
    session = LiveSession(config, start=StartPose(**ipin_walk.meta["start"]), limits=limits)
    imu = ipin_walk.imu[list(IMU_QUAT_COLUMNS)].to_numpy(float)
    session.push(imu[:100], np.array([[50.91, 49.4613, 11.1109, 5.0]]), IMU_QUAT_COLUMNS)
    with pytest.raises(CurbsideInputError, match=r"gnss\[0\]\.t: .* ahead of the IMU"):
        session.push(None, np.array([[70.0, 49.4613, 11.1109, 5.0]]), IMU_QUAT_COLUMNS)


def _fixes(t0: float, t1: float, lat: float = 49.4613, lon: float = 11.1109, accuracy_m=5.0) -> list[dict]:
    return [{"t": float(t), "lat": lat, "lon": lon, "accuracy_m": accuracy_m} for t in np.arange(t0, t1)]


def _imu_rows(rows: np.ndarray, columns=IMU_QUAT_COLUMNS) -> list[dict]:
    return [dict(zip(columns, map(float, row), strict=True)) for row in rows]


def test_an_estimate_says_why_it_waits_or_names_no_sidewalk(tmp_path, ronin_model, ipin_walk):
    imu = ipin_walk.imu[list(IMU_QUAT_COLUMNS)].to_numpy(float)
    with client_for(tmp_path, ronin_model) as client:
        no_imu = client.post("/sessions", json={}).json()["id"]
        reply = client.post(f"/sessions/{no_imu}/samples", json={"gnss": _fixes(50.0, 65.0)}).json()
        assert reply["status"] == "starting" and reply["warnings"] == [
            "no IMU rows in 14 s of data: the estimate waits for them (footsteps and velocities come from "
            "the IMU; without one, use mode gnss with engine.step_source cadence)"
        ]
        invalid = client.post("/sessions", json={}).json()["id"]
        body = {"imu": _imu_rows(imu[imu[:, 0] < 65.0]), "gnss": _fixes(50.0, 65.0, accuracy_m=0.0)}
        reply = client.post(f"/sessions/{invalid}/samples", json=body).json()
        assert reply["warnings"] == [
            "no usable fix in 15 s of data (15 without a positive accuracy_m) and no start pose: the filter "
            "starts at the first usable fix"
        ]
        stopped = client.post("/sessions", json={"start": ipin_walk.meta["start"]}).json()["id"]
        body = {"imu": _imu_rows(imu[imu[:, 0] < 62.0]), "gnss": _fixes(50.9, 62.0)}
        assert not client.post(f"/sessions/{stopped}/samples", json=body).json()["warnings"]
        reply = client.post(f"/sessions/{stopped}/samples", json={"gnss": _fixes(62.9, 75.0)}).json()
        assert reply["warnings"] == ["no IMU rows for the last 13 s of data: the estimate waits for them"]
    with client_for(tmp_path / "m", ronin_model, map_path="tests/data/maps/crossroads.geojson") as client:
        config = {"mode": "gnss", "engine.step_source": "cadence"}  # a phone without an IMU
        off = client.post("/sessions", json={"config": config}).json()["id"]
        client.post(f"/sessions/{off}/samples", json={"gnss": _fixes(0.0, 10.0, MAP_OFF_LAT, MAP_OFF_LON)})
        reply = client.get(f"/sessions/{off}/estimate").json()
        assert reply["status"] == "tracking" and reply["segment_id"] is None
        assert reply["warnings"] == ["the estimate lies 5003 m outside the map's extent: no sidewalk there"]


BAD_TYPES = {
    "a time as a string": {"imu": [{"t": "1.0", "ax": 0, "ay": 0, "az": 9.8, "gx": 0, "gy": 0, "gz": 0}]},
    "a boolean for a number": {"gnss": [{"t": True, "lat": 49.46, "lon": 11.11, "accuracy_m": 5}]},
    "end as a string": {"end": "yes"},
}


def test_wrong_json_types_are_refused_not_read_as_numbers(tmp_path, ronin_model):
    with client_for(tmp_path, ronin_model) as client:
        session_id = client.post("/sessions").json()["id"]  # no body: every field is optional
        for name, body in BAD_TYPES.items():
            reply = client.post(f"/sessions/{session_id}/samples", json=body)
            assert reply.status_code == 422, (name, reply.text)
            assert "Input should be a valid" in reply.json()["detail"], name
        with client.websocket_connect(f"/sessions/{session_id}/stream") as ws:
            ws.send_json({"end": 1})
            assert ws.receive_json() == {"detail": "end: Input should be a valid boolean", "status": 422}
        assert client.get(f"/sessions/{session_id}/estimate").json()["data_until"] is None


@pytest.mark.parametrize(
    "body",
    [
        b'{"config": {"filter.gnss.sigma_factor": Infinity}}',
        b'{"config": {"filter": {"motion": {"heading_noise_deg": NaN}}}}',
        b'{"config": {"filter.motion.heading_noise_deg": "Infinity"}}',
    ],
)
def test_a_session_config_of_infinity_or_nan_is_refused(tmp_path, ronin_model, body):
    with client_for(tmp_path, ronin_model) as client:
        reply = client.post("/sessions", content=body, headers={"content-type": "application/json"})
    assert reply.status_code == 422
    assert reply.json()["detail"].endswith("must be a finite number")
    assert reply.json()["detail"].startswith(("config.filter.gnss.sigma_factor", "config.filter.motion."))


def test_a_service_configuration_no_session_may_have_stops_it_at_start(tmp_path, ronin_model):
    config = ServiceConfig(data_dir=tmp_path, overrides={"filter.n_particles": "100000"})
    with pytest.raises(CurbsideInputError) as refused:
        TrackingService(config, ronin_model)
    assert str(refused.value) == (
        "--set filter.n_particles: 100000 exceeds the service's maximum of 5000 (every session would be "
        "refused)"
    )


def test_a_track_being_written_holds_no_other_request_up(tmp_path, ronin_model, ipin_walk, monkeypatch):
    save = store_module.TrackStore.save

    def slow_save(self, *args, **kwargs):
        time.sleep(1.5)  # an all-day walk's track
        return save(self, *args, **kwargs)

    monkeypatch.setattr(store_module.TrackStore, "save", slow_save)
    imu = ipin_walk.imu[list(IMU_QUAT_COLUMNS)].to_numpy(float)
    with client_for(tmp_path, ronin_model, inference_wait_s=0.0) as client:
        ending = client.post("/sessions", json={"start": ipin_walk.meta["start"]}).json()["id"]
        body = {"imu": _imu_rows(imu), "gnss": ipin_walk.gnss.to_dict("records")}
        assert client.post(f"/sessions/{ending}/samples", json=body).status_code == 200
        other = client.post("/sessions", json={}).json()["id"]
        summary = {}

        def delete() -> None:
            summary.update(client.delete(f"/sessions/{ending}").json())

        deleting = threading.Thread(target=delete)
        deleting.start()
        time.sleep(0.5)  # the track is being written
        t0 = time.perf_counter()
        reply = client.post(f"/sessions/{other}/samples", json={"gnss": _fixes(50.0, 52.0)})
        answered_s = time.perf_counter() - t0
        during = client.post(f"/sessions/{ending}/samples", json={"gnss": _fixes(90.0, 91.0)})
        deleting.join()
        assert reply.status_code == 200 and answered_s < 0.5  # 1.0 s before: the write held the loop
        assert during.status_code == 409  # the session is ending until its track is written
        assert summary["saved"] and client.get(f"/tracks/{ending}/track.csv").status_code == 200


def test_the_listing_of_tracks_reads_no_file(tmp_path, ronin_model, ipin_walk, monkeypatch):
    imu = ipin_walk.imu[list(IMU_QUAT_COLUMNS)].to_numpy(float)
    with client_for(tmp_path, ronin_model) as client:
        session_id = client.post("/sessions", json={"start": ipin_walk.meta["start"]}).json()["id"]
        client.post(f"/sessions/{session_id}/samples", json={"imu": _imu_rows(imu[:600])})
        assert client.delete(f"/sessions/{session_id}").json()["saved"]

        def no_reading(path):
            raise AssertionError(f"read {path}")

        monkeypatch.setattr(store_module, "_read_json", no_reading)  # 0.6 s with 5,000 tracks
        listed = client.get("/tracks").json()
        assert [t["reason"] for t in listed] == ["deleted"] and listed[0]["updates"] > 0
        track = client.get(f"/tracks/{session_id}").json()
    assert track["run"]["rows"] == listed[0]["updates"] == len(track["track"]["features"])
