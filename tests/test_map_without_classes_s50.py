"""A map with no class on any feature is refused naming its first polygon, as when only some lack one."""

from __future__ import annotations

import json

import pytest

from curbside.cli.osmseg import main as osmseg_main

SQUARE = [[[-122.397, 37.790], [-122.3969, 37.790], [-122.3969, 37.7901], [-122.397, 37.7901],
           [-122.397, 37.790]]]


@pytest.mark.parametrize("props", [{}, None, {"name": "my sidewalk"}], ids=["empty", "none", "other-keys"])
def test_a_map_with_no_class_anywhere_names_its_first_polygon(tmp_path, capsys, props):
    point = {"type": "Point", "coordinates": [-122.397, 37.79]}
    marker = {"type": "Feature", "properties": {}, "geometry": point}
    polygon = {"type": "Feature", "id": "new-1", "properties": props,
               "geometry": {"type": "Polygon", "coordinates": SQUARE}}
    path = tmp_path / "drawn.geojson"
    path.write_text(json.dumps({"type": "FeatureCollection", "features": [marker, polygon]}))
    assert osmseg_main(["show", str(path), "-o", str(tmp_path / "out.png")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and str(path) in err and "Traceback" not in err
    assert "feature 1 (id 'new-1') has no properties.class (1 such polygon(s))" in err
    assert not (tmp_path / "out.png").exists()
