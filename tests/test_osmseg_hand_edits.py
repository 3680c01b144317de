"""Hand-edited maps (the editor's save format) read back by ``osmseg compare``: repaired, refused or
scored, never silently mis-scored. Found by the osmseg compare/edit audit."""

from __future__ import annotations

import json
import logging

import numpy as np
import pytest
import shapely

from curbside.cli.osmseg import main as osmseg_main
from curbside.osmseg.compare import compare_maps
from curbside.osmseg.edit import editor_data, file_features
from curbside.osmseg.mapio import read_map


@pytest.fixture
def crossroads(test_data):
    return test_data / "maps" / "crossroads.geojson"


def _saved(tmp_path, crossroads, edit, name="edited.geojson"):
    """What the editor's *Save* writes after ``edit(features)``: ids kept, metadata plus ``edits``."""
    data = editor_data(read_map(crossroads), crossroads.name, file_features(crossroads))
    features = edit([json.loads(json.dumps(f)) for f in data["features"]])
    doc = {"type": "FeatureCollection", "curbside": {**data["meta"], "edits": {"from": crossroads.name}},
           "features": features}
    path = tmp_path / name
    path.write_text(json.dumps(doc), encoding="utf-8")
    return path


def _square(x: float, y: float, d: float) -> list:
    return [[x, y], [x + d, y], [x + d, y + d], [x, y + d], [x, y]]


def test_deleting_the_edge_building_of_a_map_without_bbox_is_scored(tmp_path, crossroads):
    # crossroads.geojson has no metadata bbox: its extent is its polygons' bounds. Deleting the building
    # that reaches furthest out used to shrink the saved map's extent, so compare clipped the deleted
    # building away from A as well and reported the building layers as nearly identical.
    original = read_map(crossroads)
    buildings = original.layer("building").to_crs(4326)
    west = int(np.argmin(buildings.geometry.bounds["minx"].to_numpy()))
    victim = int(buildings.index[west])
    edited = _saved(tmp_path, crossroads, lambda fs: [f for f in fs if f["id"] != victim])
    assert json.loads(edited.read_text())["curbside"]["bbox"] == pytest.approx(
        list(original.gdf.to_crs(4326).total_bounds)
    )
    row = compare_maps(original, read_map(edited)).table.loc["building"]
    lost = float(original.gdf.geometry.iloc[victim].area)
    assert row["area_a_m2"] - row["area_b_m2"] == pytest.approx(lost, rel=1e-3)
    assert row["count_a"] - row["count_b"] == 1 and row["iou"] < 1


def test_a_spike_or_a_zero_area_polygon_leaves_no_stray_line(tmp_path, crossroads, caplog):
    # make_valid turns a spike into polygon + line and a collinear ring into a line; rasterised, a line
    # burns a one-cell wall, so only the polygonal part may be kept.
    x, y = -122.39700, 37.79030
    spike = [[x, y], [x + 2e-5, y], [x + 2e-5, y + 2e-5], [x, y + 2e-5], [x, y], [x - 2e-5, y], [x, y]]
    flat = [[x, y], [x + 1e-5, y], [x + 2e-5, y], [x, y]]

    def add(fs):
        return fs + [
            {"type": "Feature", "id": "new-1", "properties": {"class": "building", "edited": "drawn"},
             "geometry": {"type": "Polygon", "coordinates": [spike]}},
            {"type": "Feature", "id": "new-2", "properties": {"class": "crosswalk", "edited": "drawn"},
             "geometry": {"type": "Polygon", "coordinates": [flat]}},
        ]

    path = _saved(tmp_path, crossroads, add)
    with caplog.at_level(logging.WARNING, logger="curbside.osmseg.mapio"):
        layers = read_map(path)
    assert set(layers.gdf.geom_type) <= {"Polygon", "MultiPolygon"}
    assert len(layers.gdf) == len(read_map(crossroads).gdf) + 1  # the spike kept, the flat one dropped
    square_m2 = (2e-5 * 111_320) ** 2 * 0.79  # cos(37.79 deg) for the longitude
    assert shapely.area(layers.gdf.geometry.iloc[-1]) == pytest.approx(square_m2, rel=0.05)
    assert "repaired 2 invalid" in caplog.text and "1 had no area left" in caplog.text


@pytest.mark.parametrize(
    ("props", "message"),
    [({}, "feature 17 (id 'new-1') has no properties.class"),
     (None, "feature 17 (id 'new-1') has no properties.class"),
     ({"class": "Building"}, "unknown feature class 'Building' at feature 17 (id 'new-1')")],
    ids=["no-class", "no-properties", "wrong-case"],
)
def test_a_drawn_polygon_without_a_class_is_refused_naming_it(tmp_path, crossroads, capsys, props, message):
    x, y = -122.39700, 37.79030

    def add(fs):
        return fs + [{"type": "Feature", "id": "new-1", "properties": props,
                      "geometry": {"type": "Polygon", "coordinates": [_square(x, y, 2e-5)]}}]

    path = _saved(tmp_path, crossroads, add)
    assert osmseg_main(["compare", str(crossroads), str(path)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and str(path) in err and message in err and "Traceback" not in err


def test_a_marker_without_a_class_is_ignored_like_any_non_polygon(tmp_path, crossroads):
    def add(fs):
        return fs + [{"type": "Feature", "properties": {"marker-color": "#f00"},
                      "geometry": {"type": "Point", "coordinates": [-122.397, 37.7903]}}]

    path = _saved(tmp_path, crossroads, add)
    table = compare_maps(read_map(crossroads), read_map(path)).table
    assert table["iou"].to_numpy() == pytest.approx(1.0) and (table["boundary_mean_m"] < 1e-6).all()
