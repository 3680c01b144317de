"""A stream with a gap every few seconds warns of its first gaps and counts the rest in one line."""

from __future__ import annotations

import logging

import pytest
from serve_fixtures import TRIAL

from curbside.errors import CurbsideInputError
from curbside.localize.imu import RepeatedWarning, WorldFrameStream
from curbside.localize.readers import read_any
from curbside.localize.ronin.infer import ronin_velocity


def test_gaps_every_two_seconds_give_three_lines_and_a_count(caplog):
    imu = read_any(TRIAL).imu
    since_s = imu["t"] - imu["t"].iat[0]
    gappy = imu[(since_s % 2.0) < 1.3].reset_index(drop=True)  # a 0.7 s gap every 2 s
    with caplog.at_level(logging.WARNING):
        velocity = ronin_velocity(gappy)
    lines = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    assert len(velocity) > 0
    assert sum("s gap at t=" in line for line in lines) == RepeatedWarning.SHOWN
    assert "imu.csv: 12 more gaps that split the recording (-vv lists each)" in lines
    with caplog.at_level(logging.DEBUG):
        caplog.clear()
        ronin_velocity(gappy)
    assert sum("s gap at t=" in r.getMessage() for r in caplog.records) == 15


def test_short_stretches_are_counted_too(caplog):
    imu = read_any(TRIAL).imu
    since_s = imu["t"] - imu["t"].iat[0]
    gappy = imu[((since_s % 2.0) < 0.8) | (since_s > 20)].reset_index(drop=True)
    with caplog.at_level(logging.WARNING):
        ronin_velocity(gappy)
    lines = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    short = [line for line in lines if "shorter than one window: no velocity there" in line]
    assert len(short) == RepeatedWarning.SHOWN
    assert any(line.endswith("more stretches between gaps shorter than one window (-vv lists each)")
               for line in lines)


def test_a_stream_whose_rows_are_all_gaps_is_judged_on_its_rate_before_its_end():
    """A 1 Hz log never covers the start-up decision's 2 s of gap-free rows: it used to be let through
    (a warning per row at the end, then no velocity); it is judged after ten rows."""
    imu = read_any(TRIAL).imu.iloc[::50].reset_index(drop=True)
    stream = WorldFrameStream(source="imu.csv")
    stream.push(imu.iloc[:5])
    with pytest.raises(CurbsideInputError, match=r"imu.csv: IMU rate 1\.0 Hz is below the 20 Hz minimum"):
        stream.push(imu.iloc[5:12])
