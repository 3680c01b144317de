"""Unit tests of the particle filter's components, the map raster and the tracker."""

from __future__ import annotations

import math

import geopandas as gpd
import numpy as np
import pytest
import shapely
from filterpy.monte_carlo import systematic_resample
from scipy.stats import multivariate_normal

from curbside import settings
from curbside.errors import CurbsideInputError
from curbside.localize import maplikelihood
from curbside.localize.filter import (
    FilterConfig,
    GnssFix,
    GnssLikelihood,
    InertialPredictor,
    MapLikelihood,
    ParticleSet,
    SystematicResampler,
    Tracker,
    _systematic_resample,
    normalise_log_weights,
    systematic_indices,
)
from curbside.localize.maplikelihood import (
    BUILDING,
    CROSSWALK,
    FREE,
    SIDEWALK,
    STREET,
    load_or_build_raster,
    map_hash,
    rasterize_map,
    rasterize_mask,
)
from curbside.localize.pipeline import fresh_fixes_at
from curbside.osmseg.mapio import MapLayers

UTM10 = 32610
X0, Y0 = 551000.0, 4182000.0  # downtown San Francisco in EPSG:32610


def block_map() -> MapLayers:
    """A street along x with a crosswalk, a sidewalk north of it and a building beyond."""
    def box(x0, y0, x1, y1):
        return shapely.box(X0 + x0, Y0 + y0, X0 + x1, Y0 + y1)

    rows = [
        ("street", box(-100, -6, 100, 6), None),
        ("crosswalk", box(-3, -6, 3, 6), None),
        ("sidewalk", box(-100, 6, 100, 10), "N1"),
        ("building", box(-100, 10, 100, 60), None),
    ]
    gdf = gpd.GeoDataFrame(
        {"class": [r[0] for r in rows], "segment_id": [r[2] for r in rows], "street": None, "side": None},
        geometry=[r[1] for r in rows],
        crs=UTM10,
    )
    return MapLayers(gdf)


@pytest.fixture(autouse=True)
def _cache_in_tmp(tmp_path, monkeypatch):
    monkeypatch.setattr(settings, "cache_dir", tmp_path / "cache")


def quiet_config(**kw) -> FilterConfig:
    """No process noise: motion is deterministic."""
    base = dict(step_noise_fraction=0.0, step_noise_floor_m=0.0, theta_noise_deg=0.0,
                scale_init_sigma=0.0, scale_noise_per_step=0.0)
    base.update(kw)
    return FilterConfig(**base)


# -- raster ---------------------------------------------------------------------------------------------


def test_rasterize_mask_matches_shapely_with_holes_overlaps_and_multipolygons():
    rng = np.random.default_rng(3)
    centres = rng.uniform(0, 80, (30, 2))
    discs = shapely.buffer(shapely.points(centres), rng.uniform(1, 9, 30), quad_segs=4)
    ring_with_hole = shapely.Polygon(
        [(5, 5), (70, 8), (60, 70), (8, 60)], [[(20, 20), (20, 45), (45, 45), (45, 20)]]
    )
    multi = shapely.MultiPolygon([shapely.box(0, 70, 10, 80), shapely.box(70, 0, 80, 10)])
    geoms = np.concatenate([discs, [ring_with_hole, multi, shapely.Polygon([(0, 0), (30, 4), (4, 30)])]])
    res, x0, y0, shape = 0.31, -2.05, -1.7, (280, 290)
    mask = rasterize_mask(geoms, x0, y0, res, shape)
    jj, ii = np.meshgrid(np.arange(shape[1]), np.arange(shape[0]))
    expected = shapely.contains_xy(shapely.union_all(geoms), x0 + (jj + 0.5) * res, y0 + (ii + 0.5) * res)
    assert mask.sum() > 1000
    np.testing.assert_array_equal(mask, expected)


def test_raster_class_precedence_and_outside_is_free():
    raster = rasterize_map(block_map(), 0.5)
    xs = X0 + np.array([50.0, 0.0, 50.0, 50.0, 50.0, 500.0])
    ys = Y0 + np.array([0.0, 0.0, 8.0, 30.0, -30.0, 0.0])
    codes = raster.codes_at(xs, ys)
    assert codes.tolist() == [STREET, CROSSWALK, SIDEWALK, BUILDING, FREE, FREE]


