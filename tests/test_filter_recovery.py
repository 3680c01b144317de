"""Divergence recovery (Augmented MCL driven by GNSS) in :mod:`curbside.localize.filter`."""

from __future__ import annotations

import logging
import math

import numpy as np
import pytest

from curbside.localize.filter import DivergenceRecovery, FilterConfig, GnssFix, ParticleSet, Tracker

STEP_M = 0.7  # a straight walk east, one footstep every 0.5 s, a fix at every footstep
STEP_S = 0.5
ACCURACY_M = 5.0


def walk(max_fraction: float, kidnap_m: float = 80.0, steps: int = 160, backend: str = "numba",
         seed: int = 3) -> tuple[Tracker, np.ndarray, list[int]]:
    """Walk with fixes at the truth; after 40 steps move the whole cloud ``kidnap_m`` north.

    Returns the tracker, the error (m) of the estimate at each step and the particles injected per step.
    """
    config = FilterConfig(n_particles=300, recovery_max_fraction=max_fraction, backend=backend)
    tracker = Tracker(None, config, seed=seed)
    noise = np.random.default_rng(100 + seed).normal(0.0, 0.66 * ACCURACY_M, (steps, 2))
    tracker.start_at_pose(0.0, 0.0, 0.0)
    errors, injected = [], []
    for k in range(1, steps + 1):
        if k == 40:
            tracker.particles.y += kidnap_m
        truth_x = k * STEP_M
        fix = GnssFix(truth_x + noise[k - 1, 0], noise[k - 1, 1], ACCURACY_M)
        est = tracker.step(k * STEP_S, displacement_en=(STEP_M, 0.0), gnss_fix=fix)
        errors.append(math.hypot(est.x - truth_x, est.y))
        injected.append(tracker.last_injected)
    return tracker, np.array(errors), injected


def test_a_diverged_cloud_recovers_with_recovery_and_stays_lost_without():
    _, err_on, injected = walk(max_fraction=0.25)
    _, err_off, injected_off = walk(max_fraction=0.0)
    assert err_on[39] > 60 and err_off[39] > 60  # both diverged by the kidnap
    assert np.all(err_on[100:] < 10)  # back within 60 fixes (30 s)
    assert np.all(err_off[100:] > 60)  # the robust likelihood alone cannot pull it back
    assert sum(injected[39:100]) > 0 and sum(injected_off) == 0


def test_nothing_is_injected_while_the_cloud_agrees_with_gnss():
    tracker, errors, injected = walk(max_fraction=0.25, kidnap_m=0.0, steps=300)
    assert sum(injected) == 0 and tracker.injections == 0
    assert tracker.recovery.w_fast > 0.5 * tracker.recovery.w_slow
    assert np.median(errors) < ACCURACY_M


def test_same_seed_same_track_and_injections():
    a, err_a, inj_a = walk(max_fraction=0.25)
    b, err_b, inj_b = walk(max_fraction=0.25)
    c, err_c, _ = walk(max_fraction=0.25, seed=4)
    np.testing.assert_array_equal(err_a, err_b)
    assert inj_a == inj_b and a.injections == b.injections > 0
    assert not np.array_equal(err_a, err_c)


def test_numba_and_numpy_backends_agree_with_injections():
    fast, err_fast, inj_fast = walk(max_fraction=0.25, backend="numba")
    ref, err_ref, inj_ref = walk(max_fraction=0.25, backend="numpy")
    assert inj_fast == inj_ref and fast.injections > 0
    np.testing.assert_allclose(err_fast, err_ref, atol=1e-6)
    np.testing.assert_allclose(fast.particles.x, ref.particles.x, atol=1e-6)


def test_injected_particles_land_around_the_fix_and_keep_current_drift_angles():
    config = FilterConfig(n_particles=1000, recovery_max_fraction=0.3)
    recovery = DivergenceRecovery(config, sigma_factor=0.66, rng=np.random.default_rng(0))
    p = ParticleSet(1000)
    p.x[:] = 500.0
    p.theta[:] = np.linspace(0.1, 0.2, 1000)
    p.bias_x[:] = 2.0
    fix = GnssFix(10.0, -5.0, 4.0)
    k = recovery.inject(p, fix, 0.3)
    moved = p.x < 400
    assert k == 300 and moved.sum() == 300
    # a fix measures position + bias, so the injected positions are centred on fix - bias
    assert abs(p.x[moved].mean() - 8.0) < 0.5 and abs(p.y[moved].mean() + 5.0) < 0.5
    assert 2.2 < p.x[moved].std() < 3.1  # sigma = 0.66 * 4 m
    assert np.all((p.theta >= 0.1) & (p.theta <= 0.2))


@pytest.mark.parametrize("backend", ["numba", "numpy"])
def test_agreement_is_the_prior_weighted_mean_gaussian_kernel(backend):
    config = FilterConfig(n_particles=4, recovery_kernel_scale=1.0, backend=backend)
    recovery = DivergenceRecovery(config, sigma_factor=1.0, rng=np.random.default_rng(0))
    p = ParticleSet(4)
    p.x[:] = [0.0, 1.0, 2.0, 1000.0]
    recovery.prior_log_weight[:] = np.log([0.1, 0.2, 0.3, 0.4])
    expected = 0.1 + 0.2 * math.exp(-0.5) + 0.3 * math.exp(-2.0)
    assert recovery.log_agreement(p, GnssFix(0.0, 0.0, 1.0)) == pytest.approx(math.log(expected))
    p.x[:] = 1e4  # far from the fix: a very negative log agreement, no underflow to -inf
    assert recovery.log_agreement(p, GnssFix(0.0, 0.0, 1.0)) < -1e6


@pytest.mark.parametrize(
    "bad",
    [{"recovery_max_fraction": 1.5}, {"recovery_alpha_fast": 0.01, "recovery_alpha_slow": 0.1},
     {"recovery_trigger_ratio": 0.0}],
)
def test_invalid_recovery_settings_are_rejected(bad):
    with pytest.raises(ValueError, match="recovery"):
        FilterConfig(**bad)


def test_a_collapse_is_logged_at_debug_not_as_a_warning(caplog):
    caplog.set_level(logging.DEBUG, logger="curbside.localize.filter")
    tracker = Tracker(None, FilterConfig(n_particles=50), seed=0)
    tracker.start_at_pose(0.0, 0.0, 0.0)
    tracker.particles.log_weight[:] = -np.inf  # every weight zero: the next step collapses
    est = tracker.step(0.5, displacement_en=(STEP_M, 0.0))
    assert est.recovered and tracker.recoveries == 1
    collapse = [r for r in caplog.records if "collapsed" in r.getMessage()]
    assert collapse and all(r.levelno == logging.DEBUG for r in collapse)
