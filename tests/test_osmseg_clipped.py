"""Extracts cut through their ways, and --bbox past a file's bounds (audit defects 3 and 4).

The simply cut extract is made here from the corpus's complete-ways cut of the Financial District
(``corpus/sf-financial-district.osm.bz2``): the same file without its nodes outside ``<bounds>``, as
``osmium extract --strategy simple`` writes it.
"""

from __future__ import annotations

import bz2
import logging
import math
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest
import shapely

from curbside.cli.osmseg import main as osmseg_main
from curbside.osmseg.build import build_map
from curbside.osmseg.clipped import MissingNodes, agreed_area, closed_rings
from curbside.osmseg.reader import bbox_polygon, read_osm_file
from curbside.projection import LocalFrame

OSM_DATA = Path(__file__).parent / "data" / "osm"
COMPLETE = OSM_DATA / "corpus" / "sf-financial-district.osm.bz2"
#: Buildings that kept under 10 % of their part inside the bounds when rings were closed over the
#: nodes the file has (audit).
AUDITED = ("w132125159", "w148710881", "w944032189")


def simple_cut(complete: Path, out: Path) -> dict[str, int]:
    """Write ``complete`` without the nodes outside its ``<bounds>``; count the ways that lose some."""
    root = ET.fromstring(bz2.decompress(complete.read_bytes()))
    b = root.find("bounds").attrib
    west, south, east, north = (float(b[k]) for k in ("minlon", "minlat", "maxlon", "maxlat"))
    for node in root.findall("node"):
        if not (west <= float(node.get("lon")) <= east and south <= float(node.get("lat")) <= north):
            root.remove(node)
    kept = {node.get("id") for node in root.iter("node")}
    counts = {"buildings": 0, "highways": 0}
    for way in root.iter("way"):
        tags = {t.get("k") for t in way.iter("tag")}
        if any(nd.get("ref") not in kept for nd in way.iter("nd")):
            counts["buildings"] += "building" in tags
            counts["highways"] += "highway" in tags and "building" not in tags
    out.write_bytes(ET.tostring(root, encoding="utf-8", xml_declaration=True))
    return counts


@pytest.fixture(scope="module")
def cut(tmp_path_factory) -> tuple[Path, dict[str, int]]:
    path = tmp_path_factory.mktemp("cut") / "simple-cut.osm"
    return path, simple_cut(COMPLETE, path)


def _warnings(caplog) -> list[str]:
    return [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]


# --- Defect 3: a simply cut extract ---------------------------------------------------------------


def test_cut_buildings_keep_their_part_inside_the_bounds(cut):
    path, _ = cut
    lacking = read_osm_file(path)
    whole = read_osm_file(COMPLETE)
    window = bbox_polygon(whole.bounds, whole.crs)
    inside = shapely.intersection(whole.areas.geometry.values, window)
    truth = dict(zip(whole.areas["osm_id"], inside, strict=True))
    got = dict(zip(lacking.areas["osm_id"], lacking.areas.geometry.to_crs(whole.crs).values, strict=True))
    for osm_id in AUDITED:
        inside, drawn = truth[osm_id], got.get(osm_id, shapely.Polygon())
        # Closed over the nodes the file has, each kept under 10 % of it (or was dropped).
        assert drawn.intersection(inside).area >= 0.85 * inside.area, osm_id
        assert drawn.difference(inside).area <= 0.02 * inside.area, osm_id


def test_simple_cut_builds_nearly_the_complete_map_and_says_so(cut, caplog):
    path, counts = cut
    with caplog.at_level(logging.WARNING):
        reference = build_map(osm_file=COMPLETE)
    assert _warnings(caplog) == []
    with caplog.at_level(logging.WARNING):
        layers = build_map(osm_file=path)
    built, true = layers.union("building"), reference.union("building")
    # Closed over the nodes they have, the buildings covered 84 % of the complete map's; now 96 %.
    assert built.area >= 0.95 * true.area
    assert built.difference(true).area < 20.0
    assert layers.union("sidewalk").intersection(true).area < 150.0  # was 312 m^2
    (message,) = [m for m in _warnings(caplog) if "cut through its ways" in m]
    assert path.name in message and "complete_ways" in message
    ways = counts["buildings"] + counts["highways"]
    assert f"{ways} ways refer to nodes the file lacks: {counts['buildings']} buildings" in message
    assert counts["buildings"] >= 20  # the audit's clip: 21 buildings, 36 highways


