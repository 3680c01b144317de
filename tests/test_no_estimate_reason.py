"""A run that makes no estimate says why: nothing to start from, or a recording too short to start in."""

from __future__ import annotations

import dataclasses

import pytest
from serve_fixtures import TRIAL

from curbside.errors import CurbsideInputError
from curbside.localize.live import stream_session
from curbside.localize.pipeline import track_session
from curbside.localize.readers import read_any
from curbside.localize.runconfig import RunConfig


def _cut(t0_s: float, t1_s: float, accuracy_m: float | None = None):
    """The fixture trial between two times, without its start pose (fixes' accuracy replaced if given)."""
    session = read_any(TRIAL)
    imu = session.imu[(session.imu["t"] >= t0_s) & (session.imu["t"] <= t1_s)].reset_index(drop=True)
    gnss = session.gnss[(session.gnss["t"] >= t0_s) & (session.gnss["t"] <= t1_s)].reset_index(drop=True)
    if accuracy_m is not None:
        gnss = gnss.assign(accuracy_m=accuracy_m)
    meta = {k: v for k, v in session.meta.items() if k != "start"}
    return dataclasses.replace(session, imu=imu, gnss=gnss, meta=meta, waypoints=None)


@pytest.mark.parametrize("track", [track_session, None], ids=["batch", "stream"])
def test_a_two_second_recording_with_good_fixes_is_called_too_short(track):
    session = _cut(50.95, 52.95)
    assert len(session.gnss) == 1 and session.gnss["accuracy_m"].max() < 10
    expected = (r"the recording is too short: its inertial data covers only t = 51\.5-52\.4 s, too little "
                r"to start from the first usable fix \(t = 51\.9 s\) and make an update")
    with pytest.raises(CurbsideInputError, match=expected):
        if track is None:
            stream_session(session, None, RunConfig(mode="fused"))
        else:
            track_session(session, None, "fused")


def test_a_recording_without_a_usable_fix_or_a_start_pose_says_so():
    session = _cut(50.5, 60.0, accuracy_m=500.0)
    with pytest.raises(CurbsideInputError, match="no start pose and no usable GNSS fix to start from"):
        track_session(session, None, "fused")
