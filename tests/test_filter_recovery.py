"""Divergence recovery (Augmented MCL driven by GNSS) and collapse logging."""

from __future__ import annotations

import logging
import math
import types

import numpy as np
import pytest
from filter_maps import X0, Y0, blocked_sidewalk_map

from curbside.localize.filter import (
    DivergenceRecovery,
    Estimate,
    FilterConfig,
    GnssConfig,
    GnssFix,
    GnssLikelihood,
    ParticleSet,
    RecoveryConfig,
    StreetHeadingConfig,
    Tracker,
    Update,
)

STEP_M = 0.7  # a straight walk east, one footstep every 0.5 s, a fix at every footstep
STEP_S = 0.5
ACCURACY_M = 5.0


def walk(
    max_fraction: float = 0.25,
    kidnap_m: float = 80.0,
    steps: int = 160,
    seed: int = 3,
    fix_offset_m: float = 0.0,
    trigger_ratio: float | None = None,
) -> tuple[Tracker, np.ndarray, list[int]]:
    """Walk with fixes at the truth; after 40 steps move the whole cloud ``kidnap_m`` north. From step
    60 to 119 (30 s) the fixes lie ``fix_offset_m`` north of the truth and report the same accuracy: an
    episode of a phone's fixes that are off the same way. ``trigger_ratio``: the recovery's (default:
    :class:`RecoveryConfig`'s).

    Returns the tracker, the error (m) of the estimate at each step and the particles injected per step.
    """
    trigger = {} if trigger_ratio is None else {"trigger_ratio": trigger_ratio}
    config = FilterConfig(n_particles=300, recovery=RecoveryConfig(max_fraction=max_fraction, **trigger))
    tracker = Tracker.from_config(None, config, seed=seed)
    noise = np.random.default_rng(100 + seed).normal(0.0, 0.66 * ACCURACY_M, (steps, 2))
    tracker.start_at_pose(0.0, 0.0, 0.0)
    errors, injected = [], []
    for k in range(1, steps + 1):
        if k == 40:
            tracker.particles.y += kidnap_m
        truth_x = k * STEP_M
        north = fix_offset_m if 60 <= k < 120 else 0.0
        fix = GnssFix(truth_x + noise[k - 1, 0], north + noise[k - 1, 1], ACCURACY_M)
        est = tracker.step(k * STEP_S, displacement_en=(STEP_M, 0.0), gnss_fix=fix)
        errors.append(math.hypot(est.x - truth_x, est.y))
        injected.append(est.injected)
    return tracker, np.array(errors), injected


def test_a_diverged_cloud_recovers_with_recovery_and_stays_lost_without():
    _, err_on, injected = walk(max_fraction=0.25)
    off, err_off, injected_off = walk(max_fraction=0.0)
    assert err_on[39] > 60 and err_off[39] > 60  # both diverged by the kidnap
    assert np.all(err_on[110:] < 10)  # back within 70 fixes (35 s)
    assert np.all(err_off[100:] > 60)  # the robust likelihood alone cannot pull it back
    assert sum(injected[39:120]) > 0 and sum(injected_off) == 0 and off.divergence is None


def test_half_a_minute_of_fixes_off_the_same_way_is_seldom_taken_for_a_divergence():
    # Version 0.1's trigger (0.5) re-draws the cloud around such fixes on every seed, and the estimate
    # is more than 10 m off for a fifth of the walk from then on; today's (0.4) keeps the cloud on most.
    seeds = range(4, 9)
    today = [walk(kidnap_m=0.0, seed=seed, fix_offset_m=40.0)[1:] for seed in seeds]
    version_01 = [walk(kidnap_m=0.0, seed=seed, fix_offset_m=40.0, trigger_ratio=0.5)[1:] for seed in seeds]
    assert all(sum(injected) > 0 for _, injected in version_01)
    assert sum(sum(injected) == 0 for _, injected in today) >= 3
    lost_today = np.mean([(errors[59:] > 10).mean() for errors, _ in today])
    lost_01 = np.mean([(errors[59:] > 10).mean() for errors, _ in version_01])
    assert lost_01 > 0.15 and lost_today < 0.05


def test_nothing_is_injected_while_the_cloud_agrees_with_gnss():
    tracker, errors, injected = walk(max_fraction=0.25, kidnap_m=0.0, steps=300)
    assert sum(injected) == 0 and tracker.divergence.injections == 0
    assert tracker.divergence.w_fast > 0.5 * tracker.divergence.w_slow
    assert np.median(errors) < ACCURACY_M


def test_same_seed_same_track_and_injections():
    a, err_a, inj_a = walk(max_fraction=0.25)
    b, err_b, inj_b = walk(max_fraction=0.25)
    _, err_c, _ = walk(max_fraction=0.25, seed=4)
    np.testing.assert_array_equal(err_a, err_b)
    assert inj_a == inj_b and a.divergence.injections == b.divergence.injections > 0
    assert not np.array_equal(err_a, err_c)


