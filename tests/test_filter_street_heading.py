"""The street-heading likelihood: kernel against its oracle, normalisation, gates, wiring."""

from __future__ import annotations

import math

import geopandas as gpd
import numpy as np
import pytest
from filter_maps import UTM10, X0, Y0, box, two_sidewalk_map
from hypothesis import given, settings
from hypothesis import strategies as st

from curbside.localize.filter import FilterConfig, ParticleSet, StreetHeadingLikelihood, Tracker, Update
from curbside.localize.filter.config import StreetHeadingConfig
from curbside.localize.filter.street_heading import reference_log_likelihood
from curbside.localize.raster import rasterize_map
from curbside.localize.runconfig import RunConfig
from curbside.osmseg.mapio import MapLayers

ON = StreetHeadingConfig(strength_per_m=2.0, max_turn_deg=90.0)  # no turn gate: the kernel alone


@pytest.fixture(scope="module")
def street_raster():
    """Two sidewalks along x (axis east-west): ``N`` at 6 < y < 10 and ``S`` at -10 < y < -6."""
    return rasterize_map(two_sidewalk_map())


def corner_raster():
    """An east-west sidewalk ``N`` and a north-south one ``E`` that do not touch."""
    gdf = gpd.GeoDataFrame(
        {"class": ["sidewalk", "sidewalk"], "segment_id": ["N", "E"], "street": None, "side": None},
        geometry=[box(-100, 6, 0, 10), box(30, 20, 34, 120)],
        crs=UTM10,
    )
    return rasterize_map(MapLayers(gdf))


def cloud(x: np.ndarray, y: np.ndarray, theta: np.ndarray) -> ParticleSet:
    """Particles at ``(X0 + x, Y0 + y)`` with heading offsets ``theta`` and uniform weights."""
    particles = ParticleSet(len(x))
    particles.x[:] = X0 + x
    particles.y[:] = Y0 + y
    particles.set_heading(np.asarray(theta, float))
    return particles


def test_the_kernel_matches_its_oracle_on_a_sidewalk(street_raster):
    rng = np.random.default_rng(3)
    n = 400
    theta = rng.uniform(-math.pi, math.pi, n)
    particles = cloud(rng.uniform(-50, 50, n), rng.uniform(6.5, 9.5, n), theta)
    before = particles.log_weight.copy()
    part = StreetHeadingLikelihood(street_raster, ON)
    part.weigh(particles, Update(1.0, 0.5, 0.6, 0.3))
    assert part.last_axis is not None and abs(part.last_axis[1]) < 1e-9  # east-west
    expected = reference_log_likelihood(theta, 0.6, 0.3, part.last_axis, ON)
    np.testing.assert_allclose(particles.log_weight - before, expected, atol=1e-9)


def test_along_the_street_either_way_beats_across(street_raster):
    # The step points north-east; offsets that turn it east or west are alike, north is worst.
    step = (0.5, 0.5)
    offsets = np.array([-math.pi / 4, 3 * math.pi / 4, math.pi / 4, 0.0])  # east, west, north, diagonal
    particles = cloud(np.zeros(4), np.full(4, 8.0), offsets)
    StreetHeadingLikelihood(street_raster, ON).weigh(particles, Update(1.0, 0.5, *step))
    east, west, north, diagonal = particles.log_weight
    assert east == pytest.approx(west)
    assert east > diagonal > north


@settings(max_examples=30, deadline=None)
@given(kappa_per_m=st.floats(0.1, 20.0), floor=st.floats(0.01, 0.9), step_m=st.floats(0.2, 2.0))
def test_the_density_over_headings_averages_one(kappa_per_m, floor, step_m):
    # Normalised: a sidewalk is no worse a place to be than anywhere the term does not reach.
    config = StreetHeadingConfig(strength_per_m=kappa_per_m, floor=floor)
    theta = np.linspace(-math.pi, math.pi, 20001)[:-1]
    weights = np.exp(reference_log_likelihood(theta, step_m, 0.0, (1.0, 0.0), config))
    assert weights.mean() == pytest.approx(1.0, rel=1e-6)


