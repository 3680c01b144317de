"""Map sources that ``osmseg compare``/``show``/``import-datasf`` take in: a declared non-WGS84 CRS, and
DataSF laid over a hand-made map without metadata bbox. Found by the osmseg compare/edit audit."""

from __future__ import annotations

import json

import geopandas as gpd
import pytest
import shapely

from curbside.cli.osmseg import main
from curbside.osmseg.mapio import read_map
from curbside.projection import WGS84


@pytest.fixture
def tiles(test_data):
    return [test_data / "maps" / f"datasf-{tile}-trimmed.topojson" for tile in ("3_1", "4_1")]


def test_datasf_over_a_map_without_bbox_stays_inside_that_map(tmp_path, tiles, test_data, capsys):
    # A hand-made streets map has no metadata bbox; the DataSF buildings used to be read over the
    # tiles' whole extent and the written map claimed all of it.
    street = shapely.box(-122.4105, 37.7940, -122.4100, 37.7946)
    doc = {"type": "FeatureCollection", "features": [
        {"type": "Feature", "properties": {"class": "street"}, "geometry": shapely.geometry.mapping(street)}]}
    hand = tmp_path / "hand.geojson"
    hand.write_text(json.dumps(doc), encoding="utf-8")
    bounds = read_map(hand).gdf.to_crs(WGS84).total_bounds
    out = tmp_path / "over.geojson"
    assert main(["import-datasf", *map(str, tiles), "--streets-from", str(hand), "-o", str(out)]) == 0
    capsys.readouterr()
    combined = read_map(out)
    assert combined.meta["bbox"] == pytest.approx(list(bounds))
    buildings = combined.layer("building").geometry.to_crs(WGS84)
    assert len(buildings) and buildings.intersects(shapely.box(*bounds)).all()
    every = gpd.GeoSeries(gpd.pd.concat([gpd.read_file(t).geometry for t in tiles]), crs=WGS84)
    assert (~every.intersects(street)).sum() > 10  # the tiles reach well beyond the map


def test_a_map_declaring_a_projected_crs_is_refused_even_with_small_numbers(tmp_path, test_data, capsys):
    # QGIS/GDAL export a "crs" member; kilometre coordinates of a projected CRS would pass for degrees.
    layers = read_map(test_data / "maps" / "crossroads.geojson")
    km = layers.gdf.to_crs(32610).set_geometry(
        shapely.transform(layers.gdf.to_crs(32610).geometry.values, lambda xy: xy / 1e4)
    )
    doc = json.loads(km.to_json())
    doc["crs"] = {"type": "name", "properties": {"name": "urn:ogc:def:crs:EPSG::32610"}}
    path = tmp_path / "km.geojson"
    path.write_text(json.dumps(doc), encoding="utf-8")
    assert main(["show", str(path), "-o", str(tmp_path / "km.png")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and str(path) in err and "EPSG::32610" in err and "Traceback" not in err
    assert not (tmp_path / "km.png").exists()


def test_a_crs_member_naming_wgs84_is_accepted(tmp_path, test_data):
    gdf = gpd.GeoDataFrame({"class": ["building"]}, geometry=[shapely.box(-122.4, 37.79, -122.399, 37.791)],
                           crs=4326)
    path = tmp_path / "gdal.geojson"
    gdf.to_file(path, driver="GeoJSON")
    assert "CRS84" in path.read_text() and len(read_map(path).gdf) == 1
