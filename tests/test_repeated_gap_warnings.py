"""A stream with a gap every few seconds warns of its first gaps and counts the rest in one line."""

from __future__ import annotations

import logging

from serve_fixtures import TRIAL

from curbside.localize.imu import RepeatedWarning
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
