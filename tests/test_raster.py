"""The map raster: scanline rasterisation, class precedence, building depth, segments, the disk cache."""

from __future__ import annotations

import numpy as np
import pytest
import shapely
from filter_maps import X0, Y0, block_map, box, shifted_building_map, two_sidewalk_map

from curbside import settings
from curbside.localize import raster as raster_mod
from curbside.localize.filter.kernelmath import cell_indices
from curbside.localize.raster import (
    BUILDING,
    CROSSWALK,
    FREE,
    SIDEWALK,
    STREET,
    RasterLookup,
    building_depth_m,
    load_or_build_raster,
    map_hash,
    rasterize_map,
    rasterize_mask,
)
from curbside.osmseg.mapio import MapLayers


@pytest.fixture(autouse=True)
def _cache_in_tmp(tmp_path, monkeypatch):
    monkeypatch.setattr(settings, "cache_dir", tmp_path / "cache")


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
    assert codes[[0, 1, 2, 4, 5]].tolist() == [STREET, CROSSWALK, SIDEWALK, FREE, FREE]
    assert codes[3] >= BUILDING


def test_compiled_cell_indices_match_the_numpy_index_math_on_and_off_the_map():
    lookup = RasterLookup(rasterize_map(block_map(), 0.5))
    rng = np.random.default_rng(5)
    state = np.zeros((2, 400))
    state[0] = X0 + rng.uniform(-150, 150, 400)  # the map spans -100..100 by -6..60 m: a third on it,
    state[1] = Y0 + rng.uniform(-30, 90, 400)  # the rest beyond it on every side
    cells = cell_indices(state, lookup.index_grid)
    np.testing.assert_array_equal(cells, lookup.flat_indices(state[0], state[1]))
    assert (cells >= 0).all() and (cells < lookup.padded.size).all()
    assert (lookup.padded[cells] == lookup.codes_at(state[0], state[1])).all()


def test_building_cells_record_their_depth_past_the_wall():
    raster = rasterize_map(block_map(), 0.5)  # the building starts at y = 10
    ys = Y0 + np.array([10.1, 10.6, 12.2, 20.0])
    depth = building_depth_m(raster.codes_at(np.full(4, X0 + 20.0), ys), 0.5)
    np.testing.assert_allclose(depth, ys - Y0 - 10.0, atol=0.26)
    assert np.isnan(building_depth_m(SIDEWALK, 0.5))


def test_raster_is_cached_on_disk_and_reused(monkeypatch):
    layers = block_map()
    first = load_or_build_raster(layers, 1.0)
    cached = list((settings.cache_dir / "rasters").glob("*.npz"))
    assert [p.stem for p in cached] == [map_hash(layers, 1.0, 25.0)]

    def fail(*args, **kwargs):
        raise AssertionError("rasterised again despite the cache")

    monkeypatch.setattr(raster_mod, "rasterize_map", fail)
    second = load_or_build_raster(layers, 1.0)
    np.testing.assert_array_equal(first.codes, second.codes)
    assert (second.x0, second.y0, second.resolution_m) == (first.x0, first.y0, first.resolution_m)
    assert map_hash(layers, 0.5, 25.0) != map_hash(layers, 1.0, 25.0) != map_hash(layers, 1.0, 20.0)


def test_raster_measures_the_share_of_sidewalk_under_buildings():
    assert rasterize_map(block_map(), 0.5).sidewalk_under_buildings == 0.0  # disjoint classes
    layers = shifted_building_map()  # the building covers the sidewalk's northern 2 of 4 m
    assert rasterize_map(layers, 0.5).sidewalk_under_buildings == pytest.approx(0.5, abs=0.01)
    built = load_or_build_raster(layers, 0.5)
    assert load_or_build_raster(layers, 0.5).sidewalk_under_buildings == built.sidewalk_under_buildings > 0.4


def test_sidewalks_and_crosswalks_over_buildings_where_they_overlap():
    assert rasterize_map(block_map(), 0.5).walkable_first_cells is None  # disjoint: nothing to patch
    layers = block_map()
    layers.gdf.loc[layers.gdf["class"] == "building", "geometry"] = box(-100, 4, 100, 60)  # 6 m too far south
    built = rasterize_map(layers, 0.5)
    first = built.walkable_first
    assert built.walkable_first is first and first.walkable_first is first  # made once, shared
    xs, ys = X0 + np.array([50.0, 0.0, 50.0, 50.0]), Y0 + np.array([8.0, 5.0, 5.0, 10.75])
    assert (built.codes_at(xs, ys) >= BUILDING).all()
    assert first.codes_at(xs, ys)[:2].tolist() == [SIDEWALK, CROSSWALK]
    assert first.codes_at(xs, ys)[2] >= BUILDING  # a street under a building stays a building (a deck)
    depth = building_depth_m(np.array([built.codes_at(xs, ys)[3], first.codes_at(xs, ys)[3]]), 0.5)
    np.testing.assert_allclose(depth, [6.75, 0.75], atol=0.26)  # walls measured from the sidewalk's edge
    load_or_build_raster(layers, 0.5)
    cached = load_or_build_raster(layers, 0.5)  # read back from the disk cache
    np.testing.assert_array_equal(cached.walkable_first.codes, first.codes)


def test_nearest_free_cell_from_inside_a_building():
    raster = rasterize_map(block_map(), 0.5)
    snapped = raster.nearest_free(X0 + 20.0, Y0 + 13.0, 30.0)
    assert snapped is not None
    assert raster.codes_at(np.array([snapped[0]]), np.array([snapped[1]]))[0] < BUILDING
    assert abs(snapped[1] - (Y0 + 9.75)) < 1e-9
    assert raster.nearest_free(X0 + 20.0, Y0 + 35.0, 10.0) is None


def test_segment_raster_holds_the_nearest_sidewalk_within_reach():
    layers = two_sidewalk_map()
    raster = rasterize_map(layers, 0.5, segment_reach_m=25.0)
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
    assert map_hash(no_sidewalks, 1.0, 25.0) != map_hash(layers, 1.0, 25.0)
