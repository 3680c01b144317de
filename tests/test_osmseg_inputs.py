"""osmseg build on awkward real-world input: each failure of issue 10 on a fixture, and bad files.

Fixtures are written by ``tests/data/osm/make_fixtures.py``; each scene's docstring there says which
failure it reproduces.
"""

from __future__ import annotations

import bz2
import gzip
from pathlib import Path

import numpy as np
import osmium
import pytest
import shapely

from curbside.cli.osmseg import main as osmseg_main
from curbside.osmseg import sidewalks
from curbside.osmseg.build import build_map
from curbside.osmseg.reader import read_osm_file
from curbside.osmseg.streets import carriageway_width
from curbside.osmseg.tags import first_number, metres
from curbside.projection import LocalFrame

OSM_DATA = Path(__file__).parent / "data" / "osm"
ORIGIN = (-122.4000, 37.7900)


def lonlat_bounds(layers) -> np.ndarray:
    """(west, south, east, north) of a map, degrees."""
    return layers.gdf.to_crs(4326).total_bounds


def test_feet_in_whole_number_tags_build():
    # Every width is a whole number, one is in feet: the column used to become integers and the
    # conversion to metres raised "cannot safely cast non-equivalent object to int64".
    osm = read_osm_file(OSM_DATA / "feet-widths.osm")
    width_m, tagged = carriageway_width(osm.ways)
    assert width_m[osm.ways["name"].eq("Imperial Street").to_numpy()] == pytest.approx([40 * 0.3048])
    assert tagged.all()
    layers = build_map(osm_file=OSM_DATA / "feet-widths.osm")
    assert {"building", "street", "sidewalk"} <= set(layers.gdf["class"])


@pytest.mark.parametrize(
    ("text", "expected_m"),
    [("40'", 12.192), ("6'6\"", 1.9812), ("24 ft", 7.3152), ("7,5", 7.5), ("3 km", 3000.0), ("12m", 12.0),
     ("12 m;14", 12.0), ("1 mi", 1609.344), ("0", np.nan), ("-3", np.nan), ("wide", np.nan),
     ("5 parsecs", np.nan), ("2.5.1", np.nan), ("inf", np.nan), (None, np.nan)],
)  # fmt: skip
def test_metres_parses_each_value_alone(text, expected_m):
    # Alone, so that the column has a single type, the case that used to crash.
    out = metres(__import__("pandas").Series([text], dtype=object))
    np.testing.assert_allclose(out, [expected_m])


def test_first_number_ignores_non_finite():
    out = first_number(__import__("pandas").Series(["inf", "nan;2", "-1;0", "x"]))
    np.testing.assert_array_equal(out, [np.nan, 2.0, -1.0, np.nan])


def test_map_is_clipped_to_the_bounds_the_file_declares():
    path = OSM_DATA / "past-bounds.osm"
    declared = read_osm_file(path).bounds
    assert declared is not None
    layers = build_map(osm_file=path)
    west, south, east, north = lonlat_bounds(layers)
    tolerance = 1e-6
    assert declared[0] - tolerance <= west and east <= declared[2] + tolerance
    assert declared[1] - tolerance <= south and north <= declared[3] + tolerance
    assert layers.meta["bbox"] == pytest.approx(declared, abs=1e-7)
    # Before the fix the street ran 1.5 km east, the service road 400 m south.
    assert east - west < 0.0025


def test_bbox_asked_for_wins_over_declared_bounds():
    lon0, lat0 = ORIGIN
    bbox = (lon0 - 0.0004, lat0 - 0.0003, lon0 + 0.0004, lat0 + 0.0003)
    layers = build_map(bbox, OSM_DATA / "past-bounds.osm")
    west, south, east, north = lonlat_bounds(layers)
    assert bbox[0] - 1e-6 <= west and east <= bbox[2] + 1e-6 and bbox[1] - 1e-6 <= south


def test_file_without_bounds_keeps_its_whole_extent():
    path = OSM_DATA / "wide-road.osm"
    assert read_osm_file(path).bounds is None
    west, _, east, _ = lonlat_bounds(build_map(osm_file=path))
    assert east - west > 0.0013  # the 120 m road and its sidewalks (about 0.00137 degrees)