def test_raster_is_cached_on_disk_and_reused(monkeypatch):
    layers = block_map()
    first = load_or_build_raster(layers, 1.0)
    cached = list((settings.cache_dir / "rasters").glob("*.npz"))
    assert [p.stem for p in cached] == [map_hash(layers, 1.0)]

    def fail(*args, **kwargs):
        raise AssertionError("rasterised again despite the cache")

    monkeypatch.setattr(maplikelihood, "rasterize_map", fail)
    second = load_or_build_raster(layers, 1.0)
    np.testing.assert_array_equal(first.codes, second.codes)
    assert (second.x0, second.y0, second.resolution_m) == (first.x0, first.y0, first.resolution_m)
    assert map_hash(layers, 0.5) != map_hash(layers, 1.0)


def test_nearest_free_cell_from_inside_a_building():
    raster = rasterize_map(block_map(), 0.5)
    snapped = raster.nearest_code_other_than(X0 + 20.0, Y0 + 13.0, BUILDING, 30.0)
    assert snapped is not None
    assert raster.codes_at(np.array([snapped[0]]), np.array([snapped[1]]))[0] != BUILDING
    assert abs(snapped[1] - (Y0 + 9.75)) < 1e-9
    assert raster.nearest_code_other_than(X0 + 20.0, Y0 + 35.0, BUILDING, 10.0) is None


# -- components -----------------------------------------------------------------------------------------


def test_predictor_moves_by_displacement_rotated_by_theta():
    cfg = quiet_config(n_particles=4)
    p = ParticleSet(4)
    p.theta[:] = [0.0, math.pi / 2, math.pi, -math.pi / 2]
    InertialPredictor(cfg, np.random.default_rng(0)).predict(p, 2.0, 0.5)
    np.testing.assert_allclose(p.x, [2.0, -0.5, -2.0, 0.5], atol=1e-12)
    np.testing.assert_allclose(p.y, [0.5, 2.0, -0.5, -2.0], atol=1e-12)


def test_predictor_scales_the_displacement_by_each_particles_speed_scale():
    p = ParticleSet(3)
    p.scale[:] = [0.5, 1.0, 1.2]
    InertialPredictor(quiet_config(n_particles=3), np.random.default_rng(0)).predict(p, 2.0, 1.0)
    np.testing.assert_allclose(p.x, [1.0, 2.0, 2.4], atol=1e-12)
    np.testing.assert_allclose(p.y, [0.5, 1.0, 1.2], atol=1e-12)


def test_predictor_noise_scales_with_step_length():
    cfg = FilterConfig(n_particles=20000, step_noise_fraction=0.2, step_noise_floor_m=0.05, theta_noise_deg=0)
    spreads = []
    for step in (0.0, 1.0, 2.0):
        p = ParticleSet(cfg.n_particles)
        InertialPredictor(cfg, np.random.default_rng(1)).predict(p, step, 0.0)
        spreads.append(np.std(p.y))
    np.testing.assert_allclose(spreads, [0.05, 0.2, 0.4], rtol=0.03)


def test_map_likelihood_kills_building_particles():
    raster = rasterize_map(block_map(), 0.5)
    lik = MapLikelihood(raster, jaywalk_weight=0.4)
    x = X0 + np.array([50.0, 50.0, 50.0, 0.0, 5000.0])
    y = Y0 + np.array([30.0, 0.0, 8.0, 0.0, 5000.0])
    out = lik.log_likelihood(x, y, out=np.empty(5))
    assert out[0] == -np.inf
    np.testing.assert_allclose(out[1:], [math.log(0.4), 0.0, 0.0, 0.0])


def test_gnss_likelihood_is_the_gaussian_log_density_and_prefers_near_particles():
    lik = GnssLikelihood(sigma_factor=1.5, max_accuracy_m=50.0)
    fix = GnssFix(10.0, -4.0, 6.0)
    x, y = np.array([10.0, 14.0, 40.0]), np.array([-4.0, -1.0, 20.0])
    out = lik.log_likelihood(x, y, fix, np.empty(3), np.empty(3))
    expected = multivariate_normal([10.0, -4.0], (1.5 * 6.0) ** 2 * np.eye(2)).logpdf(np.column_stack([x, y]))
    np.testing.assert_allclose(out, expected)
    assert out[0] > out[1] > out[2]


