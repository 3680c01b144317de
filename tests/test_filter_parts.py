"""Each part of the particle filter against its numpy oracle and its defining behaviour."""

from __future__ import annotations

import math

import numpy as np
import pytest
from filter_maps import X0, Y0, block_map, shifted_building_map, two_sidewalk_map
from filterpy.monte_carlo import systematic_resample
from scipy.stats import multivariate_normal

from curbside import settings
from curbside.localize.filter import (
    FilterConfig,
    GnssConfig,
    GnssFix,
    GnssLikelihood,
    InertialPredictor,
    MapConfig,
    MapLikelihood,
    MotionConfig,
    ParticleSet,
    ResampleConfig,
    SegmentEstimator,
    SystematicResampler,
    Tracker,
    Update,
    normalise_and_estimate,
)
from curbside.localize.filter.gnss import (
    reference_anisotropic_log_likelihood,
    reference_bias_update,
    reference_log_likelihood,
    reference_student_log_likelihood,
)
from curbside.localize.filter.map_likelihood import wall_tolerance_for
from curbside.localize.filter.particles import reference_moments
from curbside.localize.filter.predict import reference_draws, reference_predict
from curbside.localize.filter.resample import _systematic_gather, systematic_indices
from curbside.localize.filter.segments import segment_posterior
from curbside.localize.raster import RasterLookup, rasterize_map
from curbside.osmseg.mapio import MapLayers

QUIET = MotionConfig(
    step_noise_fraction=0.0, step_noise_floor_m=0.0, heading_noise_deg=0.0, scale_noise_per_step=0.0
)


@pytest.fixture(autouse=True)
def _cache_in_tmp(tmp_path, monkeypatch):
    monkeypatch.setattr(settings, "cache_dir", tmp_path / "cache")


def random_particles(n: int, seed: int = 0) -> ParticleSet:
    rng = np.random.default_rng(seed)
    p = ParticleSet(n)
    p.state[0] = X0 + rng.uniform(-90, 90, n)
    p.state[1] = Y0 + rng.uniform(-20, 30, n)
    p.set_heading(rng.uniform(-0.3, 0.3, n))
    p.state[5] = rng.uniform(0.8, 1.2, n)
    p.log_weight[:] = rng.normal(-3, 1, n)
    return p


# -- predictor ------------------------------------------------------------------------------------------


def test_predictor_moves_by_displacement_rotated_by_theta():
    p = ParticleSet(4)
    p.set_heading(np.array([0.0, math.pi / 2, math.pi, -math.pi / 2]))
    InertialPredictor(QUIET, 4, np.random.default_rng(0)).predict(p, 2.0, 0.5)
    np.testing.assert_allclose(p.x, [2.0, -0.5, -2.0, 0.5], atol=1e-12)
    np.testing.assert_allclose(p.y, [0.5, 2.0, -0.5, -2.0], atol=1e-12)


def test_predictor_scales_the_displacement_by_each_particles_speed_scale():
    p = ParticleSet(3)
    p.scale[:] = [0.5, 1.0, 1.2]
    InertialPredictor(QUIET, 3, np.random.default_rng(0)).predict(p, 2.0, 1.0)
    np.testing.assert_allclose(p.x, [1.0, 2.0, 2.4], atol=1e-12)
    np.testing.assert_allclose(p.y, [0.5, 1.0, 1.2], atol=1e-12)


def test_predictor_noise_scales_with_step_length():
    cfg = MotionConfig(step_noise_fraction=0.2, step_noise_floor_m=0.05, heading_noise_deg=0.0)
    spreads = []
    for step in (0.0, 1.0, 2.0):
        p = ParticleSet(20000)
        InertialPredictor(cfg, 20000, np.random.default_rng(1)).predict(p, step, 0.0)
        spreads.append(np.std(p.y))
    np.testing.assert_allclose(spreads, [0.05, 0.2, 0.4], rtol=0.03)


