"""A block side reaches out to its mapped sidewalk ray by ray, not with one distance per side.

Stop 53 took the median over a side's rays, and only where at least half of them met a mapped
sidewalk: a sidewalk that swings out along part of the block, or one mapped along only part of it,
stayed partly or wholly outside the band. The scenes are a straight residential street 8 m wide along
y = 0 (x from -100 to 100 m: curb 4 m, usual band 9 m from the centreline) with ways north of it.
"""

from __future__ import annotations

import functools
from pathlib import Path

import geopandas as gpd
import numpy as np
import pytest
import shapely
import shapely.ops

from curbside.osmseg import reach, sidewalks
from curbside.osmseg.build import build_map
from curbside.osmseg.mapio import MapLayers
from curbside.osmseg.streets import ray_origins

LON0, LAT0 = 13.4000, 52.5200
M_PER_DEG_LAT = 111_320.0
M_PER_DEG_LON = 111_320.0 * np.cos(np.radians(LAT0))
SIDEWALK = {"highway": "footway", "footway": "sidewalk"}
MAIN = {"highway": "residential", "name": "Main Street", "width": "8"}


def _lonlat(x_m: float, y_m: float) -> tuple[float, float]:
    return LON0 + x_m / M_PER_DEG_LON, LAT0 + y_m / M_PER_DEG_LAT


def scene(path: Path, ways: list[tuple[list[tuple[float, float]], dict[str, str]]]) -> Path:
    """An OSM file of Main Street along y = 0 and ``ways`` (points in metres east and north, tags)."""
    nodes, refs = [], []
    for points, _ in [([(-100, 0), (100, 0)], MAIN), *ways]:
        refs.append(list(range(len(nodes) + 1, len(nodes) + len(points) + 1)))
        nodes += points
    xml = "".join(
        f'<node id="{i}" version="1" lat="{lat:.8f}" lon="{lon:.8f}"/>'
        for i, (lon, lat) in enumerate((_lonlat(*p) for p in nodes), start=1)
    )
    for way_id, (ids, (_, tags)) in enumerate(zip(refs, [([], MAIN), *ways], strict=True), start=10):
        closed = ids + [ids[0]] if tags.get("building") else ids
        xml += f'<way id="{way_id}" version="1">' + "".join(f'<nd ref="{r}"/>' for r in closed)
        xml += "".join(f'<tag k="{k}" v="{v}"/>' for k, v in tags.items()) + "</way>"
    path.write_text(f'<?xml version="1.0"?><osm version="0.6">{xml}</osm>')
    return path


def north_area_m2(layers: MapLayers, x0_m: float, x1_m: float, y_m: float) -> float:
    """Area of Main Street's north sidewalk north of ``y_m`` between x = ``x0_m`` and ``x1_m``."""
    gdf = layers.gdf
    main_north = gdf["segment_id"].fillna("").str.match(r"w10-\d+-L").to_numpy()
    north = shapely.union_all(gdf.geometry.values[main_north])
    corners = [_lonlat(x, y) for x, y in ((x0_m, y_m), (x1_m, y_m), (x1_m, 60), (x0_m, 60))]
    box = gpd.GeoSeries([shapely.Polygon(corners)], crs="EPSG:4326").to_crs(layers.crs).values[0]
    return north.intersection(box).area


def test_a_sidewalk_that_swings_out_along_part_of_the_block_is_reached_there_and_not_elsewhere(tmp_path):
    # Its far edge lies 13 m out (the side's median), and 17 m out from x = 20 to 70 m.
    swing = [(-110, 12), (10, 12), (20, 16), (70, 16), (80, 12), (110, 12)]
    layers = build_map(osm_file=scene(tmp_path / "s.osm", [(swing, SIDEWALK)]))
    # Before: nothing beyond the median's 13 m.
    assert north_area_m2(layers, 25, 65, 13.5) == pytest.approx(40 * 3.5, rel=0.05)
    assert north_area_m2(layers, -150, 5, 13.5) < 1.0
    assert north_area_m2(layers, 85, 150, 13.5) < 1.0
    assert north_area_m2(layers, -150, 150, 17.2) < 1.0
    assert north_area_m2(layers, -150, 150, 9.5) > 200 * 3.5  # the median's reach stays everywhere