def test_gnss_mixture_is_the_mixture_density_and_bounded_below():
    eps, radius = 0.1, 50.0
    lik = GnssLikelihood(sigma_factor=1.5, max_accuracy_m=50.0, outlier_prob=eps, outlier_radius_m=radius)
    fix = GnssFix(10.0, -4.0, 6.0)
    x, y = np.array([10.0, 14.0, 40.0, 1e4]), np.array([-4.0, -1.0, 20.0, 1e4])
    out = lik.log_likelihood(x, y, fix, np.empty(4), np.empty(4))
    gauss = multivariate_normal([10.0, -4.0], (1.5 * 6.0) ** 2 * np.eye(2)).pdf(np.column_stack([x, y]))
    floor = eps / (math.pi * radius**2)
    np.testing.assert_allclose(out, np.log((1 - eps) * gauss + floor))
    assert out[0] > out[1] > out[2] and out[3] == pytest.approx(math.log(floor))
    tempered = lik.log_likelihood(x, y, fix, np.empty(4), np.empty(4), exponent=0.25)
    np.testing.assert_allclose(tempered, 0.25 * out)


@pytest.mark.parametrize("backend", ["numba", "numpy"])
def test_an_outlier_fix_cannot_drag_or_kill_the_cloud(backend):
    def after_far_fix(outlier_prob):
        cfg = quiet_config(n_particles=500, backend=backend, init_position_sigma_m=1.0,
                           gnss_outlier_prob=outlier_prob, gnss_sigma_factor=1.5)
        tracker = Tracker(None, cfg, seed=3, frame=None)
        tracker.start_at_pose(0.0, 0.0, 0.0)
        return tracker.step(1.0, displacement_en=(0.0, 0.0), gnss_fix=GnssFix(30.0, 0.0, 3.0))

    plain, robust = after_far_fix(0.0), after_far_fix(0.2)
    assert plain.n_eff < 0.5 * 500  # the Gaussian alone pulls the cloud towards a fix 30 m away
    assert robust.n_eff > 0.95 * 500 and not robust.recovered
    assert math.hypot(robust.x, robust.y) < 0.2


def test_tempering_counts_correlated_fixes_by_their_effective_number():
    lik = GnssLikelihood(1.5, 50.0, correlation_time_s=10.0)
    rho = math.exp(-1.0 / 10.0)
    assert lik.exponent(1.0) == pytest.approx((1 - rho) / (1 + rho))
    assert 2 * lik.exponent(0.5) == pytest.approx(lik.exponent(1.0), rel=0.01)  # 2 Hz reuse: no extra weight
    assert lik.exponent(math.inf) == 1.0 and lik.exponent(1e4) == pytest.approx(1.0)
    assert GnssLikelihood(1.5, 50.0).exponent(0.5) == 1.0


def test_bias_state_absorbs_a_steady_gnss_offset_instead_of_moving_the_track():
    def final_estimate(bias_sigma_m):
        cfg = FilterConfig(n_particles=500, gnss_bias_sigma_m=bias_sigma_m, gnss_bias_time_s=30.0,
                           gnss_sigma_factor=0.66, gnss_outlier_prob=0.0, gnss_error_correlation_s=0.0)
        tracker = Tracker(None, cfg, seed=0, frame=None)
        tracker.start_at_pose(0.0, 0.0, 0.0)
        for k in range(1, 121):  # 60 s east at 1.3 m/s; every fix 12 m south of the truth
            fix = GnssFix(0.65 * k, -12.0, 3.0) if k % 2 == 0 else None
            estimate = tracker.step(0.5 * k, displacement_en=(0.65, 0.0), gnss_fix=fix)
        return estimate, float(np.mean(tracker.particles.bias_y))

    plain, _ = final_estimate(0.0)
    with_bias, bias_y = final_estimate(8.0)
    assert plain.y < -10.0  # the plain filter follows the offset fixes
    assert abs(with_bias.y) < 0.5 * abs(plain.y) and bias_y < -5.0


