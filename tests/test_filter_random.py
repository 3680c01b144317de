"""The kernels' random streams (xoshiro256++ and the ziggurat) and their vectorisable math."""

from __future__ import annotations

import math

import numba
import numpy as np
import pytest
from scipy import stats

from curbside.localize.filter import FilterConfig, Tracker
from curbside.localize.filter.kernelmath import LIMIT, exp, logaddexp, sincos
from curbside.localize.filter.random import (
    LAYERS,
    Stream,
    draw_random,
    draw_standard_normal,
    load,
    next_uint64,
    store,
    ziggurat_tables,
)


@pytest.fixture(scope="module")
def million_normals() -> np.ndarray:
    return Stream(np.random.default_rng(12345)).standard_normal(1_000_000)


def test_normals_pass_a_ks_test_and_have_the_normal_moments(million_normals):
    z = million_normals
    assert stats.kstest(z, "norm").pvalue > 1e-3
    assert abs(z.mean()) < 5 / 1000 and abs(z.std() - 1) < 5 / 1000
    assert abs(stats.skew(z)) < 0.01 and abs(stats.kurtosis(z)) < 0.02


@pytest.mark.parametrize("k", [1.0, 2.0, 3.0, 3.6541528853610088, 4.0, 4.5])
def test_tail_frequencies_match_the_normal_beyond_the_base_layer_too(million_normals, k):
    # 3.654 is the ziggurat's base-layer edge: beyond it every draw comes from the exact tail sampler.
    n = len(million_normals)
    p = 2 * stats.norm.sf(k)
    count = int(np.sum(np.abs(million_normals) > k))
    assert stats.binomtest(count, n, p).pvalue > 1e-4, (k, count, n * p)


def test_signs_and_layers_are_balanced(million_normals):
    z = million_normals
    assert stats.binomtest(int(np.sum(z > 0)), len(z), 0.5).pvalue > 1e-4
    # Equal-probability bins of the normal: a chi-square test over 200 bins sees every layer's shape.
    edges = stats.norm.ppf(np.linspace(0, 1, 201))
    counts, _ = np.histogram(z, edges)
    assert stats.chisquare(counts).pvalue > 1e-4


def test_uniforms_are_uniform_on_the_unit_interval():
    u = Stream(np.random.default_rng(7)).random(1_000_000)
    assert u.min() >= 0.0 and u.max() < 1.0
    assert stats.kstest(u, "uniform").pvalue > 1e-3


def test_ziggurat_layers_have_equal_areas_and_close_at_the_top():
    k, w, f = ziggurat_tables()
    x = w * 2.0**52
    v = x[1] * f[1] + math.sqrt(math.pi / 2) * math.erfc(x[1] / math.sqrt(2))  # base box + tail
    areas = x[1:LAYERS] * (f[2 : LAYERS + 1] - f[1:LAYERS])  # layers 1..255: width x_i, height step
    np.testing.assert_allclose(areas, v, rtol=1e-9)
    assert x[0] * f[1] == pytest.approx(v)  # the base layer's pseudo-width
    assert f[LAYERS] == 1.0 and k[-1] == 0  # the top layer: always the wedge test
    assert np.all(np.diff(x[1:LAYERS]) < 0) and np.all(k[:-1] > 0)


def test_same_seed_same_stream_and_the_copy_replays_it():
    a, b = Stream(np.random.default_rng(3)), Stream(np.random.default_rng(3))
    replay = a.copy()
    first = a.standard_normal(1000)
    np.testing.assert_array_equal(first, b.standard_normal(1000))
    np.testing.assert_array_equal(first, [draw_standard_normal(replay.state) for _ in range(1000)])
    assert not np.array_equal(a.standard_normal(1000), first)  # the stream moved on


def test_streams_of_one_generator_are_distinct_and_uncorrelated():
    rng = np.random.default_rng(0)
    a, b = Stream(rng), Stream(rng)
    assert not np.array_equal(a.state, b.state)
    za, zb = a.standard_normal(200_000), b.standard_normal(200_000)
    assert abs(np.corrcoef(za, zb)[0, 1]) < 5 / math.sqrt(200_000)
    assert abs(np.corrcoef(za[1:], za[:-1])[0, 1]) < 5 / math.sqrt(200_000)  # no lag-1 correlation


def test_two_trackers_with_one_seed_draw_alike_and_never_share_state():
    one, two = (Tracker.from_config(None, FilterConfig(n_particles=10), seed=5) for _ in range(2))
    streams = [t.predictor.stream.state for t in (one, two)] + [t.resampler.stream.state for t in (one, two)]
    np.testing.assert_array_equal(streams[0], streams[1])
    assert len({id(s) for s in streams}) == 4
    assert not np.array_equal(streams[0], streams[2])  # predictor and resampler: different streams