def test_no_term_off_the_sidewalk_at_a_corner_or_standing_still(street_raster):
    part = StreetHeadingLikelihood(street_raster, ON)
    rng = np.random.default_rng(0)
    theta = rng.uniform(-1, 1, 200)
    in_street = cloud(rng.uniform(-50, 50, 200), rng.uniform(-5, 5, 200), theta)
    part.weigh(in_street, Update(1.0, 0.5, 0.7, 0.0))
    assert part.last_axis is None and np.all(in_street.log_weight == -math.log(200))
    standing = cloud(rng.uniform(-50, 50, 200), rng.uniform(6.5, 9.5, 200), theta)
    part.weigh(standing, Update(1.0, 0.5, 0.1, 0.0))  # under min_step_m
    assert part.last_axis is None and np.all(standing.log_weight == -math.log(200))
    corner = StreetHeadingLikelihood(corner_raster(), ON)
    x = np.r_[np.full(100, -20.0), np.full(100, 32.0)]
    y = np.r_[np.full(100, 8.0), np.full(100, 60.0)]
    split = cloud(x, y, theta)
    corner.weigh(split, Update(1.0, 0.5, 0.7, 0.0))
    assert corner.last_axis is None and np.all(split.log_weight == -math.log(200))


def test_no_term_while_the_cloud_turns_off_the_street(street_raster):
    # On the east-west sidewalk, offsets near 0: a step east is along the street, one north-east
    # (45 deg) or north (a turn at the corner) is not, and with a 30 deg gate weighs nothing.
    gated = StreetHeadingLikelihood(street_raster, StreetHeadingConfig(strength_per_m=2.0, max_turn_deg=30.0))
    rng = np.random.default_rng(1)
    theta = rng.normal(0.0, math.radians(5), 300)
    for step, applies in [((0.7, 0.0), True), ((-0.7, 0.1), True), ((0.5, 0.5), False), ((0.0, 0.7), False)]:
        particles = cloud(rng.uniform(-50, 50, 300), rng.uniform(6.5, 9.5, 300), theta)
        gated.weigh(particles, Update(1.0, 0.5, *step))
        assert (gated.last_axis is not None) == applies, step
        assert np.all(particles.log_weight == -math.log(300)) != applies, step
    # the offsets count: a cloud turned by -45 deg walks a north-east step along the street
    turned = cloud(rng.uniform(-50, 50, 300), rng.uniform(6.5, 9.5, 300), theta - math.pi / 4)
    gated.weigh(turned, Update(1.0, 0.5, 0.5, 0.5))
    assert gated.last_axis is not None
    # without the gate (90 deg) the turning step is weighed, as before
    ungated = StreetHeadingLikelihood(street_raster, ON)
    particles = cloud(rng.uniform(-50, 50, 300), rng.uniform(6.5, 9.5, 300), theta)
    ungated.weigh(particles, Update(1.0, 0.5, 0.0, 0.7))
    assert ungated.last_axis is not None


def test_the_tracker_adds_the_part_unless_turned_off(street_raster):
    def parts(config: FilterConfig) -> list[type]:
        return [type(lik) for lik in Tracker.from_config(street_raster, config, seed=0).likelihoods]

    assert StreetHeadingLikelihood in parts(FilterConfig())  # on by default since stop 31
    assert StreetHeadingLikelihood not in parts(FilterConfig.preset("paper"))
    off = StreetHeadingConfig(strength_per_m=0.0)
    assert StreetHeadingLikelihood not in parts(FilterConfig(street_heading=off))
    # and from a run's settings, as --set gives them
    run = RunConfig.for_mode("fused").with_overrides({"filter.street_heading.strength_per_m": 0.0})
    assert StreetHeadingLikelihood not in parts(run.filter)


def test_a_biased_heading_is_learned_along_a_sidewalk(street_raster):
    # The inertial heading reads 25 degrees left of the street; the particles' offsets start spread.
    rng = np.random.default_rng(5)
    n = 2000
    particles = cloud(rng.uniform(-50, 50, n), rng.uniform(6.5, 9.5, n), rng.normal(0, math.radians(30), n))
    part = StreetHeadingLikelihood(street_raster, ON)
    bias = math.radians(25)
    for k in range(30):
        part.weigh(particles, Update(k * 0.5, 0.5, 0.7 * math.cos(bias), 0.7 * math.sin(bias)))
    w = np.exp(particles.log_weight - particles.log_weight.max())
    sin_sum, cos_sum = np.sum(w * np.sin(particles.theta)), np.sum(w * np.cos(particles.theta))
    mean_offset = math.degrees(math.atan2(sin_sum, cos_sum))
    assert mean_offset == pytest.approx(-25, abs=4)


def test_bad_settings_are_refused():
    with pytest.raises(ValueError, match="floor"):
        StreetHeadingConfig(floor=0.0)
    with pytest.raises(ValueError, match="strength_per_m"):
        StreetHeadingConfig(strength_per_m=-1.0)
    with pytest.raises(ValueError, match="min_sidewalk_share"):
        StreetHeadingConfig(min_sidewalk_share=1.5)