def test_each_fix_is_applied_once_at_the_first_footstep_at_or_after_it():
    tf = np.array([0.2, 1.2, 2.2, 2.4, 10.0])
    fixes = (tf, tf * 10.0, np.zeros(5), np.full(5, 5.0))
    steps = np.arange(0.0, 8.01, 0.5)
    x, _, acc = fresh_fixes_at(fixes, steps, max_age_s=3.0)
    used = np.isfinite(acc)
    np.testing.assert_allclose(steps[used], [0.5, 1.5, 2.5])
    np.testing.assert_allclose(x[used], [2.0, 12.0, 24.0])  # two fixes in one step: the newer one
    x, _, acc = fresh_fixes_at(fixes, np.array([5.0, 5.5]), max_age_s=2.0)
    assert np.isnan(acc).all()  # 2.6 s old at the first footstep after it: stale


@pytest.mark.parametrize("accuracy", [-1.0, 0.0, math.nan, math.inf, 80.0])
def test_invalid_or_inaccurate_fixes_make_no_update(accuracy):
    assert not GnssLikelihood(1.0, 50.0).accepts(GnssFix(0.0, 0.0, accuracy))
    assert GnssLikelihood(1.0, 50.0).accepts(GnssFix(0.0, 0.0, 10.0))


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
        outs = [np.empty(n) for _ in range(6)]
        ids = np.arange(n, dtype=float)
        _systematic_resample(w, u0, *([ids] * 6), *outs)
        x_out = outs[0]
        np.testing.assert_array_equal(x_out.astype(int), expected)


def test_resampler_keeps_heavy_particles_and_drops_zero_weights():
    p = ParticleSet(4)
    p.x[:] = [0.0, 1.0, 2.0, 3.0]
    w = np.array([0.0, 0.5, 0.0, 0.5])
    SystematicResampler(4, np.random.default_rng(0)).resample(p, w)
    assert sorted(p.x.tolist()) == [1.0, 1.0, 3.0, 3.0]
    np.testing.assert_allclose(p.log_weight, -math.log(4))


def test_log_domain_weights_never_underflow():
    log_w = np.array([-1e6, -1e6 - 1.0, -np.inf])
    w = np.empty(3)
    assert normalise_log_weights(log_w, w)
    np.testing.assert_allclose(w, [1 / (1 + math.e**-1), math.e**-1 / (1 + math.e**-1), 0.0])
    assert not normalise_log_weights(np.full(3, -np.inf), w)
    assert not normalise_log_weights(np.array([0.0, np.nan, 1.0]), w)


@pytest.mark.parametrize("backend", ["numba", "numpy"])
def test_ten_thousand_tiny_likelihoods_keep_finite_weights(backend):
    cfg = FilterConfig(n_particles=200, resample="ess", ess_fraction=0.0, backend=backend,
                       gnss_sigma_factor=1.0, gnss_max_accuracy_m=50.0, gnss_outlier_prob=0.0)
    tracker = Tracker(None, cfg, seed=2, frame=None)
    tracker.start_at_pose(0.0, 0.0, 0.0)
    far_fix = GnssFix(400.0, 0.0, 2.0)  # each update multiplies by ~exp(-20000)
    for k in range(10_000):
        est = tracker.step(float(k + 1), displacement_en=(0.0, 0.0), gnss_fix=far_fix)
    assert tracker.recoveries == 0
    assert math.isfinite(est.x) and math.isfinite(est.y)
    assert 1.0 <= est.n_eff <= cfg.n_particles
    assert np.isfinite(tracker.particles.log_weight).any()


# -- tracker --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("backend", ["numba", "numpy"])
def test_collapse_is_recovered_never_nan(backend):
    cfg = quiet_config(n_particles=300, backend=backend, init_position_sigma_m=0.1)
    tracker = Tracker(block_map(), cfg, seed=0)
    tracker.start_at_pose(0.0, X0 + 20.0, Y0 + 8.0)
    fix = GnssFix(X0 + 20.0, Y0 + 2.0, 4.0)
    est = tracker.step(1.0, displacement_en=(0.0, 20.0), gnss_fix=fix)  # every particle into the building
    assert est.recovered and tracker.recoveries == 1
    assert math.isfinite(est.x) and math.isfinite(est.y) and math.isfinite(est.n_eff)
    codes = tracker.map_likelihood.raster.codes_at(tracker.particles.x, tracker.particles.y)
    assert not (codes == BUILDING).any()
    est = tracker.step(2.0, displacement_en=(0.5, 0.0), gnss_fix=fix)
    assert not est.recovered