@pytest.mark.parametrize("scale_noise, across", [(0.0, None), (0.01, None), (0.01, 0.1)])
def test_compiled_predictor_matches_its_oracle_fed_the_same_draws(scale_noise, across):
    cfg = MotionConfig(heading_jump_prob=0.05, heading_jump_sigma_deg=40.0, scale_noise_per_step=scale_noise,
                       step_noise_across_fraction=across)
    p = random_particles(500)
    pred = InertialPredictor(cfg, 500, np.random.default_rng(2))
    before, replay = p.state.copy(), pred.stream.copy()
    pred.predict(p, 0.6, 0.3)
    noise, jump_idx, jump_rad = reference_draws(
        replay, 500, cfg.heading_jump_prob, pred.jump_sigma, scale_noise > 0
    )
    assert 5 < len(jump_idx) < 50  # 5 % of 500
    expected = reference_predict(
        before,
        noise,
        0.6,
        0.3,
        pred.position_sigma(0.6, 0.3),
        pred.theta_sigma,
        pred.scale_sigma,
        jump_idx,
        jump_rad,
        None if across is None else pred.across_sigma(0.6, 0.3),
    )
    np.testing.assert_allclose(p.state, expected, rtol=1e-15, atol=1e-12)  # sin/cos within an ulp
    np.testing.assert_array_equal(pred.stream.state, replay.state)  # the kernel drew exactly these


def test_a_motion_swapped_mid_walk_moves_the_next_update_with_its_own_noise():
    # Tracker.adopt_motion assigns predictor.config; the per-update constants must follow it.
    pred = InertialPredictor(QUIET, 4000, np.random.default_rng(4))
    pred.config = MotionConfig(heading_noise_deg=2.0, step_noise_fraction=0.5, step_noise_floor_m=0.0,
                               scale_init_sigma=0.0, scale_noise_per_step=0.0)
    assert pred.theta_sigma == pytest.approx(math.radians(2.0))
    p = ParticleSet(4000)
    pred.predict(p, 2.0, 0.0)
    np.testing.assert_allclose([np.std(p.y), np.degrees(np.std(p.theta))], [1.0, 2.0], rtol=0.06)


def test_anisotropic_step_noise_spreads_along_each_particles_step_not_across_it():
    cfg = MotionConfig(heading_noise_deg=0.0, scale_init_sigma=0.0, scale_noise_per_step=0.0,
                       step_noise_fraction=0.5, step_noise_across_fraction=0.1, step_noise_floor_m=0.0)
    p = ParticleSet(4000)
    p.set_heading(np.where(np.arange(4000) < 2000, 0.0, math.pi / 2))  # half turn the step north
    InertialPredictor(cfg, 4000, np.random.default_rng(1)).predict(p, 2.0, 0.0)
    east, north = p.x[:2000], p.y[2000:]  # along each half's step
    np.testing.assert_allclose([np.std(east), np.std(p.y[:2000])], [1.0, 0.2], rtol=0.06)
    np.testing.assert_allclose([np.std(north), np.std(p.x[2000:])], [1.0, 0.2], rtol=0.06)
    np.testing.assert_allclose([np.mean(east), np.mean(north)], [2.0, 2.0], atol=0.06)


def test_predictor_turns_by_huge_heading_offsets_with_the_c_library():
    # Beyond kernelmath.LIMIT radians the polynomial sine/cosine would lose accuracy: the kernel falls
    # back to math.sin / math.cos for the whole update.
    p = ParticleSet(3)
    p.set_heading(np.array([0.1, 2000.0, -5000.5]))
    InertialPredictor(QUIET, 3, np.random.default_rng(0)).predict(p, 1.0, 0.0)
    np.testing.assert_array_equal(p.state[3], np.cos(p.theta))
    np.testing.assert_array_equal(p.state[4], np.sin(p.theta))
    np.testing.assert_array_equal(p.x, np.cos(p.theta))


def test_heading_jumps_move_a_few_particles_by_tens_of_degrees():
    cfg = MotionConfig(heading_noise_deg=0.0, heading_jump_prob=0.02, heading_jump_sigma_deg=30.0)
    p = ParticleSet(5000)
    InertialPredictor(cfg, 5000, np.random.default_rng(3)).predict(p, 1.0, 0.0)
    moved = np.abs(p.theta) > 0
    assert 50 < moved.sum() < 150  # 2 % of 5000
    assert 20 < np.degrees(np.std(p.theta[moved])) < 40
    np.testing.assert_allclose(np.cos(p.theta), p.state[3], atol=1e-12)  # cos/sin rows kept in step


# -- map likelihood -------------------------------------------------------------------------------------