def test_ring_cut_by_the_bounds_is_closed_along_them():
    bounds = (-122.4010, 37.7890, -122.4000, 37.7900)
    frame = LocalFrame.around(-122.4005, 37.7895)
    x0, y0 = frame.to_xy(np.array([-122.4000]), np.array([37.7895]))
    x0 = x0 - 8.0
    # A 30 x 20 m building 8 m inside the east bound and 22 m past it, turned by 0 and 20 degrees.
    for angle in (0.0, 20.0):
        c, s = math.cos(math.radians(angle)), math.sin(math.radians(angle))
        corners = [(-10.0, -10.0), (20.0, -10.0), (20.0, 10.0), (-10.0, 10.0)]
        xy = np.array([(x0[0] + c * u - s * v, y0[0] + s * u + c * v) for u, v in corners])
        true = shapely.Polygon(xy).intersection(bbox_polygon(bounds, frame.crs))
        lons, lats = frame.to_lonlat(xy[:, 0], xy[:, 1])
        locations = [(float(a), float(b)) for a, b in zip(lons, lats, strict=True)]
        locations = [locations[0], None, None, locations[3], locations[0]]  # east corners missing
        rings = closed_rings(locations, bounds, MissingNodes())
        assert rings is not None
        polys = [shapely.Polygon(np.column_stack(frame.to_xy(*np.array(r).T))) for r in rings]
        (area,) = agreed_area(np.array(polys[:1], dtype=object), np.array(polys[1:], dtype=object))
        assert area.difference(true).area < 0.05 * true.area, angle
        # Walls at an angle to the bounds: only what both guesses agree on (79 % at 20 degrees).
        assert area.intersection(true).area > (0.99 if angle == 0 else 0.75) * true.area, angle


def test_rings_that_cannot_be_closed_soundly_are_dropped():
    bounds = (-122.4010, 37.7890, -122.4000, 37.7900)
    missing = MissingNodes()
    a, b, c = (-122.4004, 37.7894), (-122.4002, 37.7894), (-122.4004, 37.7896)
    assert closed_rings([a, b, None, c, a], None, missing) is None  # no bounds
    assert closed_rings([a, None, None, None, a], bounds, missing) is None  # one node
    assert closed_rings([a, (-122.3990, 37.7894), None, c, a], bounds, missing) is None  # one outside
    assert sum(missing.dropped.values()) == 3 and len(missing.dropped) == 3


# --- Defect 4: --bbox past the bounds a file declares ----------------------------------------------


def test_bbox_past_the_bounds_is_cut_to_them_with_a_warning(caplog):
    path = OSM_DATA / "past-bounds.osm"
    west, south, east, north = read_osm_file(path).bounds
    asked = (west + 0.5 * (east - west), south, east + 0.5 * (east - west), north)
    with caplog.at_level(logging.WARNING):
        layers = build_map(asked, path)
    (message,) = [m for m in _warnings(caplog) if "reaches past the bounds" in m]
    assert path.name in message and "50 % of the bbox left out" in message
    covered = [asked[0], south, east, north]
    assert layers.meta["bbox"] == pytest.approx(covered, abs=1e-7)
    assert layers.meta["bbox_asked"] == pytest.approx(asked)
    # Before, the street ran on past the bounds with nothing beside it: open walkable space.
    assert layers.gdf.to_crs(4326).total_bounds[2] <= east + 1e-6


def test_bbox_inside_the_bounds_is_taken_as_it_is(caplog):
    path = OSM_DATA / "past-bounds.osm"
    west, south, east, north = read_osm_file(path).bounds
    asked = (west, south, 0.5 * (west + east), north)
    with caplog.at_level(logging.WARNING):
        layers = build_map(asked, path)
    assert _warnings(caplog) == []
    assert layers.meta["bbox"] == pytest.approx(asked, abs=1e-7) and "bbox_asked" not in layers.meta


def test_bbox_outside_the_bounds_is_one_line_error(tmp_path, capsys):
    path = OSM_DATA / "past-bounds.osm"
    west, south, east, north = read_osm_file(path).bounds
    out = tmp_path / "map.geojson"
    bbox = [str(v) for v in (east + 0.001, south, east + 0.002, north)]
    assert osmseg_main(["build", "--osm", str(path), "--bbox", *bbox, "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "lies outside the bounds the file declares" in err
    assert not out.exists()
