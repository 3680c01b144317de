"""Dual carriageways: no sidewalk in the median between a divided road's two one-way halves.

Scenes are small OSM files written here: a road 200 m long drawn as two one-way ways of one name,
with a two-way cross street at each end. The real case is The Embarcadero in the bundled extract.
"""

from __future__ import annotations

from pathlib import Path

import geopandas as gpd
import numpy as np
import pytest
import shapely

from curbside.osmseg.build import build_map
from curbside.osmseg.config import SegmentationConfig
from curbside.osmseg.mapio import MapLayers

WORLD = Path(__file__).parent / "data" / "osm" / "world"
LON0, LAT0 = -122.4000, 37.7900
M_PER_DEG_LAT = 111_320.0
M_PER_DEG_LON = 111_320.0 * np.cos(np.radians(LAT0))
HALF_LENGTH_M = 100.0


def _lonlat(x_m: float, y_m: float) -> tuple[float, float]:
    return LON0 + x_m / M_PER_DEG_LON, LAT0 + y_m / M_PER_DEG_LAT


def _tags(tags: dict[str, str]) -> str:
    return "".join(f'<tag k="{k}" v="{v}"/>' for k, v in tags.items())


def divided_road(
    path: Path,
    gap_m: float = 20.0,
    east: dict[str, str] | None = None,
    west: dict[str, str] | None = None,
    east_northward: bool = True,
    west_northward: bool = False,
    building_between: bool = False,
) -> Path:
    """Two one-way halves at x = +-gap_m / 2 (centrelines), cross streets at y = +-100 m; optionally
    a building 6 m wide and 120 m long between them."""
    x = gap_m / 2
    corners = {1: (-x, -HALF_LENGTH_M), 2: (-x, HALF_LENGTH_M), 3: (x, -HALF_LENGTH_M), 4: (x, HALF_LENGTH_M),
               5: (-x - 120, -HALF_LENGTH_M), 6: (x + 120, -HALF_LENGTH_M), 7: (-x - 120, HALF_LENGTH_M),
               8: (x + 120, HALF_LENGTH_M), 20: (-3, -60), 21: (3, -60), 22: (3, 60),
               23: (-3, 60)}  # fmt: skip
    nodes = "".join(
        f'<node id="{i}" version="1" lat="{lat:.8f}" lon="{lon:.8f}"/>'
        for i, (lon, lat) in ((i, _lonlat(*xy)) for i, xy in corners.items())
    )
    half = {"highway": "secondary", "name": "Divided Road", "oneway": "yes", "width": "7"}
    cross = {"highway": "residential", "name": "Cross Street"}

    def way(way_id: int, refs: list[int], tags: dict[str, str]) -> str:
        nds = "".join(f'<nd ref="{r}"/>' for r in refs)
        return f'<way id="{way_id}" version="1">{nds}{_tags(tags)}</way>'

    ways = [
        way(10, [3, 4] if east_northward else [4, 3], {**half, **(east or {})}),
        way(11, [1, 2] if west_northward else [2, 1], {**half, **(west or {})}),
        way(12, [5, 1, 3, 6], cross),
        way(13, [7, 2, 4, 8], cross),
    ]
    if building_between:
        ways.append(way(14, [20, 21, 22, 23, 20], {"building": "yes"}))
    path.write_text(f'<?xml version="1.0"?><osm version="0.6">{nodes}{"".join(ways)}</osm>')
    return path


def _box(layers: MapLayers, x0_m: float, x1_m: float, y0_m: float, y1_m: float) -> shapely.Polygon:
    corners = [_lonlat(x, y) for x, y in ((x0_m, y0_m), (x1_m, y0_m), (x1_m, y1_m), (x0_m, y1_m))]
    box = gpd.GeoSeries([shapely.Polygon(corners)], crs="EPSG:4326").to_crs(layers.crs)
    return box.values[0]


def sidewalk_m2(layers: MapLayers, box: shapely.Polygon) -> float:
    gdf = layers.gdf
    sidewalks = gdf.geometry.values[gdf["class"].to_numpy() == "sidewalk"]
    return float(shapely.area(shapely.intersection(shapely.union_all(sidewalks), box)))


def median_and_outside_m2(layers: MapLayers, gap_m: float) -> tuple[float, float, float]:
    """Sidewalk area between the centrelines, and east and west of the road (mid-block, 160 m)."""
    x = gap_m / 2
    return (
        sidewalk_m2(layers, _box(layers, -x, x, -80, 80)),
        sidewalk_m2(layers, _box(layers, x, x + 15, -80, 80)),
        sidewalk_m2(layers, _box(layers, -x - 15, -x, -80, 80)),
    )