def test_everything_in_buildings_even_after_reseeding_gives_uniform_weights():
    def box(x0, y0, x1, y1):
        return shapely.box(X0 + x0, Y0 + y0, X0 + x1, Y0 + y1)

    gdf = gpd.GeoDataFrame({"class": ["building"]}, geometry=[box(-500, -500, 500, 500)], crs=UTM10)
    tracker = Tracker(MapLayers(gdf), quiet_config(n_particles=50), seed=0)
    tracker.particles.x[:] = X0
    tracker.particles.y[:] = Y0
    tracker.started = True
    est = tracker.step(1.0, displacement_en=(1.0, 0.0))
    assert est.recovered and math.isfinite(est.x) and est.n_eff == pytest.approx(50)


def test_start_pose_in_a_building_moves_to_the_nearest_free_cell(caplog):
    tracker = Tracker(block_map(), FilterConfig(n_particles=200, init_position_sigma_m=0.3), seed=0)
    est = tracker.start_at_pose(0.0, X0 + 20.0, Y0 + 12.0)
    assert "inside a building" in caplog.text
    assert est.y < Y0 + 10.0
    with pytest.raises(CurbsideInputError, match="inside a building"):
        Tracker(block_map(), FilterConfig(max_start_snap_m=5.0), seed=0).start_at_pose(0.0, X0, Y0 + 35.0)


def _run_tracker(backend: str, seed: int, steps: int = 60, **kw) -> tuple[list, Tracker]:
    cfg = FilterConfig(n_particles=400, backend=backend, scale_init_sigma=0.05, scale_noise_per_step=0.002,
                       **kw)
    tracker = Tracker(block_map(), cfg, seed=seed)
    out = [tracker.start_at_pose(0.0, X0 - 60.0, Y0 + 8.0, 0.05)]
    for k in range(1, steps):
        fix = GnssFix(X0 - 60.0 + 1.2 * k, Y0 + 3.0, 8.0) if k % 2 else None
        out.append(tracker.step(0.5 * k, velocity_en=(2.4, 0.1), dt=0.5, gnss_fix=fix))
    return out, tracker


@pytest.mark.parametrize("gnss", [{}, {"gnss_outlier_prob": 0.1, "gnss_error_correlation_s": 10.0},
                                  {"gnss_bias_sigma_m": 6.0, "gnss_bias_time_s": 20.0}])
def test_numba_and_numpy_paths_agree(gnss):
    fast, tf = _run_tracker("numba", seed=4, **gnss)
    ref, tr = _run_tracker("numpy", seed=4, **gnss)
    np.testing.assert_allclose([e.x for e in fast], [e.x for e in ref], rtol=0, atol=1e-6)
    np.testing.assert_allclose([e.n_eff for e in fast], [e.n_eff for e in ref], rtol=1e-9)
    np.testing.assert_allclose(tf.particles.x, tr.particles.x, rtol=0, atol=1e-6)
    np.testing.assert_allclose(tf.particles.theta, tr.particles.theta, rtol=0, atol=1e-9)
    np.testing.assert_allclose(tf.particles.scale, tr.particles.scale, rtol=0, atol=1e-9)
    np.testing.assert_allclose([e.scale for e in fast], [e.scale for e in ref], rtol=1e-9)
    np.testing.assert_allclose(tf.particles.bias_x, tr.particles.bias_x, rtol=0, atol=1e-9)


def test_same_seed_same_estimates_and_particles_stay_off_buildings():
    a, ta = _run_tracker("numba", seed=9)
    b, _ = _run_tracker("numba", seed=9)
    c, _ = _run_tracker("numba", seed=10)
    assert [(e.x, e.y, e.theta) for e in a] == [(e.x, e.y, e.theta) for e in b]
    assert [e.x for e in a] != [e.x for e in c]
    codes = ta.map_likelihood.raster.codes_at(ta.particles.x, ta.particles.y)
    assert not (codes == BUILDING).any()
    assert all(Y0 < e.y < Y0 + 10 for e in a)  # the fixes at y=3 pull, the building stops at y=10


