"""osmseg on real extracts from other cities: roundabouts and loop roads (tests/data/osm/world/).

Two pieces of real OpenStreetMap data (README there): a small residential roundabout in a suburb of
Atlanta drawn as one closed way, and St James' Barton in Bristol, a roundabout of eight ways drawn
clockwise (traffic keeps left) around a sunken pedestrian plaza.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import shapely

from curbside.osmseg.build import build_map
from curbside.osmseg.config import SegmentationConfig
from curbside.osmseg.reader import read_osm_file
from curbside.osmseg.streets import carriageway_width, island_sides, side_buffers

WORLD = Path(__file__).parent / "data" / "osm" / "world"
ATLANTA = WORLD / "atlanta-roundabout.osm"
BRISTOL = WORLD / "bristol-roundabout.osm"
ATLANTA_RING = 235499756
BRISTOL_ARCS = (37283065, 37283067, 37354482, 38696932, 38696934, 202755223, 202755224, 203035036)


def union_of(gdf, cls: str) -> shapely.Geometry:
    return shapely.union_all(gdf.geometry.values[gdf["class"].to_numpy() == cls])


def atlanta_ring(path: Path = ATLANTA) -> tuple[shapely.LineString, shapely.Polygon]:
    ways = read_osm_file(path).ways
    ring = ways.geometry.values[ways["osm_id"].to_numpy() == ATLANTA_RING][0]
    return ring, shapely.Polygon(ring.coords)


def bristol_island() -> shapely.Polygon:
    """The area the roundabout's centreline encloses, in the map's CRS."""
    ways = read_osm_file(BRISTOL).ways
    arcs = ways.geometry.values[np.isin(ways["osm_id"].to_numpy(), BRISTOL_ARCS)]
    noded = shapely.get_parts(shapely.node(shapely.union_all(arcs)))
    (polygon,) = shapely.get_parts(shapely.polygonize(noded))
    return polygon


def test_side_buffers_of_a_closed_way_are_bands():
    # GEOS's single-sided buffer of a closed line is the polygon it encloses, shrunk on the left and
    # whole on the right; a roundabout drawn as one closed way then had its island paved and its
    # outer lane missing.
    ring, inside = atlanta_ring()
    assert shapely.is_ccw(ring)
    left = side_buffers(np.array([ring]), 4.0)[0]
    right = side_buffers(np.array([ring]), -4.0)[0]
    assert shapely.area(shapely.difference(left, inside)) < 0.01  # inside the ring
    assert shapely.area(shapely.intersection(right, inside)) < 0.01  # outside it
    # Bands 4 m wide along a 118 m ring, narrower (inside) and wider (outside) by its curvature.
    assert left.area == pytest.approx(4.0 * ring.length - np.pi * 16, rel=0.05)
    assert right.area == pytest.approx(4.0 * ring.length + np.pi * 16, rel=0.05)
    open_line = shapely.LineString(ring.coords[:5])
    assert side_buffers(np.array([open_line]), 4.0)[0].equals(
        shapely.buffer(open_line, 4.0, single_sided=True, quad_segs=2)
    )


def test_roundabout_drawn_as_one_closed_way_is_a_ring_of_carriageway():
    layers = build_map(osm_file=ATLANTA)
    street = union_of(layers.gdf, "street")
    ring, inside = atlanta_ring()
    island = inside.buffer(-4.5)  # inside the inner curb (residential: 8 m wide)
    outer_lane = shapely.difference(inside.buffer(3.5), inside.buffer(0.5))
    # Before: 612 m^2 of the island was street, and the outer lane was sidewalk.
    assert shapely.area(shapely.intersection(street, island)) < 1.0
    assert shapely.area(shapely.intersection(street, outer_lane)) > 0.97 * outer_lane.area
    sidewalk = union_of(layers.gdf, "sidewalk")
    assert shapely.area(shapely.intersection(sidewalk, outer_lane)) < 1.0


def test_loop_without_junctions_has_its_sidewalk_outside_only(tmp_path):
    text = ATLANTA.read_text(encoding="utf-8")
    alone = tmp_path / "ring-alone.osm"
    alone.write_text(re.sub(r'  <way id="23549975[78]".*?</way>\n', "", text, flags=re.S), encoding="utf-8")
    layers = build_map(osm_file=alone)
    ring, inside = atlanta_ring(alone)
    radius_m = np.sqrt(inside.area / np.pi)
    street, sidewalk = union_of(layers.gdf, "street"), union_of(layers.gdf, "sidewalk")
    assert street.area == pytest.approx(2 * 4.0 * ring.length, rel=0.03)
    # From the outer curb (4 m out) to 5 m beyond it; before: 1,329 m^2 that included the outer lane.
    band = np.pi * ((radius_m + 9.0) ** 2 - (radius_m + 4.0) ** 2)
    assert sidewalk.area == pytest.approx(band, rel=0.05)
    assert shapely.area(shapely.intersection(sidewalk, inside)) < 1.0


def test_island_sides_of_roundabouts_both_ways_round():
    ways = read_osm_file(BRISTOL).ways
    arcs = ways.geometry.values[np.isin(ways["osm_id"].to_numpy(), BRISTOL_ARCS)]
    assert len(arcs) == len(BRISTOL_ARCS)
    # Clockwise (traffic keeps left): the island is on the right of every way, the straight
    # two-node ones included.
    assert (island_sides(arcs) == -1).all()
    ring, _ = atlanta_ring()
    assert island_sides(np.array([ring])).tolist() == [1]  # anticlockwise
    assert island_sides(np.array([shapely.LineString([(0, 0), (10, 0)])])).tolist() == [0]


def test_roundabout_island_gets_no_sidewalk():
    layers = build_map(osm_file=BRISTOL)
    island = bristol_island()
    sidewalk = union_of(layers.gdf, "sidewalk")
    # Before: 1,063 m^2 of sidewalk segments ran round the inside of the roundabout.
    assert shapely.area(shapely.intersection(sidewalk, island)) < 1.0
    outside = shapely.difference(island.buffer(20.0), island)
    assert shapely.area(shapely.intersection(sidewalk, outside)) > 1000.0
    names = set(layers.gdf["street"].dropna())
    assert "St James' Barton" in names


def test_a_road_with_a_number_and_no_name_is_called_by_its_number(tmp_path):
    # St James' Barton is also the A38; without its name its sidewalks were "unnamed street".
    text = BRISTOL.read_text(encoding="utf-8")
    numbered = tmp_path / "numbered.osm"
    numbered.write_text(text.replace('<tag k="name" v="St James\' Barton"/>', ""), encoding="utf-8")
    named = build_map(osm_file=BRISTOL).gdf
    streets = build_map(osm_file=numbered).gdf["street"]
    was_barton = (named["street"] == "St James' Barton").to_numpy()
    assert was_barton.any()
    assert (streets[was_barton] == "A38").all()
    assert (streets[~was_barton].fillna("") == named["street"][~was_barton].fillna("")).all()


def test_a_width_no_carriageway_has_is_ignored_with_a_warning(caplog):
    # width="0.5 km" (a unit slip) drew a 500 m carriageway over the whole neighbourhood.
    ways = pd.DataFrame([
        {"osm_id": 7, "highway": "residential", "width": "0.5 km", "lanes": "2"},
        {"osm_id": 8, "highway": "residential", "est_width": "1 mi"},
        {"osm_id": 9, "highway": "primary", "width": "40"},
    ])
    config = SegmentationConfig()
    with caplog.at_level("WARNING", logger="curbside.osmseg.streets"):
        width, tagged = carriageway_width(ways, config)
    lane, parking = config.lane_width_m, config.assumed_parking_width_m
    assert width[0] == pytest.approx(2 * lane + 2 * parking)
    assert width[1] == config.default_carriageway_width_m["residential"]
    assert width[2] == 40.0
    assert tagged.tolist() == [False, False, True]
    assert "2 road way(s) tagged wider than 60 m (way 7: 500 m)" in caplog.text