def _xoshiro256pp_reference(s: list[int], k: int) -> list[int]:
    """The reference C code (prng.di.unimi.it/xoshiro256plusplus.c), in Python integers."""
    mask = 2**64 - 1

    def rotl(x: int, r: int) -> int:
        return ((x << r) | (x >> (64 - r))) & mask

    out = []
    for _ in range(k):
        out.append((rotl((s[0] + s[3]) & mask, 23) + s[0]) & mask)
        t = (s[1] << 17) & mask
        s[2] ^= s[0]
        s[3] ^= s[1]
        s[1] ^= s[2]
        s[0] ^= s[3]
        s[2] ^= t
        s[3] = rotl(s[3], 45)
    return out


def test_xoshiro256pp_matches_the_reference_code():
    @numba.njit
    def first(state, k):
        s = load(state)
        out = np.empty(k, np.uint64)
        for i in range(k):
            out[i], s = next_uint64(s)
        return out

    seed = [1, 2, 3, 4]
    got = first(np.array(seed, dtype=np.uint64), 1000).tolist()
    assert got[0] == 41943041  # rotl(1 + 4, 23) + 1
    assert got == _xoshiro256pp_reference(seed, 1000)
    random_seed = Stream(np.random.default_rng(9)).state
    assert first(random_seed.copy(), 1000).tolist() == _xoshiro256pp_reference(random_seed.tolist(), 1000)


def test_state_round_trips_through_load_and_store():
    @numba.njit
    def bump(state):
        s = load(state)
        _, s = next_uint64(s)
        store(state, s)

    state = np.array([1, 2, 3, 4], dtype=np.uint64)
    bump(state)
    assert state.tolist() != [1, 2, 3, 4] and state.dtype == np.uint64
    assert 0.0 <= draw_random(state) < 1.0


# -- kernelmath -----------------------------------------------------------------------------------------


@numba.njit(error_model="numpy")
def _apply_sincos(x, s, c):
    for i in range(x.shape[0]):
        s[i], c[i] = sincos(x[i])


@numba.njit(error_model="numpy")
def _apply_exp(x, out):
    for i in range(x.shape[0]):
        out[i] = exp(x[i])


@numba.njit(error_model="numpy")
def _apply_logaddexp(x, c, out):
    for i in range(x.shape[0]):
        out[i] = logaddexp(x[i], c)


def _ulps(got: np.ndarray, want: np.ndarray) -> float:
    return float(np.max(np.where(got == want, 0.0, np.abs(got - want) / np.spacing(np.abs(want)))))


@pytest.mark.parametrize("scale", [1e-9, 0.01, 0.5, 4.0, 300.0])
def test_sincos_is_within_an_ulp_of_the_c_library(scale):
    x = np.random.default_rng(1).normal(0, scale, 200_000)
    x = x[np.abs(x) < LIMIT]
    s, c = np.empty_like(x), np.empty_like(x)
    _apply_sincos(x, s, c)
    assert _ulps(s, np.sin(x)) <= 1 and _ulps(c, np.cos(x)) <= 1


def test_sincos_at_quadrant_boundaries():
    x = np.array([0.0, -0.0, math.pi / 4, math.pi / 2, math.pi, -math.pi / 2, 3 * math.pi / 4, 7.0, 1000.0])
    s, c = np.empty_like(x), np.empty_like(x)
    _apply_sincos(x, s, c)
    np.testing.assert_allclose(s, np.sin(x), rtol=0, atol=2e-16)
    np.testing.assert_allclose(c, np.cos(x), rtol=0, atol=2e-16)


@pytest.mark.parametrize(("lo", "hi"), [(-745.1, 709.0), (-1.0, 1.0), (-1e-12, 1e-12), (-745.1, -705.0)])
def test_exp_is_within_an_ulp_of_the_c_library_subnormals_included(lo, hi):
    x = np.random.default_rng(2).uniform(lo, hi, 200_000)
    out = np.empty_like(x)
    _apply_exp(x, out)
    assert _ulps(out, np.exp(x)) <= 1


def test_exp_edge_cases():
    x = np.array([-math.inf, -1e300, -746.0, -745.2, 0.0, -0.0, math.nan])
    out = np.empty_like(x)
    _apply_exp(x, out)
    np.testing.assert_array_equal(out[:6], [0.0, 0.0, 0.0, 0.0, 1.0, 1.0])
    assert math.isnan(out[6])


@pytest.mark.parametrize("c", [-12.0, 3.0, -math.inf])
def test_logaddexp_matches_numpy(c):
    x = np.concatenate([np.random.default_rng(3).uniform(-800, 50, 200_000), [c, -math.inf, 0.0]])
    out = np.empty_like(x)
    _apply_logaddexp(x, c, out)
    want = np.logaddexp(x, c)
    finite = np.isfinite(want)
    assert _ulps(out[finite], want[finite]) <= 1
    np.testing.assert_array_equal(out[~finite], want[~finite])  # -inf with -inf stays -inf
    assert math.isnan(logaddexp(math.nan, c))