def test_fix_starts_an_unstarted_tracker_with_theta_over_the_full_circle():
    tracker = Tracker(None, FilterConfig(n_particles=2000), seed=1)
    assert tracker.step(0.0, displacement_en=(0.0, 0.0)) is None
    fix = tracker.fix(37.79, -122.40, 5.0)
    est = tracker.step(0.5, displacement_en=(0.0, 0.0), gnss_fix=fix)
    sigma = tracker.config.gnss_sigma_factor * 5.0
    assert est is not None and math.hypot(est.x - fix.x, est.y - fix.y) < 4 * sigma / math.sqrt(2000)
    assert abs(est.lat - 37.79) < 1e-5 and abs(est.lon + 122.40) < 1e-5
    counts, _ = np.histogram(tracker.particles.theta, bins=4, range=(-math.pi, math.pi))
    assert counts.min() > 350


def test_config_rejects_bad_values():
    for kw in ({"jaywalk_weight": 1.5}, {"n_particles": 0}, {"resample": "never"}, {"backend": "cuda"},
               {"gnss_outlier_prob": 1.0}, {"gnss_outlier_radius_m": 0.0},
               {"gnss_error_correlation_s": -1.0}, {"gnss_bias_sigma_m": -1.0}, {"gnss_bias_time_s": 0.0}):
        with pytest.raises(ValueError):
            FilterConfig(**kw)


# -- posterior mode over sidewalk segments -------------------------------------------------------------


def two_sidewalk_map() -> MapLayers:
    """A street along x with a sidewalk on each side: "N" (6 < y < 10) and "S" (-10 < y < -6)."""
    bands = ((-6, 6), (6, 10), (-10, -6), (40, 45))
    geoms = [shapely.box(X0 - 100, Y0 + y0, X0 + 100, Y0 + y1) for y0, y1 in bands]
    gdf = gpd.GeoDataFrame(
        {"class": ["street", "sidewalk", "sidewalk", "building"], "segment_id": [None, "N", "S", None],
         "street": None, "side": None},
        geometry=geoms, crs=UTM10,
    )
    return MapLayers(gdf)


def test_segment_raster_holds_the_nearest_sidewalk_within_reach(monkeypatch):
    monkeypatch.setattr(settings, "segment_raster_max_distance_m", 25.0)
    layers = two_sidewalk_map()
    raster = rasterize_map(layers, 0.5)
    ids = raster.segment_ids
    assert sorted(ids.tolist()) == ["N", "S"]
    ys = Y0 + np.array([8.0, 0.5, -0.5, -8.0, 30.0, 36.0, 44.0])
    got = raster.segments_at(np.full(len(ys), X0), ys)
    expected = [ids.tolist().index(s) if s else -1 for s in ("N", "N", "S", "S", "N", None, None)]
    assert got.tolist() == expected
    assert raster.segments_at(np.array([X0 + 500.0]), np.array([Y0]))[0] == -1  # outside the grid
    # Against shapely's nearest polygon wherever the two sidewalks are not nearly equidistant.
    rng = np.random.default_rng(0)
    x, y = X0 + rng.uniform(-99, 99, 2000), Y0 + rng.uniform(-9.9, 44.9, 2000)
    sidewalks = layers.layer("sidewalk")
    dist = np.stack([shapely.distance(g, shapely.points(x, y)) for g in sidewalks.geometry.values])
    nearest = np.where(dist.min(axis=0) <= 24.0, dist.argmin(axis=0), -1)
    clear = (np.abs(dist[0] - dist[1]) > 1.0) & (np.abs(dist.min(axis=0) - 25.0) > 1.0)
    names = np.append(sidewalks["segment_id"].to_numpy(), None)
    got = raster.segments_at(x, y)
    assert clear.sum() > 1500
    assert (np.append(ids, None)[got][clear] == names[nearest][clear]).all()