def test_map_likelihood_kills_building_particles_and_weighs_streets():
    raster = rasterize_map(block_map(), 0.5)
    lik = MapLikelihood(raster, MapConfig(jaywalk_weight=0.4))
    x = X0 + np.array([50.0, 50.0, 50.0, 0.0, 5000.0])
    y = Y0 + np.array([30.0, 0.0, 8.0, 0.0, 5000.0])
    out = lik.log_likelihood(x, y)
    assert out[0] == -np.inf
    np.testing.assert_allclose(out[1:], [math.log(0.4), 0.0, 0.0, 0.0])
    p = ParticleSet(5)
    p.state[0], p.state[1] = x, y
    p.log_weight[:] = 0.0
    lik.weigh(p, Update(1.0, 0.5, 0.0, 0.0))
    np.testing.assert_array_equal(p.log_weight, out)
    assert lik.blocked_share == 0.2  # one particle of five behind a wall; the street's 0.4 is not one


def test_a_step_across_the_street_weighs_the_crossing_weight_and_a_step_along_it_the_jaywalk_weight():
    raster = rasterize_map(two_sidewalk_map(), 0.5)  # street along x (|y| < 6), sidewalks N and S
    lik = MapLikelihood(raster, MapConfig(jaywalk_weight=0.4, crossing_weight=0.7, crossing_angle_deg=30.0))
    p = ParticleSet(6)
    p.state[0] = X0 + np.array([0.0, 10.0, 20.0, 30.0, 40.0, 50.0])
    p.state[1] = Y0 + np.array([0.0, 0.0, 0.0, 0.0, 3.0, 8.0])  # five on the street, one on a sidewalk
    p.set_heading(np.radians([0.0, 25.0, 40.0, 90.0, -170.0, 90.0]))  # the step north, turned by these
    north = Update(1.0, 0.5, 0.0, 0.7)
    want = np.log([0.7, 0.7, 0.4, 0.4, 0.7, 1.0])  # 0 and 25 deg off square: crossing; 40 and 90: along
    np.testing.assert_allclose(lik.reference_log_likelihood(p, north), want)
    p.log_weight[:] = 0.0
    lik.weigh(p, north)
    np.testing.assert_allclose(p.log_weight, want)
    for update in (Update(1.0, 0.5, 0.0, 0.1), None):  # standing, or no step: the street weighs as it is
        p.log_weight[:] = 0.0
        lik.weigh(p, update)
        np.testing.assert_allclose(p.log_weight, np.log([0.4] * 5 + [1.0]))
    for config in (FilterConfig.preset("paper").map, MapConfig(crossing_weight=0.2)):  # off; below w
        p.log_weight[:] = 0.0
        MapLikelihood(raster, config).weigh(p, north)
        np.testing.assert_allclose(p.log_weight, np.log([0.4] * 5 + [1.0]))
    forbidden = MapLikelihood(raster, MapConfig(jaywalk_weight=0.0, crossing_weight=0.0))
    assert np.isneginf(forbidden.reference_log_likelihood(p, north)[:5]).all()
    gdf = two_sidewalk_map().gdf  # without sidewalk segments there is no street axis: one street weight
    no_segments = MapLikelihood(rasterize_map(MapLayers(gdf[gdf["class"] != "sidewalk"])), MapConfig())
    assert no_segments.max_along < 0
    p.log_weight[:] = 0.0
    no_segments.weigh(p, north)
    np.testing.assert_allclose(p.log_weight, np.log([0.4] * 5 + [1.0]))  # the last on free ground now


def test_soft_walls_tolerate_a_metre_of_map_error_but_not_ten():
    raster = rasterize_map(block_map(), 0.5)  # building from y = 10
    lik = MapLikelihood(raster, MapConfig(wall_tolerance_m=1.5))
    w = np.exp(lik.log_likelihood(np.full(4, X0), Y0 + np.array([9.0, 10.75, 12.0, 20.0])))
    assert w[0] == 1.0 and 0.8 < w[1] < 0.95 and 0.3 < w[2] < 0.6 and w[3] == 0.0
    hard = MapLikelihood(raster, MapConfig())
    assert np.exp(hard.log_likelihood(np.array([X0]), np.array([Y0 + 10.75])))[0] == 0.0
    p = ParticleSet(4)  # with soft walls, a particle counts as stopped once its weight is under 1 %
    p.state[0], p.state[1] = np.full(4, X0), Y0 + np.array([9.0, 10.75, 12.0, 20.0])
    lik.weigh(p, Update(1.0, 0.5, 0.0, 0.0))
    assert lik.blocked_share == 0.25