def test_a_sidewalk_mapped_along_a_third_of_the_block_is_reached_along_that_stretch(tmp_path):
    # 67 m of the 200 m block, 14 m out: 8 of the side's 25 rays meet it, a run of 64 m.
    layers = build_map(osm_file=scene(tmp_path / "s.osm", [([(-30, 14), (37, 14)], SIDEWALK)]))
    # Before: under half the rays met it, and the band stopped at 9 m. Now it reaches 15 m (14 m
    # plus half of 2 m) over the 64 m that the rays stand for, held level to the run's ends.
    assert north_area_m2(layers, -150, 150, 9.5) == pytest.approx(64 * 5.5, rel=0.03)
    assert north_area_m2(layers, -150, -29, 9.5) + north_area_m2(layers, 37, 150, 9.5) < 1.0
    assert north_area_m2(layers, -150, 150, 15.2) < 1.0
    # Every id of the usual map is kept, and the south side is unchanged.
    usual = functools.partial(reach.reach_polygons, min_run_m=np.inf)
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(sidewalks, "reach_polygons", usual)
        before = build_map(osm_file=scene(tmp_path / "s.osm", [([(-30, 14), (37, 14)], SIDEWALK)]))
    assert list(before.gdf["segment_id"]) == list(layers.gdf["segment_id"])
    south = (layers.gdf["segment_id"] == "w10-0-R").to_numpy()
    assert shapely.equals(layers.gdf.geometry.values[south], before.gdf.geometry.values[south]).all()
    assert north_area_m2(before, -150, 150, 9.5) < 1.0


def test_a_short_path_seen_through_a_gap_between_buildings_stays_out(tmp_path, monkeypatch):
    # Buildings from y = 10 to 20 m with a 12 m gap at x = 0, and a 24 m path behind them: one ray
    # passes the gap, a run of 8 m, under the 24 m a run needs.
    buildings = [([(-110, 10), (-6, 10), (-6, 20), (-110, 20)], {"building": "yes"}),
                 ([(6, 10), (110, 10), (110, 20), (6, 20)], {"building": "yes"})]  # fmt: skip
    path = scene(tmp_path / "s.osm", [*buildings, ([(-12, 22), (12, 22)], SIDEWALK)])
    assert north_area_m2(build_map(osm_file=path), -150, 150, 9.5) < 1.0
    # Any run at all would take the backyard behind the gap.
    monkeypatch.setattr(sidewalks, "reach_polygons", functools.partial(reach.reach_polygons, min_run_m=8))
    assert north_area_m2(build_map(osm_file=path), -150, 150, 9.5) > 20


@pytest.mark.parametrize(
    "ways",
    [
        # A service road 11 m out (5 m wide) in front of the path: that path is the service road's.
        [([(-110, 11), (110, 11)], {"highway": "service"}), ([(-30, 16), (37, 16)], SIDEWALK)],
        # Another street 30 m out, its sidewalk 24 m out: nearer that street than Main Street, so
        # the band would only have reached into the free space short of the midline between them.
        [([(-30, 30), (37, 30)], {"highway": "residential", "width": "8"}),
         ([(-30, 24), (37, 24)], SIDEWALK)],  # fmt: skip
    ],
    ids=["beyond-a-service-road", "another-streets-sidewalk"],
)
def test_a_path_that_is_another_roads_stays_out(tmp_path, ways):
    layers = build_map(osm_file=scene(tmp_path / "s.osm", ways))
    assert north_area_m2(layers, -150, 150, 9.5) < 1.0


def test_the_rays_on_the_stretches_are_the_rays_on_the_blocks():
    lines = np.array([
        shapely.LineString([(0, 0), (30, 0), (50, 25), (50, 90)]),
        shapely.LineString([(0, 0), (5, 0)]),  # shorter than a ray step: one stretch
        shapely.LineString([(0, 0), (16, 0)]),
    ])  # fmt: skip
    stretches, line_of = reach.ray_stretches(lines)
    n = np.maximum(1, (shapely.length(lines) // reach.RAY_STEP_M).astype(int))
    assert np.array_equal(line_of, np.repeat(np.arange(3), n))
    _, block_xy, block_tangent = ray_origins(lines, n)
    _, xy, tangent = ray_origins(stretches, np.ones(len(stretches), dtype=int))
    np.testing.assert_allclose(xy, block_xy, atol=1e-9)
    np.testing.assert_allclose(tangent, block_tangent, atol=1e-9)
    rank = np.arange(len(line_of)) - np.repeat(np.cumsum(n) - n, n)
    step = shapely.length(lines) / n
    pairs = zip(line_of, rank, strict=True)
    expected = [shapely.ops.substring(lines[i], k * step[i], (k + 1) * step[i]) for i, k in pairs]
    assert all(shapely.equals_exact(stretches, np.array(expected), tolerance=1e-9))
