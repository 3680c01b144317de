"""Sidewalk segments reach out to a separately mapped sidewalk that lies beyond the usual band.

The real case is the east side of Ploshchad Truda in Saint Petersburg
(``tests/data/osm/world/spb-ploshchad-truda-east.osm``, README there): ``parking:right=separate``
puts its ``footway=sidewalk`` 10-11 m from the carriageway's centreline, past the curb (4.5 m) plus
``sidewalk_depth_m`` (5 m), so the mapped sidewalk was free space. The synthetic scenes are a straight
residential street 8 m wide (curb 4 m, usual band 9 m from the centreline) with one more way north
of it.
"""

from __future__ import annotations

from pathlib import Path

import geopandas as gpd
import numpy as np
import pytest
import shapely

from curbside.osmseg import sidewalks
from curbside.osmseg.build import build_map
from curbside.osmseg.mapio import MapLayers
from curbside.osmseg.reader import bbox_polygon, declared_bounds, read_osm_file

TRUDA = Path(__file__).parent / "data" / "osm" / "world" / "spb-ploshchad-truda-east.osm"
EAST_HALF = 235504983  # Ploshchad Truda's northbound half, drawn northwards: east is its right
EAST_SIDEWALK = 416690533  # footway=sidewalk, no width tag (2 m)
LON0, LAT0 = 13.4000, 52.5200
M_PER_DEG_LAT = 111_320.0
M_PER_DEG_LON = 111_320.0 * np.cos(np.radians(LAT0))


def _way_in_map(path: Path, layers: MapLayers, osm_id: int) -> shapely.LineString:
    ways = read_osm_file(path).ways.to_crs(layers.crs)
    return ways.geometry.values[ways["osm_id"].to_numpy() == osm_id][0]


def test_the_sidewalk_beyond_a_parking_lane_lies_in_its_block_side():
    # Before: none of the 53 m of the east sidewalk inside the map lay in a segment.
    layers = build_map(osm_file=TRUDA)
    bounds = bbox_polygon(declared_bounds(TRUDA), layers.crs)
    line = _way_in_map(TRUDA, layers, EAST_SIDEWALK).intersection(bounds)
    assert line.length == pytest.approx(53, abs=1)
    gdf = layers.gdf
    (segment,) = gdf.geometry.values[gdf["segment_id"].to_numpy() == f"w{EAST_HALF}-0-R"]
    assert line.intersection(segment).length / line.length > 0.99
    row = gdf[gdf["segment_id"] == f"w{EAST_HALF}-0-R"].iloc[0]
    assert (row["street"], row["side"]) == ("площадь Труда", "right")
    assert 45 < row["facing_deg"] < 135  # east
    # The band stops at the sidewalk's far edge, which runs 10.7 to 12.2 m from the centreline
    # (its distance plus half of 2 m; stop 54 follows it ray by ray, stop 53 stopped at the 11.6 m median).
    centreline = _way_in_map(TRUDA, layers, EAST_HALF)
    reach_m = shapely.distance(shapely.points(shapely.get_coordinates(segment)), centreline).max()
    assert reach_m == pytest.approx(12.2, abs=0.3)


def test_only_that_block_side_changes(monkeypatch):
    layers = build_map(osm_file=TRUDA)
    # The usual band: no mapped sidewalk reached.
    monkeypatch.setattr(sidewalks, "mapped_far_edges_m", lambda lines, *_: np.full((len(lines), 2), np.nan))
    usual = build_map(osm_file=TRUDA)
    assert len(layers.gdf) == len(usual.gdf)
    same = shapely.equals(layers.gdf.geometry.values, usual.gdf.geometry.values)
    assert list(layers.gdf["segment_id"][~same]) == [f"w{EAST_HALF}-0-R"]
    grown = layers.gdf.geometry.values[~same][0].difference(usual.gdf.geometry.values[~same][0])
    assert grown.area == pytest.approx(139, abs=5)  # stop 53, out to the median far edge alone: 131 m^2


def _lonlat(x_m: float, y_m: float) -> tuple[float, float]:
    return LON0 + x_m / M_PER_DEG_LON, LAT0 + y_m / M_PER_DEG_LAT


def street_with(
    path: Path, north: dict[str, str], north_y_m: float, building: bool = False, gap_m: float = 0.0
) -> Path:
    """Residential street along y = 0 (x from -100 to 100 m, 8 m wide), a way with tags ``north``
    along y = ``north_y_m`` (x from -110 to 110 m) and, optionally, buildings from y = 10 to 12 m
    along it, with a gap of ``gap_m`` between two of them at x = 0."""
    g = gap_m / 2
    xy = {1: (-100, 0), 2: (100, 0), 3: (-110, north_y_m), 4: (110, north_y_m),
          5: (-110, 10), 6: (-g, 10), 7: (-g, 12), 8: (-110, 12),
          15: (g, 10), 16: (110, 10), 17: (110, 12), 18: (g, 12)}  # fmt: skip
    nodes = "".join(
        f'<node id="{i}" version="1" lat="{lat:.8f}" lon="{lon:.8f}"/>'
        for i, (lon, lat) in ((i, _lonlat(*p)) for i, p in xy.items())
    )

    def way(way_id: int, refs: list[int], tags: dict[str, str]) -> str:
        nds = "".join(f'<nd ref="{r}"/>' for r in refs)
        tagged = "".join(f'<tag k="{k}" v="{v}"/>' for k, v in tags.items())
        return f'<way id="{way_id}" version="1">{nds}{tagged}</way>'

    main = {"highway": "residential", "name": "Main Street", "width": "8"}
    ways = [way(10, [1, 2], main), way(11, [3, 4], north)]
    if building:
        ways.append(way(12, [5, 6, 7, 8, 5], {"building": "yes"}))
        ways.append(way(14, [15, 16, 17, 18, 15], {"building": "yes"}))
    path.write_text(f'<?xml version="1.0"?><osm version="0.6">{nodes}{"".join(ways)}</osm>')
    return path