def test_sidewalks_win_and_walls_soften_on_a_map_whose_buildings_cover_its_sidewalks():
    conflicted = rasterize_map(shifted_building_map(), 0.5)  # building from y = 8, over the sidewalk's 8-10 m
    lik = MapLikelihood(conflicted, MapConfig())
    assert lik.wall_tolerance_m == 1.5 and lik.walkable_first
    w = np.exp(lik.log_likelihood(np.full(4, X0 + 50.0), Y0 + np.array([7.0, 8.75, 10.75, 16.0])))
    assert w[0] == w[1] == 1.0 and 0.8 < w[2] < 0.95 and w[3] == 0.0  # the wall now starts at 10 m, soft
    walls_only = MapLikelihood(conflicted, MapConfig(conflict_walkable_first=False))
    assert not walls_only.walkable_first and walls_only.raster is conflicted
    w = np.exp(walls_only.log_likelihood(np.full(3, X0 + 50.0), Y0 + np.array([7.0, 8.75, 14.0])))
    assert w[0] == 1.0 and 0.8 < w[1] < 0.95 and w[2] == 0.0  # 0.75 m inside: soft; 6 m: past 3 t
    clean = MapLikelihood(rasterize_map(block_map(), 0.5), MapConfig())
    assert clean.wall_tolerance_m == 0.0 and not clean.walkable_first
    assert not MapLikelihood(conflicted, FilterConfig.preset("paper").map).walkable_first
    assert wall_tolerance_for(conflicted, FilterConfig.preset("paper").map) == 0.0  # the paper's hard walls
    assert wall_tolerance_for(conflicted, MapConfig(conflict_share_min=0.6)) == 0.0  # 0.5 covered
    assert wall_tolerance_for(conflicted, MapConfig(wall_tolerance_m=2.0)) == 2.0


def test_filters_on_one_conflicted_map_share_one_walkable_first_raster():
    conflicted = rasterize_map(shifted_building_map(), 0.5)  # as the live service holds it: one per map
    first, second = (Tracker.from_config(conflicted, seed=seed) for seed in (0, 1))
    assert first.map_raster is second.map_raster is conflicted.walkable_first is not conflicted
    assert first.walkable_first and first.wall_tolerance_m == 1.5
    paper = Tracker.from_config(conflicted, FilterConfig.preset("paper"))
    assert paper.map_raster is conflicted and not paper.walkable_first


# -- GNSS likelihood ------------------------------------------------------------------------------------


def test_gnss_likelihood_is_the_gaussian_log_density_and_prefers_near_particles():
    lik = GnssLikelihood(
        GnssConfig(sigma_factor=1.5, outlier_prob=0.0, correlation_time_s=0.0), 3, np.random.default_rng(0)
    )
    fix = GnssFix(10.0, -4.0, 6.0)
    p = ParticleSet(3)
    p.state[0], p.state[1] = [10.0, 14.0, 40.0], [-4.0, -1.0, 20.0]
    p.log_weight[:] = 0.0
    lik.weigh(p, Update(1.0, 1.0, 0.0, 0.0, fix))
    expected = multivariate_normal([10.0, -4.0], (1.5 * 6.0) ** 2 * np.eye(2)).logpdf(p.state[:2].T)
    np.testing.assert_allclose(p.log_weight, expected)
    assert p.log_weight[0] > p.log_weight[1] > p.log_weight[2]


