"""The inertial-error measurement behind the phone profile, on synthetic walks with known errors."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pyproj
import pytest

from curbside.evaluate import inertial_errors as ie


def _walk(heading_err_deg: float, scale: float, drift_deg_per_min: float = 0.0):
    """A square walk of 40 m legs at 1.25 m/s (true north frame) and its velocity with known errors."""
    corners = np.array([[0, 0], [40, 0], [40, 40], [0, 40], [0, 0], [40, 0]], float)
    t_wp = np.arange(len(corners)) * 32.0
    proj = pyproj.Proj(proj="aeqd", lon_0=11.0, lat_0=49.4, ellps="WGS84")
    lon, lat = proj(corners[:, 0], corners[:, 1], inverse=True)
    waypoints = pd.DataFrame({"t": t_wp, "lat": lat, "lon": lon})
    t = np.arange(0.0, t_wp[-1] + 0.01, 0.05)
    leg = np.minimum((t // 32).astype(int), len(corners) - 2)
    v = (corners[leg + 1] - corners[leg]) / 32.0
    err = np.radians(heading_err_deg + drift_deg_per_min * t / 60.0)
    c, s = np.cos(err), np.sin(err)  # clockwise-positive heading error
    ve = scale * (c * v[:, 0] + s * v[:, 1])
    vn = scale * (-s * v[:, 0] + c * v[:, 1])
    return pd.DataFrame({"t": t, "ve": ve, "vn": vn}), waypoints


def test_leg_errors_recover_a_known_heading_error_and_scale():
    velocity, waypoints = _walk(10.0, 1.1)
    legs = ie.leg_errors(velocity, waypoints, ie.MeasureConfig())
    assert len(legs) == 5
    np.testing.assert_allclose(legs["heading_err_deg"], 10.0, atol=0.2)
    np.testing.assert_allclose(legs["speed_ratio"], 1.1, atol=0.01)
    summary = ie.trial_summary(legs)
    assert summary["bias_deg"] == pytest.approx(10.0, abs=0.2)
    assert summary["distance_ratio"] == pytest.approx(1.1, abs=0.01)


def test_window_speed_ratios_read_a_scale_and_the_noise_a_window_adds():
    velocity, waypoints = _walk(5.0, 1.1)
    ratios = ie.window_speed_ratios(velocity, waypoints, window_s=5.0)
    assert len(ratios) == 5 * 6  # five legs of 32 s, six whole 5 s windows each
    np.testing.assert_allclose(ratios, 1.1, atol=0.01)  # a heading error changes no path length
    # Speed noise of 20 % correlated over 1 s (an AR(1) at 20 Hz): over 5 s windows its spread shrinks
    # to about 0.2 * sqrt(2 * 1 / 5) = 0.13, and over 10 s windows to about 0.09.
    rng = np.random.default_rng(1)
    noisy = []
    for _ in range(40):
        phi, n = np.exp(-0.05), np.zeros(len(velocity))
        for i in range(1, len(n)):
            n[i] = phi * n[i - 1] + np.sqrt(1 - phi**2) * 0.2 * rng.standard_normal()
        noisy.append(velocity.assign(ve=velocity["ve"] * (1 + n), vn=velocity["vn"] * (1 + n)))
    sd5 = np.std(np.concatenate([ie.window_speed_ratios(v, waypoints, 5.0) for v in noisy]))
    sd10 = np.std(np.concatenate([ie.window_speed_ratios(v, waypoints, 10.0) for v in noisy]))
    assert 0.10 < sd5 < 0.16 and 0.065 < sd10 < 0.115 and sd10 < sd5
    standing = waypoints.assign(t=waypoints["t"] * 10)  # the same legs walked at 0.125 m/s
    assert len(ie.window_speed_ratios(velocity, standing, 5.0)) == 0


def test_trial_summary_finds_a_linear_drift():
    velocity, waypoints = _walk(0.0, 1.0, drift_deg_per_min=6.0)
    summary = ie.trial_summary(ie.leg_errors(velocity, waypoints, ie.MeasureConfig()))
    assert summary["drift_deg_per_min"] == pytest.approx(6.0, abs=0.3)


def test_random_walk_fit_on_a_simulated_walk():
    rng = np.random.default_rng(0)
    trials = []
    for _ in range(60):
        t = np.arange(0.0, 180.0, 12.0)  # a leg every 12 s for 3 minutes
        h = np.cumsum(rng.standard_normal(len(t))) * 5.0 * np.sqrt(12.0 / 60.0)  # 5 deg/sqrt(min)
        noise = 2.0 * rng.standard_normal(len(t))
        trials.append(pd.DataFrame({"t_mid_s": t, "heading_err_deg": h + noise, "length_m": 10.0}))
    walk, leg_noise = ie.random_walk_fit(trials, max_lag_min=2.0)
    assert walk == pytest.approx(5.0, rel=0.15)
    assert leg_noise == pytest.approx(2.0, rel=0.35)


def test_standing_spans_and_phantom_motion():
    rate = 50.0
    t = np.arange(0.0, 60.0, 1 / rate)
    rng = np.random.default_rng(1)
    handling = t < 25.0
    acc = np.tile([0.0, 0.0, 9.81], (len(t), 1)) + 0.02 * rng.standard_normal((len(t), 3))
    acc[handling] += 3.0 * rng.standard_normal((handling.sum(), 3))
    imu = pd.DataFrame({"t": t, "ax": acc[:, 0], "ay": acc[:, 1], "az": acc[:, 2]})
    spans = ie.standing_spans(imu, 58.0, ie.MeasureConfig())
    assert spans["handling"][1] == pytest.approx(23.0, abs=0.6)
    assert spans["still"] == pytest.approx((27.0, 56.0), abs=0.6)
    velocity = pd.DataFrame({"t": t, "ve": np.where(handling, 0.3, 0.0), "vn": 0.0})
    moving = ie.phantom_motion(velocity, spans["handling"])
    still = ie.phantom_motion(velocity, spans["still"])
    assert moving["mean_speed_mps"] == pytest.approx(0.3) and moving["net_speed_mps"] == pytest.approx(
        0.3, rel=0.01
    )
    assert still["mean_speed_mps"] == 0.0