def north_sidewalk(layers: MapLayers) -> shapely.Geometry:
    gdf = layers.gdf
    return shapely.union_all(gdf.geometry.values[gdf["segment_id"].fillna("").str.endswith("-L").to_numpy()])


def beyond_m2(layers: MapLayers, y_m: float) -> float:
    """Area of the north sidewalk more than ``y_m`` north of the street."""
    corners = [_lonlat(x, y) for x, y in ((-150, y_m), (150, y_m), (150, 60), (-150, 60))]
    box = gpd.GeoSeries([shapely.Polygon(corners)], crs="EPSG:4326").to_crs(layers.crs).values[0]
    return north_sidewalk(layers).intersection(box).area


def test_a_parallel_mapped_sidewalk_past_the_band_is_reached(tmp_path):
    sidewalk = {"highway": "footway", "footway": "sidewalk"}
    layers = build_map(osm_file=street_with(tmp_path / "s.osm", sidewalk, 14))
    assert beyond_m2(layers, 9.5) == pytest.approx(200 * 5.5, rel=0.02)  # out to 15 m: 14 m + half of 2 m
    assert beyond_m2(layers, 15.2) < 1.0


@pytest.mark.parametrize(
    ("north", "north_y_m", "building", "gap_m"),
    [
        ({"highway": "footway", "footway": "sidewalk"}, 30, False, 0),  # past the 25 m search
        ({"highway": "footway"}, 14, False, 0),  # a park path, not a sidewalk
        ({"highway": "footway", "footway": "sidewalk"}, 16, True, 0),  # behind buildings
        # Behind buildings with a passage between them: before rays stopped at buildings, the band
        # reached round through the gap to the path behind them (1,000 m^2 of backyard).
        ({"highway": "footway", "footway": "sidewalk"}, 16, True, 4),
    ],
    ids=["sidewalk-30m", "park-path-14m", "behind-buildings", "behind-buildings-with-a-gap"],
)
def test_other_footways_do_not_drag_the_band_out(tmp_path, north, north_y_m, building, gap_m):
    layers = build_map(osm_file=street_with(tmp_path / "s.osm", north, north_y_m, building, gap_m))
    assert beyond_m2(layers, 9.5) < 1.0


def test_a_sidewalk_beyond_another_road_is_not_reached(tmp_path):
    # A service road along y = 11 m (5 m wide) and a sidewalk along y = 16 m: that sidewalk is the
    # service road's, and Main Street's band stays short of the service road's carriageway.
    path = street_with(tmp_path / "s.osm", {"highway": "service"}, 11)
    text = path.read_text()
    extra = "".join(
        f'<node id="{i}" version="1" lat="{lat:.8f}" lon="{lon:.8f}"/>'
        for i, (lon, lat) in ((20, _lonlat(-110, 16)), (21, _lonlat(110, 16)))
    )
    sidewalk = '<way id="13" version="1"><nd ref="20"/><nd ref="21"/><tag k="highway" v="footway"/>'
    sidewalk += '<tag k="footway" v="sidewalk"/></way>'
    path.write_text(text.replace("<way ", extra + "<way ", 1).replace("</osm>", sidewalk + "</osm>"))
    layers = build_map(osm_file=path)
    assert beyond_m2(layers, 9.5) < 1.0


def test_the_map_and_osmseg_build_say_how_much_of_the_mapped_sidewalks_the_segments_cover(
    monkeypatch, tmp_path, capsys
):
    from curbside.cli.osmseg import main

    assert main(["build", "--osm", str(TRUDA), "-o", str(tmp_path / "map.geojson")]) == 0
    said = capsys.readouterr().out
    layers = build_map(osm_file=TRUDA)
    share, km = layers.meta["sidewalk_ways_in_segments"], layers.meta["sidewalk_ways_km"]
    assert share > 0.99 and km == pytest.approx(0.14, abs=0.01)
    assert f"{100 * share:.1f} % of the {km:g} km of mapped sidewalks (footway=sidewalk) lie in " in said
    assert "lie in sidewalk segments\n" in said
    # With the usual band alone the east sidewalk's 53 m are free space, and the share says so.
    monkeypatch.setattr(sidewalks, "mapped_far_edges_m", lambda lines, *_: np.full((len(lines), 2), np.nan))
    assert build_map(osm_file=TRUDA).meta["sidewalk_ways_in_segments"] < share - 0.3


def test_the_share_counts_only_the_mapped_sidewalk_inside_a_map_without_declared_bounds(tmp_path):
    # The 220 m sidewalk runs 10 m past each end of the 200 m street, so past the map's polygons.
    sidewalk = {"highway": "footway", "footway": "sidewalk"}
    layers = build_map(osm_file=street_with(tmp_path / "s.osm", sidewalk, 14))
    assert layers.meta["sidewalk_ways_km"] < 0.215
    assert layers.meta["sidewalk_ways_in_segments"] > 0.95