def test_gnss_mixture_is_the_mixture_density_bounded_below_and_tempered():
    eps, radius = 0.1, 50.0
    cfg = GnssConfig(sigma_factor=1.5, outlier_prob=eps, outlier_radius_m=radius, correlation_time_s=2.0)
    lik = GnssLikelihood(cfg, 4, np.random.default_rng(0))
    fix = GnssFix(10.0, -4.0, 6.0)
    p = ParticleSet(4)
    p.state[0], p.state[1] = [10.0, 14.0, 40.0, 1e4], [-4.0, -1.0, 20.0, 1e4]
    p.log_weight[:] = 0.0
    lik.weigh(p, Update(5.0, 1.0, 0.0, 0.0, fix))  # the first fix: exponent 1
    gauss = multivariate_normal([10.0, -4.0], (1.5 * 6.0) ** 2 * np.eye(2)).pdf(p.state[:2].T)
    floor = eps / (math.pi * radius**2)
    np.testing.assert_allclose(p.log_weight, np.log((1 - eps) * gauss + floor))
    assert p.log_weight[3] == pytest.approx(math.log(floor))
    p.log_weight[:] = 0.0
    lik.weigh(p, Update(6.0, 1.0, 0.0, 0.0, fix))  # one second later: tempered
    rho = math.exp(-1.0 / 2.0)
    expected = reference_log_likelihood(
        p.state[0], p.state[1], fix, lik.coefficients(fix), (1 - rho) / (1 + rho)
    )
    np.testing.assert_allclose(p.log_weight, expected, rtol=1e-12)


def test_tempering_counts_correlated_fixes_by_their_effective_number():
    lik = GnssLikelihood(GnssConfig(correlation_time_s=10.0), 1, np.random.default_rng(0))
    rho = math.exp(-1.0 / 10.0)
    assert lik.exponent(1.0) == pytest.approx((1 - rho) / (1 + rho))
    assert 2 * lik.exponent(0.5) == pytest.approx(lik.exponent(1.0), rel=0.01)  # 2 Hz reuse: no extra weight
    assert lik.exponent(math.inf) == 1.0 and lik.exponent(1e4) == pytest.approx(1.0)
    assert GnssLikelihood(GnssConfig(correlation_time_s=0.0), 1, None).exponent(0.5) == 1.0


def test_a_fix_reporting_a_poor_accuracy_is_tempered_as_longer_correlated():
    lik = GnssLikelihood(GnssConfig(correlation_time_s=3.0, correlation_accuracy_m=10.0), 3, None)
    constant = GnssLikelihood(GnssConfig(correlation_time_s=3.0, correlation_accuracy_m=0.0), 3, None)
    for accuracy_m in (3.0, 10.0):  # at or under the reference: one time constant
        assert lik.exponent(1.0, accuracy_m) == constant.exponent(1.0, accuracy_m) == constant.exponent(1.0)
    rho = math.exp(-1.0 / 7.5)  # 25 m: 2.5 times as long
    assert lik.exponent(1.0, 25.0) == pytest.approx((1 - rho) / (1 + rho))
    assert lik.exponent(1.0, 25.0) < lik.exponent(1.0, 10.0)
    assert constant.exponent(1.0, 25.0) == lik.exponent(1.0)
    assert lik.exponent(math.inf, 25.0) == 1.0  # the first fix counts whole
    fix = GnssFix(10.0, -4.0, 25.0)
    p = ParticleSet(3)
    p.state[0], p.state[1] = [10.0, 14.0, 40.0], [-4.0, -1.0, 20.0]
    lik.weigh(p, Update(5.0, 1.0, 0.0, 0.0, fix))
    p.log_weight[:] = 0.0
    lik.weigh(p, Update(6.0, 1.0, 0.0, 0.0, fix))  # the update reads the fix's accuracy
    exponent = (1 - rho) / (1 + rho)
    expected = reference_log_likelihood(p.state[0], p.state[1], fix, lik.coefficients(fix), exponent)
    np.testing.assert_allclose(p.log_weight, expected, rtol=1e-12)