def _recovery(
    n: int, kernel_scale: float = 5.0, sigma_factor: float = 0.66, heading_sigma_deg: float = 0.0
) -> DivergenceRecovery:
    rng = np.random.default_rng(0)
    gnss = GnssLikelihood(GnssConfig(sigma_factor=sigma_factor), n, rng)
    config = RecoveryConfig(
        max_fraction=0.3, kernel_scale=kernel_scale, inject_heading_sigma_deg=heading_sigma_deg
    )
    return DivergenceRecovery(config, gnss, rng)


def test_injected_particles_land_around_the_fix_and_keep_current_heading_offsets():
    recovery = _recovery(1000)
    p = ParticleSet(1000)
    p.x[:] = 500.0
    p.set_heading(np.linspace(0.1, 0.2, 1000))
    p.bias_x[:] = 2.0
    k = recovery.inject(p, GnssFix(10.0, -5.0, 4.0), 0.3)
    moved = p.x < 400
    assert k == 300 and moved.sum() == 300
    # a fix measures position + bias, so the injected positions are centred on fix - bias
    assert abs(p.x[moved].mean() - 8.0) < 0.5 and abs(p.y[moved].mean() + 5.0) < 0.5
    assert 2.2 < p.x[moved].std() < 3.1  # sigma = 0.66 * 4 m
    assert np.all((p.theta >= 0.1) & (p.theta <= 0.2))
    np.testing.assert_allclose(np.cos(p.theta), p.state[3])


def test_injected_heading_offsets_are_jittered_around_current_ones():
    recovery = _recovery(4000, heading_sigma_deg=30.0)
    p = ParticleSet(4000)
    p.x[:] = 500.0
    p.set_heading(np.full(4000, 0.5))
    recovery.inject(p, GnssFix(0.0, 0.0, 4.0), 0.3)
    moved = p.x < 400
    assert np.all(p.theta[~moved] == 0.5)  # particles that stay keep their offsets
    assert abs(np.degrees(p.theta[moved].std()) - 30.0) < 2.0
    assert abs(p.theta[moved].mean() - 0.5) < 0.06  # 4 standard errors
    np.testing.assert_allclose(np.cos(p.theta), p.state[3])
    np.testing.assert_allclose(np.sin(p.theta), p.state[4])


def test_agreement_is_the_prior_weighted_mean_gaussian_kernel():
    recovery = _recovery(4, kernel_scale=1.0, sigma_factor=1.0)
    p = ParticleSet(4)
    p.x[:] = [0.0, 1.0, 2.0, 1000.0]
    p.log_weight[:] = np.log([0.1, 0.2, 0.3, 0.4])
    expected = 0.1 + 0.2 * math.exp(-0.5) + 0.3 * math.exp(-2.0)
    assert recovery.log_agreement(p, GnssFix(0.0, 0.0, 1.0)) == pytest.approx(math.log(expected))
    p.x[:] = 1e4  # far from the fix: a very negative log agreement, no underflow to -inf
    assert recovery.log_agreement(p, GnssFix(0.0, 0.0, 1.0)) < -1e6


@pytest.mark.parametrize(
    "bad", [{"max_fraction": 1.5}, {"alpha_fast": 0.01, "alpha_slow": 0.1}, {"trigger_ratio": 0.0}]
)
def test_invalid_recovery_settings_are_rejected(bad):
    with pytest.raises(ValueError, match="max_fraction|alpha|trigger"):
        RecoveryConfig(**bad)


def test_a_collapse_is_logged_at_debug_not_as_a_warning(caplog):
    caplog.set_level(logging.DEBUG, logger="curbside.localize.filter")
    tracker = Tracker.from_config(None, FilterConfig(n_particles=50), seed=0)
    tracker.start_at_pose(0.0, 0.0, 0.0)
    tracker.particles.log_weight[:] = -np.inf  # every weight zero: the next step collapses
    est = tracker.step(0.5, displacement_en=(STEP_M, 0.0))
    assert est.recovered and tracker.recoveries == 1
    collapse = [r for r in caplog.records if "collapsed" in r.getMessage()]
    assert collapse and all(r.levelno == logging.DEBUG for r in collapse)


def _lost_share_after_a_heading_kidnap(heading_sigma_deg: float, seed: int) -> float:
    """Turn every heading offset by 150 deg and move the cloud 60 m off at step 40 of a walk east with
    good fixes; the share of steps 100-400 whose estimate is more than 10 m off."""
    config = FilterConfig(
        n_particles=300, recovery=RecoveryConfig(inject_heading_sigma_deg=heading_sigma_deg)
    )
    tracker = Tracker.from_config(None, config, seed=seed)
    noise = np.random.default_rng(100 + seed).normal(0.0, 0.66 * ACCURACY_M, (400, 2))
    tracker.start_at_pose(0.0, 0.0, 0.0)
    errors = []
    for k in range(1, 401):
        if k == 40:
            tracker.particles.set_heading(tracker.particles.theta + math.radians(150.0))
            tracker.particles.y += 60.0
        fix = GnssFix(k * STEP_M + noise[k - 1, 0], noise[k - 1, 1], ACCURACY_M)
        est = tracker.step(k * STEP_S, displacement_en=(STEP_M, 0.0), gnss_fix=fix)
        errors.append(math.hypot(est.x - k * STEP_M, est.y))
    return float((np.array(errors[100:]) > 10.0).mean())


