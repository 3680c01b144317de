"""The GNSS-driven heading correction: the path fit, its gates, and a cloud held on good fixes."""

from __future__ import annotations

import math

import numpy as np
import pyproj
import pytest

from curbside.localize.filter import FilterConfig, GnssFix, Tracker
from curbside.localize.filter.correction_config import HeadingCorrectionConfig
from curbside.localize.filter.heading_correction import HeadingCorrection
from curbside.localize.filter.pathfit import fit_similarity
from curbside.projection import LocalFrame

X0, Y0 = 550_000.0, 4_180_000.0


def test_the_path_fit_places_the_walker_where_the_fixes_say():
    rng = np.random.default_rng(0)
    path = np.cumsum(np.exp(1j * rng.normal(0.0, 0.3, 40)) * 1.2)
    z = 1.4 * np.exp(1j * math.radians(50))
    fixes = z * path + (30 - 12j)
    fit = fit_similarity(path, fixes, np.full(len(path), 5.0))
    assert fit.scale == pytest.approx(1.4) and math.degrees(fit.rotation) == pytest.approx(50.0)
    assert fit.rms_m == pytest.approx(0.0, abs=1e-9)
    assert fit.place(path[-1] + 2.0) == pytest.approx(fixes[-1] + 2.0 * z)


def _turned_walk(
    fraction: float, seed: int, turn_deg: float = 60.0, fix_error_m: float = 1.5, accuracy_m: float = 5.0,
    fix_tau_s: float = 0.0, speed_read: float = 0.6,
) -> tuple[np.ndarray, int]:
    """East at 1.3 m/s for 240 s with a fix every second. The velocity reads ``speed_read`` of the
    speed and, after 40 s, its direction turns by ``turn_deg`` (a velocity model that has not seen the
    phone). Fix errors: white, or AR(1) with ``fix_tau_s``. Returns the error at each update after
    60 s (m) and the number of corrections."""
    config = FilterConfig(n_particles=500, heading_correction=HeadingCorrectionConfig(fraction=fraction))
    tracker = Tracker.from_config(None, config, seed=seed)
    tracker.frame = LocalFrame(pyproj.CRS("EPSG:32610"))
    rng = np.random.default_rng(100 + seed)
    tracker.start_at_pose(0.0, X0, Y0, 0.0)
    bias = 0j
    rho = math.exp(-1.0 / fix_tau_s) if fix_tau_s > 0 else 0.0
    errors = []
    for k in range(1, 481):
        t = 0.5 * k
        fix = None
        if k % 2 == 0:
            white = fix_error_m * complex(*rng.standard_normal(2))
            bias = rho * bias + math.sqrt(1 - rho**2) * white if fix_tau_s > 0 else white
            fix = GnssFix(X0 + 1.3 * t + bias.real, Y0 + bias.imag, accuracy_m)
        heading = math.radians(turn_deg) if t > 40 else 0.0
        velocity = 1.3 * speed_read * np.array([math.cos(heading), math.sin(heading)])
        estimate = tracker.step(t, velocity_en=velocity, dt=0.5, gnss_fix=fix)
        if t > 60:
            errors.append(math.hypot(estimate.x - (X0 + 1.3 * t), estimate.y - Y0))
    return np.array(errors), tracker.turn.corrections if tracker.turn is not None else 0


def test_a_velocity_that_turned_does_not_walk_the_cloud_off_good_fixes():
    """The velocity turns by 60 degrees and reads 40 % slow, the fixes err by 1.5 m: without the
    correction the cloud walks off (up to 60 m) until the divergence recovery brings it back; with it
    one re-draw puts it on the fixes for the rest of the walk."""
    on = [_turned_walk(0.1, seed) for seed in range(3)]
    off = [_turned_walk(0.0, seed) for seed in range(3)]
    assert all(corrections > 0 for _, corrections in on)
    assert all(np.median(e) > 10.0 for e, _ in off)
    assert all(np.median(e) < 3.0 for e, _ in on)


@pytest.mark.parametrize(
    ("what", "kwargs"),
    [
        ("a velocity that is right", {"turn_deg": 0.0, "speed_read": 1.0}),
        ("fixes reporting 10 m", {"accuracy_m": 10.0, "fix_error_m": 6.0, "fix_tau_s": 30.0}),
        ("fixes that wander with multipath", {"fix_error_m": 8.0, "fix_tau_s": 30.0, "turn_deg": 0.0,
                                              "speed_read": 1.0}),
    ],
)
def test_no_correction_where_the_gates_say_no(what, kwargs):
    for seed in range(2):
        _, corrections = _turned_walk(0.1, seed, **kwargs)
        assert corrections == 0, what


def test_built_with_gnss_unless_off():
    assert isinstance(Tracker.from_config(None, FilterConfig(), seed=0).turn, HeadingCorrection)
    assert Tracker.from_config(None, FilterConfig.preset("paper"), seed=0).turn is None
    assert Tracker.from_config(None, FilterConfig(), seed=0, use_gnss=False).turn is None
    with pytest.raises(ValueError, match="min_scale"):
        HeadingCorrectionConfig(min_scale=2.0, max_scale=1.0)