def test_bias_state_update_matches_its_oracle_and_learns_a_steady_offset():
    cfg = GnssConfig(
        sigma_factor=0.3, bias_sigma_factor=2.0, bias_time_s=30.0, outlier_prob=0.05, correlation_time_s=0.0
    )
    lik = GnssLikelihood(cfg, 300, np.random.default_rng(0))
    p = random_particles(300)
    p.state[0], p.state[1] = (p.state[0] - X0) / 20, (p.state[1] - Y0) / 10  # within 5 m of the origin
    fixes = [
        GnssFix(3.0, -8.0, 4.0),
        GnssFix(3.5, -8.2, 4.0),
        GnssFix(60.0, 40.0, 4.0),
    ]  # the last: an outlier
    for k, fix in enumerate(fixes):
        rho, prior = lik._bias_prior(fix, 1.0 if k else math.inf)
        s_ = prior + lik.sigma_m(fix) ** 2
        a, b = -0.5 / s_, lik.log_inlier_prob - math.log(2 * math.pi * s_)
        ll, expected_state, r_mean = reference_bias_update(
            p.state, fix, a, b, lik.log_outlier_density, rho, prior / s_
        )
        before = p.log_weight.copy()
        lik.weigh(p, Update(float(k), 1.0, 0.0, 0.0, fix))
        np.testing.assert_allclose(p.log_weight - before, ll, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(p.state, expected_state, rtol=0, atol=1e-12)
        assert lik.bias_variance == pytest.approx((1 - r_mean * prior / s_) * prior)
    # the first two fixes taught the bias means the offset fix - position; the outlier 70 m away did not
    assert np.abs(p.bias_x + p.x - 3.4).mean() < 1.5 and np.abs(p.bias_y + p.y + 8.1).mean() < 1.5


@pytest.mark.parametrize("accuracy", [-1.0, 0.0, math.nan, math.inf, 80.0])
def test_invalid_or_inaccurate_fixes_make_no_update(accuracy):
    lik = GnssLikelihood(GnssConfig(max_accuracy_m=50.0), 2, np.random.default_rng(0))
    assert not lik.accepts(GnssFix(0.0, 0.0, accuracy))
    assert lik.accepts(GnssFix(0.0, 0.0, 10.0))
    p = ParticleSet(2)
    before = p.log_weight.copy()
    lik.weigh(p, Update(1.0, 1.0, 0.0, 0.0, GnssFix(0.0, 0.0, accuracy)))
    np.testing.assert_array_equal(p.log_weight, before)


# -- normalisation, resampling, segments ----------------------------------------------------------------


def test_normalisation_matches_the_logsumexp_oracle_and_never_underflows():
    p = random_particles(300)
    p.log_weight -= 1e6  # far below exp's range
    p.log_weight[::7] = -np.inf
    expected = reference_moments(p)
    got = normalise_and_estimate(p)
    assert got.ok
    np.testing.assert_allclose(got, expected, rtol=1e-9)
    np.testing.assert_allclose(p.weights.sum(), 1.0)
    p.log_weight[:] = -np.inf
    assert not normalise_and_estimate(p).ok
    p.log_weight[:] = 0.0
    p.log_weight[3] = np.nan
    assert not normalise_and_estimate(p).ok


def test_systematic_resampling_matches_filterpy_on_the_same_uniform():
    rng = np.random.default_rng(5)
    for n in (1, 7, 500):
        w = rng.gamma(0.3, size=n)
        w /= w.sum()
        # filterpy draws its one uniform from the legacy global RNG: replay that draw.
        np.random.seed(n)  # noqa: NPY002
        u0 = np.random.random()  # noqa: NPY002
        np.random.seed(n)  # noqa: NPY002
        expected = systematic_resample(w)
        np.testing.assert_array_equal(systematic_indices(w, u0), expected)
        state = np.tile(np.arange(n, dtype=float), (8, 1))
        out = np.empty_like(state)
        ancestors = np.full(n, -1)
        _systematic_gather(w, u0, state, out, ancestors)
        np.testing.assert_array_equal(out.astype(int), np.tile(expected, (8, 1)))
        np.testing.assert_array_equal(ancestors, expected)


def test_resampler_keeps_heavy_particles_drops_zero_weights_and_follows_its_policy():
    p = ParticleSet(4)
    p.x[:] = [0.0, 1.0, 2.0, 3.0]
    p.weights[:] = [0.0, 0.5, 0.0, 0.5]
    assert SystematicResampler(ResampleConfig(policy="always"), np.random.default_rng(0)).resample(p, 2.0)
    assert sorted(p.x.tolist()) == [1.0, 1.0, 3.0, 3.0]
    np.testing.assert_allclose(p.log_weight, -math.log(4))
    lazy = SystematicResampler(ResampleConfig(policy="ess", ess_fraction=0.5), np.random.default_rng(0))
    assert not lazy.resample(p, 3.0) and lazy.resample(p, 1.5)


def test_segment_mode_matches_its_oracle_and_picks_the_heavier_sidewalk():
    raster = rasterize_map(two_sidewalk_map(), 0.5)
    p = random_particles(500, seed=4)
    rng = np.random.default_rng(1)
    north = np.arange(500) < 250
    p.state[1] = np.where(north, Y0 + 8.0, Y0 - 8.0) + rng.uniform(-1, 1, 500)
    p.weights[:] = np.where(north, 0.6, 0.4) / 250
    mode = SegmentEstimator(raster, 500).mode(p)
    segment_of = RasterLookup(raster).segments_at(p.x, p.y)
    _, expected = segment_posterior(segment_of, p.weights, p.x, p.y)
    assert raster.segment_ids[mode.segment] == "N" and mode.prob == pytest.approx(0.6)
    np.testing.assert_allclose(mode, expected, rtol=1e-12)


def test_config_sections_reject_bad_values():
    for make in (
        lambda: MapConfig(jaywalk_weight=1.5),
        lambda: FilterConfig(n_particles=0),
        lambda: ResampleConfig(policy="never"),
        lambda: GnssConfig(outlier_prob=1.0),
        lambda: GnssConfig(outlier_radius_m=0.0),
        lambda: GnssConfig(correlation_time_s=-1.0),
        lambda: GnssConfig(bias_sigma_factor=-1.0),
        lambda: GnssConfig(bias_time_s=0.0),
        lambda: MotionConfig(heading_jump_prob=2.0),
        lambda: MapConfig(wall_tolerance_m=-1.0),
        lambda: MapConfig(crossing_weight=1.2),
        lambda: MapConfig(crossing_angle_deg=0.0),
    ):
        with pytest.raises(ValueError):
            make()


def test_student_t_likelihood_is_scipys_density_and_still_pulls_from_far_away():
    cfg = GnssConfig(student_dof=3.0, sigma_factor=0.66, correlation_time_s=0.0)
    lik = GnssLikelihood(cfg, 4, np.random.default_rng(0))
    fix = GnssFix(10.0, -4.0, 6.0)
    p = ParticleSet(4)
    p.state[0], p.state[1] = [10.0, 14.0, 60.0, 80.0], [-4.0, -1.0, 20.0, 20.0]
    p.log_weight[:] = 0.0
    lik.weigh(p, Update(1.0, 1.0, 0.0, 0.0, fix))
    expected = reference_student_log_likelihood(p.x, p.y, fix, lik.sigma_m(fix), 3.0, 1.0)
    np.testing.assert_allclose(p.log_weight, expected, rtol=1e-12)
    assert p.log_weight[2] - p.log_weight[3] > 0.5  # 50 m vs 70 m away: the nearer one still wins


def test_anisotropic_likelihood_follows_the_street_and_matches_its_oracle():
    raster = rasterize_map(two_sidewalk_map(), 0.5)  # streets along x: axis (1, 0)
    cfg = GnssConfig(across_factor=2.0, sigma_factor=0.66, correlation_time_s=0.0, outlier_prob=0.05)
    lik = GnssLikelihood(cfg, 4, np.random.default_rng(0), raster)
    fix = GnssFix(X0, Y0 + 8.0, 6.0)
    p = ParticleSet(4)
    # 10 m along the street, 10 m across it (on the opposite sidewalk), and near the fix
    p.state[0], p.state[1] = X0 + np.array([10.0, 0.0, 1.0, -10.0]), Y0 + np.array([8.0, -2.0, 8.0, 8.0])
    p.log_weight[:] = 0.0
    lik.weigh(p, Update(1.0, 1.0, 0.0, 0.0, fix))
    expected = reference_anisotropic_log_likelihood(
        p.x, p.y, fix, lik.sigma_m(fix), 2.0, (1.0, 0.0), lik.log_outlier_density, lik.log_inlier_prob, 1.0
    )
    np.testing.assert_allclose(p.log_weight, expected, rtol=1e-10)
    assert p.log_weight[1] > p.log_weight[0]  # across the street is cheaper than the same distance along it
    iso = GnssLikelihood(
        GnssConfig(sigma_factor=0.66, correlation_time_s=0.0), 4, np.random.default_rng(0), raster
    )
    q = ParticleSet(4)
    q.state[:2] = p.state[:2]
    q.log_weight[:] = 0.0
    iso.weigh(q, Update(1.0, 1.0, 0.0, 0.0, fix))
    assert q.log_weight[1] == pytest.approx(q.log_weight[0])  # isotropic: the same