@pytest.mark.parametrize(
    ("east_northward", "west_northward", "west"),
    [
        (True, False, None),  # traffic keeps right
        (False, True, None),  # traffic keeps left: the median is on each half's right
        (True, True, {"oneway": "-1"}),  # one half drawn against its traffic
    ],
    ids=["keep-right", "keep-left", "drawn-backwards"],
)
def test_the_median_of_a_divided_road_has_no_sidewalk(tmp_path, east_northward, west_northward, west):
    path = divided_road(tmp_path / "divided.osm", east_northward=east_northward,
                        west_northward=west_northward, west=west)  # fmt: skip
    layers = build_map(osm_file=path)
    median, east, west_side = median_and_outside_m2(layers, 20.0)
    assert median < 1.0
    # The outer sides keep theirs: 160 m of block, 5 m deep.
    assert east > 0.9 * 160 * 5 and west_side > 0.9 * 160 * 5
    off = build_map(osm_file=path, config=SegmentationConfig(max_median_width_m=0.0))
    assert median_and_outside_m2(off, 20.0)[0] > 0.9 * 2 * 160 * 5  # the rule off: both bands back


def test_a_street_split_round_a_row_of_buildings_keeps_its_inner_sidewalks(tmp_path):
    path = divided_road(tmp_path / "split.osm", building_between=True)
    median, _, _ = median_and_outside_m2(build_map(osm_file=path), 20.0)
    # 3.5 m of sidewalk between each curb and the building, along its 120 m.
    assert median > 0.8 * 2 * 120 * 3.5


@pytest.mark.parametrize(
    ("gap_m", "east", "west", "west_northward"),
    [
        (20.0, None, None, True),  # two one-way streets the same way (a one-way pair, not one road)
        (20.0, None, {"name": "Frontage Road"}, False),  # another street beside it
        (20.0, {"sidewalk": "both"}, {"sidewalk:left": "yes"}, False),  # the mapper says there are
        (50.0, None, None, False),  # a park between them (43 m curb to curb), not a median
        (20.0, {"oneway": "no"}, None, False),  # one half two-way
    ],
    ids=["same-direction", "other-name", "tagged", "wide", "two-way"],
)
def test_a_side_that_is_not_a_median_keeps_its_sidewalk(tmp_path, gap_m, east, west, west_northward):
    path = divided_road(tmp_path / "pair.osm", gap_m, east=east, west=west, west_northward=west_northward)
    median, _, _ = median_and_outside_m2(build_map(osm_file=path), gap_m)
    assert median > 0.9 * 160 * 5


def removed_by_the_rule(**source) -> tuple[gpd.GeoDataFrame, gpd.GeoDataFrame]:
    """The sidewalk segments built, and those the median rule removed (built with it off)."""
    built = build_map(**source).gdf
    off = build_map(**source, config=SegmentationConfig(max_median_width_m=0.0)).gdf
    sidewalks = built[built["class"] == "sidewalk"]
    off_sidewalks = off[off["class"] == "sidewalk"]
    # The rule only removes: every segment built is one built without it, unchanged.
    same = off_sidewalks.set_index("segment_id").geometry
    for seg_id, polygon in zip(sidewalks["segment_id"], sidewalks.geometry.values, strict=True):
        assert polygon.equals(same[seg_id])
    return built, off_sidewalks[~off_sidewalks["segment_id"].isin(sidewalks["segment_id"])]


def assert_on_the_median_side(built: gpd.GeoDataFrame, removed: gpd.GeoDataFrame, median_side: str) -> None:
    """Every removed piece is on the side where the median lies for the traffic's hand (left where
    traffic keeps right), and its way keeps the sidewalk on the other side."""
    assert set(removed["side"]) == {median_side}
    kept_ways = {seg_id.split("-")[0] for seg_id in built["segment_id"].dropna()}
    assert {seg_id.split("-")[0] for seg_id in removed["segment_id"]} <= kept_ways


def test_the_embarcadero_median_in_the_bundled_extract_has_no_sidewalk():
    # North of the Ferry Building the Embarcadero is two one-way ways with the F-line's tracks between them.
    built, removed = removed_by_the_rule(bbox=(-122.4000, 37.7955, -122.3950, 37.8015))
    assert set(removed["street"]) == {"The Embarcadero"} and len(removed) >= 2
    assert (built["street"] == "The Embarcadero").sum() >= 4  # its outer sides keep theirs
    assert_on_the_median_side(built, removed, "left")


def test_dual_carriageways_where_traffic_keeps_left():
    # Bristol, round St James' Barton: one-way trunk and primary pairs (real OSM, tests/data/osm/world).
    built, removed = removed_by_the_rule(osm_file=WORLD / "bristol-st-james-barton.osm")
    assert set(removed["street"]) == {"Bond Street", "The Haymarket", "North Street", "Marlborough Street"}
    assert len(removed) >= 8
    assert_on_the_median_side(built, removed, "right")
    # The roundabout, whose island sides were already bare, keeps every other sidewalk.
    assert (built["street"] == "St James' Barton").sum() > 0


def test_a_piece_whose_halves_part_near_one_end_keeps_its_outer_sidewalk():
    # Braunschweig, Celler Straße (real OSM): the northbound half w501406799 runs on for 120 m
    # alone; only near its south end does a square line meet the southbound half. Two of the three
    # lines must meet it, so its west sidewalk stays (one line would have removed 600 m^2).
    built, removed = removed_by_the_rule(osm_file=WORLD / "braunschweig-celler-strasse.osm")
    assert "w501406799-0-L" in set(built["segment_id"])
    assert set(removed["street"]) == {"Celler Straße"} and len(removed) == 3
    assert_on_the_median_side(built, removed, "left")
