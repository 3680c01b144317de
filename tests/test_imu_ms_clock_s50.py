"""An IMU whose ``t`` counts milliseconds from the app's start: the refusal asks if it is milliseconds."""

from __future__ import annotations

import numpy as np
import pytest

from curbside.errors import CurbsideInputError
from curbside.localize.imu import low_rate_problem
from curbside.localize.live import LiveSession
from curbside.localize.runconfig import RunConfig


def _imu_rows(t: np.ndarray) -> np.ndarray:
    n = len(t)
    return np.column_stack([t, np.zeros(n), np.zeros(n), np.full(n, 9.81), np.zeros((n, 3))])


def test_a_live_session_fed_milliseconds_is_told_so_with_the_rate_it_read():
    live = LiveSession(RunConfig(), None, None, name="phone")
    t_ms = 1000.0 + 20.0 * np.arange(150)  # 50 Hz, t in ms since the app started
    with pytest.raises(CurbsideInputError) as caught:
        for lo in range(0, 150, 25):
            live.push(_imu_rows(t_ms[lo:lo + 25]))
    message = str(caught.value)
    assert "IMU rate 0.05 Hz is below the 20 Hz minimum" in message
    assert "rows 20 s apart: is t in milliseconds? it must be in seconds" in message


@pytest.mark.parametrize(
    ("interval_s", "expected"),
    [(0.02, None), (0.1, "IMU rate 10.0 Hz is below the 20 Hz minimum for RoNIN"),
     (1.0, "IMU rate 1.0 Hz is below the 20 Hz minimum for RoNIN"),
     (2.5, "IMU rate 0.4 Hz is below the 20 Hz minimum for RoNIN (rows 2.5 s apart: is t in milliseconds?"),
     (5000.0, "IMU rate 0.0002 Hz is below the 20 Hz minimum for RoNIN")],
    ids=["50-hz", "10-hz", "1-hz-log", "400-hz-in-ms", "beyond-ms"],
)
def test_the_hint_is_for_intervals_a_millisecond_clock_gives(interval_s, expected):
    problem = low_rate_problem(interval_s, 20.0)
    if expected is None:
        assert problem is None
        return
    assert problem.startswith(expected)
    assert ("milliseconds" in problem) == (2.0 <= interval_s <= 1000.0)
