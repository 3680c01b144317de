"""segment_prob's calibration: the fixes' persistence read online, the temperature, the tracker's use."""

from __future__ import annotations

import math

import numpy as np
import pytest
from filter_maps import QUIET_MOTION, X0, Y0, two_sidewalk_map
from hypothesis import given, settings
from hypothesis import strategies as st

from curbside import settings as curbside_settings
from curbside.localize.filter import (
    CalibrationConfig,
    FilterConfig,
    GnssFix,
    SegmentCalibration,
    Tracker,
)
from curbside.localize.filter.calibration import TAIL_DOF, accuracy_radius_m, radius_at_share_m

LAG_S = 10.0


@pytest.fixture(autouse=True)
def _cache_in_tmp(tmp_path, monkeypatch):
    monkeypatch.setattr(curbside_settings, "cache_dir", tmp_path / "cache")


def variogram_persistence(t: np.ndarray, e: np.ndarray, tolerance_s: float = 1.0) -> float:
    """The whole walk's persistence, batch: each fix paired with the first fix at most LAG_S older, if
    that one is nearly LAG_S older."""
    first = np.searchsorted(t, t - LAG_S)
    j = np.flatnonzero(
        (first < np.arange(len(t))) & (t - t[np.minimum(first, len(t) - 1)] > LAG_S - tolerance_s)
    )
    i = first[j]
    change = np.mean(np.sum((e[j] - e[i]) ** 2, axis=1))
    return 1.0 - change / (2.0 * np.mean(np.sum(e**2, axis=1)))


def gauss_markov(rho_per_s: float, n: int, seed: int) -> np.ndarray:
    """A 2-D first-order Gauss-Markov error sampled every second (unit stationary variance per axis)."""
    rng = np.random.default_rng(seed)
    e = np.empty((n, 2))
    e[0] = rng.normal(size=2)
    for k in range(1, n):
        e[k] = rho_per_s * e[k - 1] + math.sqrt(1 - rho_per_s**2) * rng.normal(size=2)
    return e


def observed(config: CalibrationConfig, t: np.ndarray, e: np.ndarray) -> SegmentCalibration:
    cal = SegmentCalibration(config, 2000)
    for tk, (x, y) in zip(t, e, strict=True):
        cal.observe(float(tk), float(x), float(y))
    return cal


@settings(max_examples=40, deadline=None)
@given(
    gaps=st.lists(st.floats(0.2, 4.0), min_size=2, max_size=120),
    seed=st.integers(0, 10_000),
)
def test_the_running_persistence_is_the_batch_variogram(gaps, seed):
    t = np.cumsum(gaps)
    e = np.random.default_rng(seed).normal(0, 5, (len(t), 2))
    cal = observed(CalibrationConfig(prior_pairs=0.0), t, e)
    if cal.pairs == 0:
        assert cal.persistence == CalibrationConfig().prior_persistence
    else:
        assert cal.persistence == pytest.approx(variogram_persistence(t, e), abs=1e-9)


@pytest.mark.parametrize("tau_s", [2.0, 10.0, 60.0])
def test_a_gauss_markov_error_reads_its_share_left_after_the_lag(tau_s):
    e = gauss_markov(math.exp(-1.0 / tau_s), 4000, seed=int(tau_s))
    cal = observed(CalibrationConfig(), np.arange(4000.0), e)
    assert cal.persistence == pytest.approx(math.exp(-LAG_S / tau_s), abs=0.08)


def test_the_prior_holds_until_pairs_come_and_then_gives_way():
    config = CalibrationConfig(prior_persistence=0.3, prior_pairs=20.0)
    steady = np.tile([4.0, -3.0], (200, 1))  # an error that never changes: persistence 1
    few = observed(config, np.arange(12.0), steady[:12])
    many = observed(config, np.arange(200.0), steady)
    assert few.pairs == 2 and few.persistence == pytest.approx((2 * 1.0 + 20 * 0.3) / 22)
    assert many.persistence == pytest.approx((190 + 20 * 0.3) / 210)
    assert observed(config, np.array([]), steady[:0]).temperature == pytest.approx(1.5 + 2.0 * 0.3)


def test_lasting_fixes_temper_more_than_white_ones_and_the_order_of_probabilities_is_kept():
    t = np.arange(600.0)
    white = observed(CalibrationConfig(), t, gauss_markov(0.0, 600, 1))
    lasting = observed(CalibrationConfig(), t, gauss_markov(math.exp(-1 / 60), 600, 1))
    assert white.temperature < 1.8 < 3.0 < lasting.temperature
    probs = [0.3, 0.5, 0.7, 0.9, 0.99, 0.999, 1.0]
    for cal in (white, lasting):
        out = [cal.calibrate(p) for p in probs]
        assert out == sorted(out) and out[1] == pytest.approx(0.5)
        assert all(0.5 < q < p for p, q in zip(probs[2:], out[2:], strict=True))  # pulled towards 0.5
        assert out[-1] < 1.0  # half a particle of doubt
        assert cal.calibrate(0.0) == 0.0  # no segment stays no segment
    assert lasting.calibrate(0.99) < white.calibrate(0.99)


@pytest.mark.parametrize(
    "bad",
    [
        {"temperature": 0.0},
        {"temperature_per_persistence": -1.0},
        {"prior_persistence": 1.5},
        {"pair_tolerance_s": 0.0},
        {"pair_tolerance_s": 20.0},
        {"persistence_lag_s": math.inf},
        {"prior_pairs": -1.0},
    ],
)
def test_a_bad_calibration_is_refused(bad):
    with pytest.raises(ValueError):
        CalibrationConfig(**bad)