def test_jittered_injection_recovers_a_cloud_whose_heading_offset_went_wrong():
    # injected particles that copy the wrong offset run off again; jittered ones find the right one.
    # One kidnap with 300 particles is a coin toss either way, so the claim is about six of them.
    seeds = range(6)
    without = np.mean([_lost_share_after_a_heading_kidnap(0.0, seed) for seed in seeds])
    jittered = np.mean([_lost_share_after_a_heading_kidnap(30.0, seed) for seed in seeds])
    assert without > 0.7
    assert jittered < 0.35


# -- the stall trigger ------------------------------------------------------------------------------


def blocked_walk(stall_ratio: float, seed: int, steps: int = 180) -> tuple[np.ndarray, np.ndarray]:
    """East along a sidewalk whose map has a wall across it at x = 40-44 m (``blocked_sidewalk_map``);
    fixes at the truth (3 m noise, 10 m accuracy). Returns the error and the injections per step.
    The street-heading part is off, so that the stall trigger alone brings the cloud back."""
    config = FilterConfig(n_particles=1000, recovery=RecoveryConfig(stall_ratio=stall_ratio),
                          street_heading=StreetHeadingConfig(strength_per_m=0.0))
    tracker = Tracker.from_config(blocked_sidewalk_map(), config, seed=seed)
    noise = np.random.default_rng(50 + seed).normal(0.0, 3.0, (steps, 2))
    tracker.start_at_pose(0.0, X0, Y0 + 2.0, 0.0)
    errors, injected = [], []
    for k in range(1, steps + 1):
        x = STEP_M * k
        fix = GnssFix(X0 + x + noise[k - 1, 0], Y0 + 2.0 + noise[k - 1, 1], 10.0)
        est = tracker.step(k * STEP_S, displacement_en=(STEP_M, 0.0), gnss_fix=fix)
        errors.append(math.hypot(est.x - X0 - x, est.y - Y0 - 2.0))
        injected.append(est.injected)
    return np.array(errors), np.array(injected)


def test_a_cloud_the_map_holds_still_while_the_phone_walks_on_is_redrawn_around_the_fixes():
    # The walker passes the wall (a footprint the street does not have) at step 57; the cloud stops there.
    on = [blocked_walk(0.2, seed) for seed in range(4)]
    off = [blocked_walk(0.0, seed) for seed in range(4)]
    for errors, injected in on:
        assert not injected[:57].any()  # walking freely is no stall
        assert 57 < np.argmax(injected > 0) <= 57 + 25  # within the 10 s window after the wall
        assert errors[85:130].max() < 8.0
    # without the trigger only the agreement kernel (5 sigma, 33 m) or a collapse brings it back
    assert np.mean([e[85:130].mean() for e, _ in off]) > 3 * np.mean([e[85:130].mean() for e, _ in on])
    assert all(not injected[:120].any() for _, injected in off)


def stall_verdicts(step_east_m, estimate_x, blocked_share: float = 0.5, updates: int = 40) -> list[bool]:
    """``stalled`` at each of ``updates`` updates 0.5 s apart: footstep ``k`` moves ``step_east_m(k)``
    east, the estimate before it stands at ``(estimate_x(k), 5)`` and the map stops ``blocked_share``
    of the particles at every update."""
    walls = types.SimpleNamespace(blocked_share=blocked_share)  # what the test reads of the map
    recovery = DivergenceRecovery(RecoveryConfig(), GnssLikelihood(GnssConfig(), 10, None), None, walls)
    estimate = Estimate(0.0, 5.0, 5.0, 0.0, 1.0, 10.0, False, None, None, 0.0, 5.0, 5.0, 0)
    return [
        recovery.stalled(Update(k * 0.5, 0.5, step_east_m(k), 0.0, None),
                         estimate._replace(t=k * 0.5, x=estimate_x(k)))
        for k in range(1, updates + 1)
    ]


def test_stalled_needs_the_whole_window_a_walking_pace_a_still_estimate_and_walls():
    walking_still = stall_verdicts(lambda k: 0.7, lambda k: 5.0)  # 1.4 m/s, the estimate never moves
    assert not any(walking_still[:18]) and all(walking_still[20:])  # 10 s of history first
    assert not any(stall_verdicts(lambda k: 0.1, lambda k: 5.0))  # 0.2 m/s of phantom motion: standing
    assert not any(stall_verdicts(lambda k: 0.7, lambda k: 0.35 * k))  # moving at half the inertial pace
    # 5 s out and 5 s back: the inertial displacement over 10 s is nil, so turning back is no stall
    assert not any(stall_verdicts(lambda k: 0.7 if k % 20 < 10 else -0.7, lambda k: 5.0))
    # held back with no wall in the way (fixes that lag the walker pull it): no stall
    assert not any(stall_verdicts(lambda k: 0.7, lambda k: 5.0, blocked_share=0.1))
