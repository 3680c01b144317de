"""A cloud far from every good fix is re-drawn around them (``filter.recovery.relocate_*``), and only then.

The reviewer's repro (stop 50): a phone's first fix is its stale last-known place, hundreds of metres or
kilometres off; the tracker starts there and good fixes never brought it back.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from curbside.localize.filter import FilterConfig, GnssFix, RecoveryConfig, Tracker

STEP_S = 0.5
STEP_M = 0.7  # a walk east at 1.4 m/s
ACCURACY_M = 5.0


def _tracker(recovery: RecoveryConfig | None = None, seed: int = 1) -> Tracker:
    config = FilterConfig(n_particles=500)
    if recovery is not None:
        config = dataclasses.replace(config, recovery=recovery)
    return Tracker.from_config(None, config, seed=seed)


def _seconds_back(offset_m: float, bearing_deg: float = 0.0, seed: int = 1, steps: int = 600) -> float | None:
    """Start at a stale fix ``offset_m`` away, then stand at the origin with good 5 m fixes at 1 Hz (the
    repro); seconds until the estimate is within 20 m of the fixes (``None``: not in ``steps`` s)."""
    tracker = _tracker(seed=seed)
    bearing = math.radians(bearing_deg)
    stale = GnssFix(offset_m * math.sin(bearing), offset_m * math.cos(bearing), 8.0)
    tracker.step(0.0, displacement_en=(0.0, 0.0), gnss_fix=stale)
    noise = np.random.default_rng(seed).normal(0.0, 0.66 * ACCURACY_M, (steps, 2))
    for k in range(1, steps + 1):
        est = tracker.step(float(k), displacement_en=(0.0, 0.0), gnss_fix=GnssFix(*noise[k - 1], ACCURACY_M))
        if math.hypot(est.x, est.y) < 20.0:
            return float(k)
    return None


@pytest.mark.parametrize("offset_m", [330.0, 1100.0, 5000.0])
def test_a_start_at_a_stale_fix_far_away_comes_back_to_the_good_fixes(offset_m):
    # Before: the cloud stayed where the stale fix put it for all ten minutes of good fixes (without a
    # map nothing else moves it). Now: 20 s of far fixes, then the whole cloud is re-drawn around them.
    for seed, bearing in ((1, 0.0), (2, 135.0)):
        back = _seconds_back(offset_m, bearing, seed)
        assert back is not None and back <= 25, (offset_m, seed, back)


def _walk(fix_error, recovery: RecoveryConfig | None = None, steps: int = 400, seed: int = 3):
    """A walk east from a known start, a fix at every footstep (0.5 s): ``fix_error(k)`` is footstep
    ``k``'s fix error (east, north) in metres. Returns the tracker and its estimates."""
    tracker = _tracker(recovery, seed)
    tracker.start_at_pose(0.0, 0.0, 0.0)
    noise = np.random.default_rng(100 + seed).normal(0.0, 0.66 * ACCURACY_M, (steps, 2))
    estimates = []
    for k in range(1, steps + 1):
        ex, ey = fix_error(k)
        fix = GnssFix(k * STEP_M + noise[k - 1, 0] + ex, noise[k - 1, 1] + ey, ACCURACY_M)
        estimates.append(tracker.step(k * STEP_S, displacement_en=(STEP_M, 0.0), gnss_fix=fix))
    return tracker, estimates


def _multipath(k: int) -> tuple[float, float]:
    """A minute of fixes 60 m north of the walker, and now and then one 150 m south."""
    if 60 <= k < 180:
        return 0.0, 60.0
    return (0.0, -150.0) if k % 37 == 0 else (0.0, 0.0)


def test_a_minute_of_multipath_fixes_never_relocates_and_changes_nothing():
    tracker, estimates = _walk(_multipath)
    off, estimates_off = _walk(_multipath, RecoveryConfig(relocate_distance_m=0.0))
    assert tracker.divergence.relocations == 0
    assert estimates == estimates_off  # the same track, number for number


def _scattered(k: int) -> tuple[float, float]:
    """From footstep 100 on, fixes 400-600 m off, each in a random direction."""
    if k < 100:
        return 0.0, 0.0
    rng = np.random.default_rng(k)
    angle, distance = rng.uniform(0.0, 2.0 * math.pi), rng.uniform(400.0, 600.0)
    return distance * math.cos(angle), distance * math.sin(angle)


def test_far_fixes_that_disagree_with_each_other_do_not_relocate():
    tracker, _ = _walk(_scattered, steps=300)
    assert tracker.divergence.relocations == 0


def test_a_near_fix_starts_the_count_again():
    # far (400 m north) for 15 s, one good fix, far again for 15 s: never 20 s in a row
    def error(k: int) -> tuple[float, float]:
        return (0.0, 0.0) if k < 20 or k == 50 or k >= 80 else (0.0, 400.0)

    tracker, _ = _walk(error, steps=120)
    assert tracker.divergence.relocations == 0
    longer, estimates = _walk(lambda k: (0.0, 400.0) if k >= 20 else (0.0, 0.0), steps=120)
    assert longer.divergence.relocations >= 1
    assert math.hypot(estimates[-1].x - 120 * STEP_M, estimates[-1].y - 400.0) < 20.0


def test_fixes_reporting_a_poor_accuracy_do_not_count():
    config = RecoveryConfig()
    tracker = _tracker()
    tracker.start_at_pose(0.0, 0.0, 0.0)
    poor = config.relocate_max_accuracy_m + 5.0
    for k in range(1, 121):
        tracker.step(k * STEP_S, displacement_en=(0.0, 0.0), gnss_fix=GnssFix(0.0, 1000.0, poor))
    assert tracker.divergence.relocations == 0


@pytest.mark.parametrize(
    "bad",
    [{"relocate_distance_m": -1.0}, {"relocate_after_s": 0.0}, {"relocate_agreeing_share": 1.5},
     {"relocate_heading_sigma_deg": -5.0}, {"relocate_min_fixes": 0}],
)
def test_invalid_relocation_settings_are_rejected(bad):
    with pytest.raises(ValueError, match="relocate_"):
        RecoveryConfig(**bad)