def test_segment_raster_is_cached_and_a_map_without_sidewalks_has_none():
    layers = two_sidewalk_map()
    first = load_or_build_raster(layers, 1.0)
    second = load_or_build_raster(layers, 1.0)
    np.testing.assert_array_equal(first.segment_index, second.segment_index)
    np.testing.assert_array_equal(first.segment_ids, second.segment_ids)
    no_sidewalks = MapLayers(layers.gdf[layers.gdf["class"] != "sidewalk"])
    raster = load_or_build_raster(no_sidewalks, 1.0)
    assert raster.segment_index is None
    assert raster.segments_at(np.array([X0]), np.array([Y0 + 8.0])).tolist() == [-1]
    assert map_hash(no_sidewalks, 1.0) != map_hash(layers, 1.0)


@pytest.mark.parametrize("backend", ["numba", "numpy"])
def test_bimodal_cloud_mode_is_on_the_heavier_sidewalk_while_the_mean_is_mid_street(backend):
    tracker = Tracker(two_sidewalk_map(), quiet_config(n_particles=500, backend=backend), seed=0)
    tracker.start_at_pose(0.0, X0, Y0 + 8.0)
    p = tracker.particles
    rng = np.random.default_rng(1)
    north = np.arange(500) < 250
    p.x[:] = X0 + rng.uniform(-20, 20, 500)
    p.y[:] = np.where(north, Y0 + 8.0, Y0 - 8.0) + rng.uniform(-1, 1, 500)
    p.log_weight[:] = np.where(north, math.log(0.6), math.log(0.4))
    weights = np.where(north, 0.6, 0.4)
    mean_y, mode_x, mode_y = np.average(p.y, weights=weights), p.x[north].mean(), p.y[north].mean()
    est = tracker.step(0.5, displacement_en=(0.0, 0.0))  # no motion, no noise: the cloud stays
    assert est.segment_id == "N"
    assert est.segment_prob == pytest.approx(0.6)
    assert (est.mode_x, est.mode_y) == (pytest.approx(mode_x), pytest.approx(mode_y))
    assert 6.0 < est.mode_y - Y0 < 10.0  # on the north sidewalk
    assert est.y == pytest.approx(mean_y) and -6.0 < est.y - Y0 < 6.0  # the mean: in the street
    off = Tracker(two_sidewalk_map(), quiet_config(n_particles=500, backend=backend, segment_estimate=False))
    est_off = off.start_at_pose(0.0, X0, Y0 + 8.0)
    assert est_off.segment_id is None and math.isnan(est_off.segment_prob)
    assert (est_off.mode_x, est_off.mode_y) == (est_off.x, est_off.y)


def _run_two_sidewalks(backend: str, seed: int) -> list:
    cfg = FilterConfig(n_particles=400, backend=backend, init_position_sigma_m=8.0)
    tracker = Tracker(two_sidewalk_map(), cfg, seed=seed)
    out = [tracker.start_at_pose(0.0, X0 - 60.0, Y0, 0.0)]  # mid-street: the cloud spans both sides
    for k in range(1, 80):
        # Fixes mid-street, one side or the other by 1 m: which sidewalk wins is up to the draws.
        fix = GnssFix(X0 - 60.0 + 1.2 * k, Y0 + (-1.0) ** k, 5.0)
        out.append(tracker.step(0.5 * k, velocity_en=(2.4, 0.0), dt=0.5, gnss_fix=fix))
    return out


def test_numba_and_numpy_segment_modes_agree():
    fast, ref = _run_two_sidewalks("numba", 5), _run_two_sidewalks("numpy", 5)
    assert [e.segment_id for e in fast] == [e.segment_id for e in ref]
    assert {e.segment_id for e in fast} == {"N", "S"}
    np.testing.assert_allclose([e.segment_prob for e in fast], [e.segment_prob for e in ref], atol=1e-9)
    np.testing.assert_allclose([e.mode_x for e in fast], [e.mode_x for e in ref], rtol=0, atol=1e-6)
    np.testing.assert_allclose([e.mode_y for e in fast], [e.mode_y for e in ref], rtol=0, atol=1e-6)
    probs = np.array([e.segment_prob for e in fast])
    assert ((probs > 0) & (probs <= 1 + 1e-12)).all() and (probs < 0.99).any()