def test_bounds_without_data_is_one_line_error(tmp_path, capsys):
    text = (OSM_DATA / "past-bounds.osm").read_text()
    lon_shift = text.replace('minlon="-122.4', 'minlon="-121.4').replace('maxlon="-122.3', 'maxlon="-121.3')
    path = tmp_path / "elsewhere.osm"
    path.write_text(lon_shift)
    out = tmp_path / "map.geojson"
    assert osmseg_main(["build", "--osm", str(path), "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert "inside the bounds the file declares" in err and len(err.strip().splitlines()) == 1
    assert not out.exists()


def test_building_layer_is_a_clean_coverage():
    layers = build_map(osm_file=OSM_DATA / "overlapping-buildings.osm")
    buildings = layers.layer("building").geometry.values
    # Drawn: 2400 + 600 (inside) + 1575 + 750 m^2 with 550 m^2 of overlaps; before: 5343 != 4415.
    assert shapely.area(buildings).sum() == pytest.approx(shapely.union_all(buildings).area, abs=1e-3)
    assert shapely.union_all(buildings).area == pytest.approx(2400 + 1575 + 750 - 175 - 125, rel=0.01)
    # The tower inside its podium keeps its own outline.
    assert len(buildings) == 4
    assert np.isclose(shapely.area(buildings), 600, rtol=0.01).any()


def test_way_is_cut_where_the_file_lacks_nodes(caplog):
    path = OSM_DATA / "cut-at-bounds.osm"
    osm = read_osm_file(path)
    loop = osm.ways[osm.ways["name"] == "Loop Street"]
    assert len(loop) == 2  # two runs, not one line joined across the missing nodes
    with caplog.at_level("WARNING"):
        layers = build_map(osm_file=path)
    frame = LocalFrame(layers.crs)
    origin = shapely.Point(*frame.to_xy(*ORIGIN))
    street = layers.union("street")
    assert not street.contains(origin)
    # The building that lacks a node but keeps one outside the bounds is no simple cut: where its
    # ring left the bounds is unknown, so it is dropped (closing it over its nodes drew a triangle).
    assert len(layers.layer("building")) == 1
    assert "1 dropped (nodes outside the bounds the file declares)" in caplog.text
    assert "2 ways refer to nodes the file lacks" in caplog.text and "complete_ways" in caplog.text


def test_dissolve_survives_cells_that_are_not_a_clean_coverage():
    # Two cells of one row that overlap by a sliver (their shared edge is not matched): GEOS's
    # coverage union raises "CoverageUnion cannot process incorrectly noded inputs" on this row.
    square = shapely.Polygon([(1, 1), (1, 0), (0, 0), (0, 1), (1, 1)])
    sliver = shapely.Polygon([(1, 0), (0.9, 1), (2, 1), (2, 0), (1, 0)])
    table = np.array([[square, sliver], [shapely.box(5, 5, 6, 6), None]], dtype=object)
    if shapely.geos_version >= (3, 14, 0):
        with pytest.raises(shapely.errors.GEOSException, match="incorrectly noded"):
            shapely.coverage_union_all(table, axis=1)
    rows = sidewalks.dissolve_rows(table)
    assert shapely.is_valid(rows).all()
    assert rows[0].area == pytest.approx(2.0) and rows[1].area == pytest.approx(1.0)


# --- Bad files: one line, exit status 2, nothing written ---------------------------------------------


def _bad_files(tmp: Path) -> dict[str, Path]:
    """One file per kind of bad input."""
    good = (OSM_DATA / "crossroads-mapped-sidewalks.osm").read_bytes()
    files = {
        "empty.osm": b"",
        "html.osm": b'<?xml version="1.0"?>\n<html><body>not OSM</body></html>\n',
        "gpx.osm": b'<?xml version="1.0"?>\n<gpx version="1.1"><trk/></gpx>\n',
        "binary.osm": b"PK\x03\x04\x00\x00binary",
        "truncated.osm": good[: len(good) // 2],
        "truncated.osm.gz": gzip.compress(good)[:300],
        "truncated.osm.bz2": bz2.compress(good)[:300],
        "text-named.osm.pbf": b"this is not a PBF file\n",
        "no-data.osm": b'<?xml version="1.0"?>\n<osm version="0.6"></osm>\n',
        "bad-coordinates.osm": b'<?xml version="1.0"?>\n<osm version="0.6"><node id="1" lat="95" lon="400"/>'
        b'<way id="1"><nd ref="1"/><nd ref="1"/><tag k="highway" v="residential"/></way></osm>\n',
        "only-relations.osm": b'<?xml version="1.0"?>\n<osm version="0.6"><relation id="5">'
        b'<member type="way" ref="1" role="outer"/><tag k="type" v="multipolygon"/>'
        b'<tag k="building" v="yes"/></relation></osm>\n',
        "nodes-only.osm": b'<?xml version="1.0"?>\n<osm version="0.6">'
        b'<node id="1" lat="37.79" lon="-122.4"><tag k="amenity" v="bench"/></node></osm>\n',
        "map.geojson": b'{"type": "FeatureCollection", "features": []}',
    }
    for name, data in files.items():
        (tmp / name).write_bytes(data)
    truncated_pbf = tmp / "whole.osm.pbf"
    with osmium.SimpleWriter(str(truncated_pbf)) as writer:
        for obj in osmium.FileProcessor(str(OSM_DATA / "crossroads-mapped-sidewalks.osm")):
            writer.add(obj)
    (tmp / "truncated.osm.pbf").write_bytes(truncated_pbf.read_bytes()[:200])
    truncated_pbf.unlink()
    (tmp / "folder.osm").mkdir()
    paths = {name: tmp / name for name in [*files, "truncated.osm.pbf", "folder.osm"]}
    paths["missing.osm"] = tmp / "missing.osm"
    return paths


def test_every_kind_of_bad_file_is_one_line_and_status_2(tmp_path, capsys):
    inputs = tmp_path / "inputs"
    inputs.mkdir()
    for name, path in _bad_files(inputs).items():
        out = tmp_path / f"{name}.geojson"
        status = osmseg_main(["build", "--osm", str(path), "-o", str(out)])
        err = capsys.readouterr().err
        assert status == 2, (name, err)
        lines = err.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith("osmseg: error: "), (name, err)
        assert "internal error" not in err and "Traceback" not in err, name
        assert not out.exists(), name