def test_fused_calibrates_with_fixes_the_paper_and_the_inertial_filter_do_not():
    fused = Tracker.from_config(two_sidewalk_map(), FilterConfig(n_particles=200))
    assert fused.calibration is not None
    assert Tracker.from_config(two_sidewalk_map(), FilterConfig.preset("paper")).calibration is None
    assert (
        Tracker.from_config(two_sidewalk_map(), FilterConfig(n_particles=200), use_gnss=False).calibration
        is None
    )
    assert Tracker.from_config(None, FilterConfig(n_particles=200)).calibration is not None  # the radius


def test_the_tracker_reports_the_tempered_mass_and_reads_the_fixes_innovations():
    quiet = QUIET_MOTION
    raw = Tracker.from_config(
        two_sidewalk_map(),
        FilterConfig(
            n_particles=300,
            motion=quiet,
            calibration=CalibrationConfig(temperature=1.0, temperature_per_persistence=0.0),
        ),
        seed=3,
    )
    # without the outage floor (tests/test_outage_radius_s51.py): these fixes run ahead of the walker
    no_floor = CalibrationConfig(radius_floor_m_per_s=0.0)
    tempered = Tracker.from_config(
        two_sidewalk_map(), FilterConfig(n_particles=300, motion=quiet, calibration=no_floor), seed=3
    )
    for tracker in (raw, tempered):
        tracker.start_at_pose(0.0, X0, Y0 + 8.0)
    for k in range(1, 200):
        fix = GnssFix(X0 + 1.4 * k, Y0 + 8.0 + 4.0, 6.0)  # 4 m north of the walker, every fix
        a = raw.step(0.5 * k, displacement_en=(0.7, 0.0), gnss_fix=fix)
        b = tempered.step(0.5 * k, displacement_en=(0.7, 0.0), gnss_fix=fix)
        assert (a.x, a.y, a.segment_id) == (b.x, b.y, b.segment_id)  # the track does not change
        assert b.segment_prob == pytest.approx(tempered.calibration.calibrate(a.segment_prob))
        # the same cloud, its 68 % radius widened by the square root of the temperature
        assert b.accuracy_m == pytest.approx(a.accuracy_m * math.sqrt(tempered.calibration.temperature))
    assert tempered.calibration.pairs > 0
    assert tempered.calibration.persistence > 0.6  # an offset that lasts reads as one


@pytest.mark.parametrize("sigma_m", [0.5, 3.0, 20.0])
def test_the_68_percent_radius_of_a_gaussian_cloud_holds_68_percent_of_it(sigma_m):
    xy = np.random.default_rng(7).normal(0, sigma_m, (200_000, 2)) + [551_000.0, 4_182_000.0]
    spread = math.sqrt(np.mean(np.sum((xy - xy.mean(axis=0)) ** 2, axis=1)))
    inside = np.hypot(*(xy - xy.mean(axis=0)).T) <= accuracy_radius_m(spread)
    assert inside.mean() == pytest.approx(0.68, abs=0.005)
    assert accuracy_radius_m(spread, 4.0) == pytest.approx(2 * accuracy_radius_m(spread))


def test_radius_at_share_scales_the_68_percent_radius_as_for_a_gaussian_with_an_infinite_tail_dof():
    gauss = math.inf
    assert radius_at_share_m(4.0, 0.68, gauss) == pytest.approx(4.0)
    # sqrt(ln 0.05 / ln 0.32)
    assert radius_at_share_m(4.0, 0.95, gauss) == pytest.approx(4.0 * 1.62146, rel=1e-5)
    half = radius_at_share_m(np.array([1.0, 2.0]), 0.5, gauss)
    np.testing.assert_allclose(half, [0.77995, 1.55990], rtol=1e-4)
    assert radius_at_share_m(4.0, 0.95, 1e9) == pytest.approx(radius_at_share_m(4.0, 0.95, gauss), rel=1e-6)
    for share in (0.0, 1.0, 1.5):
        with pytest.raises(ValueError, match="share"):
            radius_at_share_m(4.0, share)
    with pytest.raises(ValueError, match="tail_dof"):
        radius_at_share_m(4.0, 0.9, 0.0)


def test_radius_at_share_holds_its_share_of_student_t_errors_and_widens_the_tail_beyond_a_gaussians():
    rng = np.random.default_rng(11)  # circular bivariate t: a Gaussian over sqrt(chi2(nu) / nu)
    xy = rng.standard_normal((400_000, 2)) / np.sqrt(rng.chisquare(TAIL_DOF, 400_000) / TAIL_DOF)[:, None]
    error = np.hypot(*xy.T)
    accuracy_m = float(np.quantile(error, 0.68))  # a radius that is right at 68 %
    for share in (0.5, 0.8, 0.9, 0.95, 0.99):
        assert np.mean(error <= radius_at_share_m(accuracy_m, share)) == pytest.approx(share, abs=0.003)
    assert radius_at_share_m(1.0, 0.95) == pytest.approx(2.59, abs=0.005)
    assert radius_at_share_m(1.0, 0.5) < radius_at_share_m(1.0, 0.5, math.inf) < 1.0
    assert radius_at_share_m(1.0, 0.9) > radius_at_share_m(1.0, 0.9, math.inf) > 1.0
