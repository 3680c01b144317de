"""The GNSS-driven speed-scale correction: the fit, its gates, and a lagging cloud caught up."""

from __future__ import annotations

import math

import numpy as np
import pyproj
import pytest

from curbside.localize.filter import FilterConfig, GnssFix, Tracker
from curbside.localize.filter.correction_config import ScaleCorrectionConfig
from curbside.localize.filter.scale import ScaleCorrection, fit_scale, robust_fit
from curbside.projection import LocalFrame

X0, Y0 = 550_000.0, 4_180_000.0


def _walk_and_fixes(rng, scale=1.3, rotation=0.1, n=60, noise_m=3.0):
    steps = np.exp(1j * rng.normal(0.0, 0.3, n)) * 1.2  # a wavy walk, 1.2 m per second
    path = np.cumsum(steps)
    fixes = (
        scale * np.exp(1j * rotation) * path
        + (40 - 25j)
        + noise_m * (rng.normal(size=n) + 1j * rng.normal(size=n))
    )
    return path, fixes


def test_the_similarity_fit_recovers_scale_and_rotation_whatever_the_offset():
    path, fixes = _walk_and_fixes(np.random.default_rng(0))
    scale, rotation, se = fit_scale(path, fixes, np.full(len(path), 5.0), correlation_s=1.0)
    assert scale == pytest.approx(1.3, abs=0.05) and rotation == pytest.approx(0.1, abs=0.05)
    assert 0 < se < 0.05
    _, _, se_correlated = fit_scale(path, fixes, np.full(len(path), 5.0), correlation_s=30.0)
    assert se_correlated == pytest.approx(se * math.sqrt(30.0), rel=1e-9)  # 2 independent fixes, not 60


def test_the_robust_fit_ignores_a_few_fixes_tens_of_metres_off():
    plain_errors, robust_errors = [], []
    for seed in range(5):
        rng = np.random.default_rng(seed)
        path, fixes = _walk_and_fixes(rng)
        bad = rng.choice(len(fixes), size=8, replace=False)
        fixes[bad] += 45.0 * np.exp(1j * rng.uniform(0, 2 * np.pi, len(bad)))
        accuracy = np.full(len(path), 5.0)
        plain_errors.append(abs(fit_scale(path, fixes, accuracy, correlation_s=30.0)[0] - 1.3))
        robust_errors.append(abs(robust_fit(path, fixes, accuracy, ScaleCorrectionConfig())[0] - 1.3))
    assert max(robust_errors) < 0.05
    assert np.mean(robust_errors) < 0.3 * np.mean(plain_errors)


def _straight_walk(
    fraction: float, seed: int, true_speed_mps: float, duration_s: float = 300.0, adopt: bool = False
):
    """East at ``true_speed_mps`` while the inertial velocity says 1 m/s; a 6 m fix every second.
    ``adopt``: start idle and turn the correction on with ``Tracker.adopt_motion`` at the first step."""
    correction = ScaleCorrectionConfig(fraction=fraction, window_s=120.0)
    config = FilterConfig(n_particles=500,  # the N these seeds were drawn for
                          scale_correction=correction if not adopt else ScaleCorrectionConfig(window_s=120.0))
    tracker = Tracker.from_config(None, config, seed=seed)
    if adopt:
        tracker.adopt_motion(config.motion, correction)
    tracker.frame = LocalFrame(pyproj.CRS("EPSG:32610"))
    rng = np.random.default_rng(100 + seed)
    estimate = tracker.start_at_pose(0.0, X0, Y0, 0.0)
    for k in range(1, int(duration_s / 0.5) + 1):
        t = 0.5 * k
        fix = None
        if k % 2 == 0:
            fix = GnssFix(
                X0 + true_speed_mps * t + 4 * rng.standard_normal(), Y0 + 4 * rng.standard_normal(), 6.0
            )
        estimate = tracker.step(t, velocity_en=(1.0, 0.0), dt=0.5, gnss_fix=fix)
    corrections = tracker.scale.corrections if tracker.scale is not None else 0
    return estimate.scale, estimate.x - (X0 + true_speed_mps * duration_s), corrections


def test_a_cloud_lagging_good_fixes_gets_its_speed_scale_back():
    """A walk whose inertial speed reads a third low: the scale prior and its random walk reach ~1.3 and
    the cloud lags good fixes by 10-36 m; the correction re-draws scales around the fitted 1.5."""
    on = [_straight_walk(0.05, seed, 1.5) for seed in range(4)]
    off = [_straight_walk(0.0, seed, 1.5) for seed in range(4)]
    assert sum(c for _, _, c in on) >= 3
    assert sum(abs(s - 1.5) < 0.1 for s, _, _ in on) >= 3
    assert np.median([abs(e) for _, e, _ in on]) < 0.3 * np.median([abs(e) for _, e, _ in off])
    assert sum(c for _, _, c in off) == 0
    adopted = [_straight_walk(0.05, seed, 1.5, adopt=True) for seed in range(4)]
    assert [c for _, _, c in adopted] == [c for _, _, c in on]  # turned on mid-walk, the same part


def test_no_correction_when_the_scale_is_right():
    for seed in range(3):
        _, error_m, corrections = _straight_walk(0.05, seed, 1.0)
        assert corrections == 0 and abs(error_m) < 5.0


def test_idle_by_default_on_when_asked_for_never_without_gnss():
    for config in (FilterConfig(), FilterConfig.preset("paper")):
        idle = Tracker.from_config(None, config, seed=0).scale
        assert idle.config.fraction == 0.0  # built, so adopt_motion can turn it on, but idle
    on = FilterConfig(scale_correction=ScaleCorrectionConfig(fraction=0.05))
    assert isinstance(Tracker.from_config(None, on, seed=0).scale, ScaleCorrection)
    assert Tracker.from_config(None, on, seed=0, use_gnss=False).scale is None
    with pytest.raises(ValueError, match="min_scale"):
        ScaleCorrectionConfig(min_scale=1.5, max_scale=1.2)
