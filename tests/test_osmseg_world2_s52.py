"""osmseg on more real extracts from other cities: building relations (tests/data/osm/world/).

Two pieces of real OpenStreetMap data (README there): the Hotel Metropol in Moscow, a building
multipolygon whose outer ring and one of its three courtyards are each drawn as two ways, alone in its
file; and the Nicholas Palace in Saint Petersburg, a building relation of twelve outer ways of which an
openstreetmap.org export (complete ways, with ``<bounds>``) holds only the three that enter its bounds.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import osmium
import pytest
import shapely

from curbside.osmseg.areas import Surroundings, open_outer_closures, outside_buildings
from curbside.osmseg.build import build_map
from curbside.osmseg.reader import bbox_polygon, declared_bounds, read_osm_file
from curbside.projection import LocalFrame

WORLD = Path(__file__).parent / "data" / "osm" / "world"
METROPOL = WORLD / "moscow-metropol.osm"
PALACE = WORLD / "spb-nicholas-palace.osm"
PALACE_OUTER = (824294687, 417815576, 417815582)  # the ring's only ways in the file


def buildings(layers) -> np.ndarray:
    return layers.gdf.geometry.values[layers.gdf["class"].to_numpy() == "building"]


def test_a_file_with_only_a_building_relation_builds():
    # Before: "no highways, buildings or crossings in this file" (exit 2): the coordinates of a
    # relation's member ways were not counted as read.
    (hotel,) = buildings(build_map(osm_file=METROPOL))
    assert len(hotel.interiors) == 3  # three courtyards, one of them drawn as two ways
    assert hotel.area == pytest.approx(7849, rel=0.01)


def palace_chain() -> tuple[shapely.LineString, shapely.Polygon]:
    """The palace's outer ways in the file, merged, and the file's bounds, in the map's CRS."""
    frame = LocalFrame(read_osm_file(PALACE).crs)
    walls = []
    for way in osmium.FileProcessor(str(PALACE)).with_locations():
        if way.is_way() and way.id in PALACE_OUTER:  # untagged members: not in OsmData.ways
            lon, lat = np.array([(n.lon, n.lat) for n in way.nodes]).T
            walls.append(shapely.LineString(np.column_stack(frame.to_xy(lon, lat))))
    bounds = bbox_polygon(declared_bounds(PALACE), frame.crs)
    return shapely.line_merge(shapely.multilinestrings(walls)), bounds


def test_a_building_relation_crossing_the_bounds_keeps_its_part_inside(caplog):
    # Before: the palace was dropped ("multipolygon whose outer ways close no ring"), and the strip
    # it fills inside the bounds was free space and sidewalk along Galernaya ulitsa.
    caplog.set_level(logging.WARNING)
    layers = build_map(osm_file=PALACE)
    assert "r1404109" not in caplog.text
    chain, bounds = palace_chain()
    # Along the palace's walls: the palace and its manege (r6209770, 1,277 m^2, sharing a wall).
    along = [b for b in buildings(layers) if shapely.intersection(b, chain).length > 1.0]
    found = sorted(along, key=shapely.area)
    assert [round(b.area, -1) for b in found] == [300, 1280]
    palace = found[0]
    assert palace.area == pytest.approx(301, rel=0.05)
    # It is the side of its walls away from the street, inside the bounds, and it is whole there:
    # the palace walls inside the bounds are all on its boundary.
    streets = layers.gdf.geometry.values[layers.gdf["class"].to_numpy() == "street"]
    assert shapely.area(shapely.intersection(shapely.union_all(streets), palace)) < 0.5
    assert shapely.difference(palace, bounds.buffer(0.01)).area < 0.01
    walls_inside = shapely.intersection(chain, bounds)
    assert shapely.difference(walls_inside, palace.boundary.buffer(0.05)).length < 0.1


def test_without_evidence_of_the_side_the_relation_stays_dropped():
    # Nothing on either side of the walls (no other building, no street): which side is building is
    # unknown, and a wrong guess would wall off the other, so nothing is drawn.
    chain, bounds = palace_chain()
    nothing = Surroundings(bounds, np.array([], dtype=object), np.array([], dtype=object))
    lines = np.array(shapely.get_parts(shapely.line_merge(chain)))
    out = open_outer_closures(lines, np.zeros(len(lines), dtype=int), np.zeros(len(lines), bool), 1, nothing)
    assert shapely.is_empty(out[0])
    street = Surroundings(bounds, nothing.taken, read_osm_file(PALACE).ways.geometry.values)
    out = open_outer_closures(lines, np.zeros(len(lines), dtype=int), np.zeros(len(lines), bool), 1, street)
    assert out[0].area == pytest.approx(301, rel=0.05)


def test_a_chain_ending_inside_the_bounds_is_not_closed():
    # An end inside the bounds means the file was cut through its ways (or the ring is broken): the
    # chain is not the whole ring inside the bounds, so the building is not guessed.
    chain, bounds = palace_chain()
    xy = shapely.get_coordinates(chain)
    last_inside = np.flatnonzero(shapely.contains_xy(bounds, *xy.T))[-1]
    cut = shapely.LineString(xy[: last_inside + 1])  # ends at a corner inside the bounds
    street = Surroundings(bounds, np.array([], dtype=object), read_osm_file(PALACE).ways.geometry.values)
    out = open_outer_closures(np.array([cut]), np.zeros(1, dtype=int), np.zeros(1, bool), 1, street)
    assert shapely.is_empty(out[0])


def test_what_counts_as_standing_outside_buildings():
    # Courtyards have service roads (the palace's has two) and arcades have passages: neither tells
    # which side of a wall is building. Streets, mapped sidewalks and crossings do.
    tags = [
        {"highway": "residential"},
        {"highway": "primary_link"},
        {"highway": "service"},
        {"highway": "residential", "tunnel": "building_passage"},
        {"highway": "footway", "footway": "sidewalk"},
        {"highway": "footway", "footway": "crossing", "covered": "yes"},
        {"highway": "footway"},
    ]
    assert outside_buildings(tags).tolist() == [True, True, False, False, True, False, False]
