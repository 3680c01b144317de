"""accuracy_m through a GNSS outage: a floor that grows with the seconds since the last agreeing fix."""

from __future__ import annotations

import math

import numpy as np
import pytest
from filter_maps import QUIET_MOTION, X0, Y0, two_sidewalk_map

from curbside.localize.filter import CalibrationConfig, FilterConfig, GnssFix, MotionConfig, Tracker
from curbside.localize.runconfig import RunConfig

FLOOR_M_PER_S = CalibrationConfig().radius_floor_m_per_s
OUTAGE_S = (20.0, 110.0)

pytestmark = pytest.mark.usefixtures("cache_in_tmp")


def tracker(
    floor_m_per_s: float | None = None, motion: MotionConfig = QUIET_MOTION, seed: int = 0
) -> Tracker:
    calibration = {} if floor_m_per_s is None else {
        "calibration": CalibrationConfig(radius_floor_m_per_s=floor_m_per_s)
    }
    config = FilterConfig(n_particles=300, motion=motion, **calibration)
    return Tracker.from_config(two_sidewalk_map(), config, seed=seed)


def outage_walk(tr: Tracker, scale_error: float = 0.1, dt_s: float = 0.5):
    """Walk east along the north sidewalk at 1 m/s for 130 s, fixes (2 m noise) every update except in
    the 90 s :data:`OUTAGE_S`, through which the inertial speed reads ``scale_error`` too fast.

    Yields ``(estimate, true error in metres, in the outage, seconds since the last agreeing fix before
    the update)`` per update (a fix is judged after the update's estimate)."""
    rng = np.random.default_rng(1)
    x, y = -80.0, 8.0
    tr.start_at_pose(0.0, X0 + x, Y0 + y)
    for k in range(1, int(130 / dt_s)):
        t = k * dt_s
        x += dt_s
        outage = OUTAGE_S[0] < t < OUTAGE_S[1]
        fix = None if outage else GnssFix(X0 + x + rng.normal(0, 2), Y0 + y + rng.normal(0, 2), 4.0)
        moved = dt_s * (1.0 + scale_error if outage else 1.0)
        since_s = tr.seconds_since_fix(t)
        e = tr.step(t, displacement_en=(moved, 0.0), gnss_fix=fix)
        yield e, math.hypot(e.x - X0 - x, e.y - Y0 - y), outage, since_s


def test_through_an_outage_the_radius_grows_with_the_error():
    rows = [(e.accuracy_m, err, since) for e, err, outage, since in outage_walk(tracker()) if outage]
    radius, error, since = np.array(rows).T
    # 68 % promised; the cloud's own radius held the walker 27 % of these updates (3.8 m at the end
    # against an error of 9 m)
    assert np.mean(error <= radius) >= 0.9
    assert radius[-1] >= FLOOR_M_PER_S * since[-1] > error[-1]
    assert np.all(np.diff(radius[since > 30]) > 0)


def test_the_floor_changes_accuracy_m_and_nothing_else():
    walks = [outage_walk(tracker(floor, motion=MotionConfig(), seed=4)) for floor in (0.0, FLOOR_M_PER_S)]
    widened = 0
    for (a, _, _, since_a), (b, _, _, since_b) in zip(*walks, strict=True):
        same = {"accuracy_m": 0.0, "frame": None}
        assert a._replace(**same) == b._replace(**same)  # position, segment, probability...
        assert since_a == since_b  # the agreement test reads the cloud's radius, not the floor
        if b.accuracy_m != a.accuracy_m:
            assert b.accuracy_m == pytest.approx(FLOOR_M_PER_S * since_b) and b.accuracy_m > a.accuracy_m
            widened += 1
    assert widened > 0


def test_the_floor_counts_from_a_pose_start_and_restarts_at_an_agreeing_fix():
    tr = tracker()
    tr.start_at_pose(0.0, X0 - 80.0, Y0 + 8.0)
    for k in range(1, 101):
        e = tr.step(0.5 * k, displacement_en=(0.5, 0.0))
    assert tr.last_fix_t is None and e.accuracy_m == pytest.approx(FLOOR_M_PER_S * 50.0)
    e = tr.step(50.5, displacement_en=(0.5, 0.0), gnss_fix=GnssFix(e.x + 0.5, e.y, 4.0))
    assert tr.last_fix_t == 50.5 and e.accuracy_m == pytest.approx(FLOOR_M_PER_S * 50.5)  # judged after
    e = tr.step(51.0, displacement_en=(0.5, 0.0))
    assert e.accuracy_m < 5.0  # the cloud's own radius again
    tr.start_at_pose(60.0, X0, Y0 + 8.0)  # a restart is a new start, later than the fix at 50.5 s
    for k in range(1, 101):
        e = tr.step(60.0 + k, displacement_en=(0.0, 0.0))
    assert e.accuracy_m == pytest.approx(FLOOR_M_PER_S * 100.0)


def test_a_fix_far_off_does_not_agree_through_the_floor():
    tr = tracker()
    tr.start_at_pose(0.0, X0 - 80.0, Y0 + 8.0)
    for k in range(1, 201):
        e = tr.step(0.5 * k, displacement_en=(0.5, 0.0))
    assert e.accuracy_m == pytest.approx(FLOOR_M_PER_S * 100.0)  # the cloud's radius is about 4 m
    # 20 m off: within 3 x hypot(4, floor) m of the estimate, not within 3 x hypot(4, 4) m
    e = tr.step(100.5, displacement_en=(0.5, 0.0), gnss_fix=GnssFix(e.x + 20.0, e.y, 4.0))
    assert tr.last_fix_t is None and e.accuracy_m == pytest.approx(FLOOR_M_PER_S * 100.5)


def test_no_floor_without_the_calibration_and_at_zero():
    quiet_paper = FilterConfig.preset("paper")
    for tr in (tracker(0.0), Tracker.from_config(two_sidewalk_map(), quiet_paper)):
        rows = [(e.accuracy_m, since) for e, _, outage, since in outage_walk(tr) if outage]
        assert max(r for r, _ in rows) < 10.0 < FLOOR_M_PER_S * rows[-1][1]


@pytest.mark.parametrize("bad", [-0.1, math.inf, math.nan])
def test_a_bad_floor_rate_is_refused(bad):
    with pytest.raises(ValueError, match="radius_floor_m_per_s"):
        CalibrationConfig(radius_floor_m_per_s=bad)


def test_the_floor_rate_is_a_run_parameter():
    config = RunConfig().with_overrides({"filter.calibration.radius_floor_m_per_s": 0.0})
    assert config.to_dict()["filter"]["calibration"]["radius_floor_m_per_s"] == 0.0
    assert RunConfig().to_dict()["filter"]["calibration"]["radius_floor_m_per_s"] == FLOOR_M_PER_S
