"""Which side of the street: ``facing_deg`` from the build's centrelines, and the compass side it names."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import shapely

from curbside import settings
from curbside.cli.osmseg import main as osmseg_main
from curbside.osmseg.build import build_map
from curbside.osmseg.mapio import read_map, write_map
from curbside.osmseg.places import COMPASS_SIDES, compass_names, compass_sides, sidewalk_places
from curbside.osmseg.reader import read_osm_file
from curbside.osmseg.sidewalks import facing_bearings_deg

#: Market Street between 2nd and 4th Street, with the diagonal SoMa grid meeting the square FiDi one.
MARKET_BBOX = (-122.404, 37.786, -122.394, 37.794)


@pytest.fixture(scope="module")
def market():
    return build_map(MARKET_BBOX)


def _sector_gap(a: str, b: str) -> int:
    i, j = COMPASS_SIDES.index(a), COMPASS_SIDES.index(b)
    return min((i - j) % 8, (j - i) % 8)


def test_facing_is_the_centrelines_normal_on_the_sides_side():
    east = shapely.LineString([(0, 0), (100, 0)])
    north = shapely.LineString([(0, 0), (0, 100)])
    band = shapely.box(40, 5, 60, 10)  # where the part lies does not matter, only where it projects
    lines = np.array([east, east, north, north])
    facing = facing_bearings_deg(np.array([band] * 4), lines, np.array(["left", "right", "left", "right"]))
    assert facing == pytest.approx([0.0, 180.0, 270.0, 90.0])
    assert compass_names(facing) == ["north", "south", "west", "east"]
    assert np.isnan(facing_bearings_deg(np.array([band]), np.array([shapely.LineString([(1, 1), (1, 1)])]),
                                        np.array(["left"])))[0]


def test_a_bend_is_read_where_the_segment_lies():
    bend = shapely.LineString([(0, 0), (50, 0), (50, 50)])  # east, then north
    near_start, near_end = shapely.box(10, 4, 20, 8), shapely.box(40, 35, 45, 45)
    parts, lines = np.array([near_start, near_end]), np.array([bend, bend])
    facing = facing_bearings_deg(parts, lines, np.array(["left"] * 2))
    assert facing == pytest.approx([0.0, 270.0])


def test_every_side_on_market_street_is_northwest_or_southeast(market):
    places = sidewalk_places(market)
    sidewalks = market.layer("sidewalk")
    on_market = (sidewalks["street"] == "Market Street").to_numpy()
    sides = {places[str(i)].side for i in sidewalks["segment_id"][on_market]}
    assert sides == {"northwest", "southeast"}  # Market runs at 45-47 deg; its sides are these two
    # From the polygons alone a corner piece reads "southwest" here: the case this fixes.
    geometric = compass_sides(sidewalks.geometry.to_numpy(), market.layer("street").geometry.to_numpy())
    assert not {s for s, market_side in zip(geometric, on_market, strict=True) if market_side} <= sides


def test_the_side_is_the_osm_ways_own_left_or_right(market):
    """Checked against the raw OSM ways (not the build's blocks): the way's normal where it passes nearest."""
    ways = read_osm_file(settings.default_osm_file, MARKET_BBOX).ways.to_crs(market.crs)
    by_id = dict(zip(ways["osm_id"].astype(int), ways.geometry, strict=True))
    sidewalks = market.layer("sidewalk")
    places = sidewalk_places(market)
    gaps = []
    for seg, side, geom in zip(sidewalks["segment_id"], sidewalks["side"], sidewalks.geometry, strict=True):
        way = by_id[int(seg[1:].split("-")[0])]
        at = way.project(geom.centroid)
        a, b = way.interpolate(max(at - 2, 0)), way.interpolate(min(at + 2, way.length))
        dx, dy = b.x - a.x, b.y - a.y
        sign = 1 if side == "left" else -1
        expected = compass_names([np.degrees(np.arctan2(-dy * sign, dx * sign)) % 360])[0]
        gaps.append(_sector_gap(places[str(seg)].side, expected))
    gaps = np.array(gaps)
    assert len(gaps) > 300
    assert (gaps <= 1).all()  # a neighbouring eighth at most, where the way kinks within 2 m
    assert (gaps == 0).mean() > 0.98


def test_facing_survives_the_file_and_wins_over_the_polygons(market, tmp_path):
    path = write_map(market, tmp_path / "map.geojson")
    doc = json.loads(path.read_text())
    sidewalk = next(f for f in doc["features"] if f["properties"]["class"] == "sidewalk")
    assert isinstance(sidewalk["properties"]["facing_deg"], float)
    others = [f["properties"] for f in doc["features"] if f["properties"]["class"] != "sidewalk"]
    assert others and all("facing_deg" not in props for props in others)
    again = read_map(path)
    assert again.layer("sidewalk")["facing_deg"].to_numpy() == pytest.approx(
        market.layer("sidewalk")["facing_deg"].to_numpy(), abs=0.051
    )
    # A hand-set bearing is the side named, whatever the polygon's shape says.
    sidewalk["properties"]["facing_deg"] = (sidewalk["properties"]["facing_deg"] + 180) % 360
    (tmp_path / "flipped.geojson").write_text(json.dumps(doc))
    seg = sidewalk["properties"]["segment_id"]
    before = sidewalk_places(again)[seg].side
    after = sidewalk_places(read_map(tmp_path / "flipped.geojson"))[seg].side
    assert _sector_gap(before, after) == 4


def test_a_map_without_facing_still_gets_sides_from_its_polygons(market, tmp_path):
    doc = json.loads(write_map(market, tmp_path / "map.geojson").read_text())
    for f in doc["features"]:
        f["properties"].pop("facing_deg", None)
    (tmp_path / "old.geojson").write_text(json.dumps(doc))
    old = read_map(tmp_path / "old.geojson")
    sidewalks = old.layer("sidewalk")
    places = sidewalk_places(old)
    expected = compass_sides(sidewalks.geometry.to_numpy(), old.layer("street").geometry.to_numpy())
    assert [places[str(i)].side for i in sidewalks["segment_id"]] == expected
    assert np.mean([side is not None for side in expected]) > 0.98


@pytest.mark.parametrize("value", ["north", [1, 2], float("inf")], ids=["word", "list", "inf"])
def test_a_facing_that_is_not_a_bearing_is_refused_in_one_line(tmp_path, capsys, value, test_data: Path):
    source = test_data / "maps" / "crossroads.geojson"
    doc = json.loads(source.read_text())
    sidewalk = next(f for f in doc["features"] if f["properties"]["class"] == "sidewalk")
    sidewalk["properties"]["facing_deg"] = value
    path = tmp_path / "bad.geojson"
    path.write_text(json.dumps(doc).replace("Infinity", "1e999"))
    before = set(tmp_path.iterdir())
    assert osmseg_main(["show", str(path), "-o", str(tmp_path / "out.png")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and str(path) in err and "facing_deg must be a bearing" in err
    assert "Traceback" not in err and set(tmp_path.iterdir()) == before
