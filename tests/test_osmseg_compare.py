"""osmseg compare (per-class areas, IoU, boundary distance over the common extent) and import-datasf."""

from __future__ import annotations

import json
import math

import geopandas as gpd
import numpy as np
import pytest
import shapely

from curbside.cli.osmseg import main
from curbside.errors import CurbsideInputError
from curbside.osmseg.compare import compare_maps
from curbside.osmseg.datasf import read_datasf
from curbside.osmseg.mapio import MapLayers, read_map, write_map
from curbside.projection import WGS84

UTM10 = "EPSG:32610"
X0, Y0 = 552_000.0, 4_183_000.0  # downtown San Francisco, UTM zone 10N


def _layers(rows: list[tuple[str, shapely.Geometry]], extent: shapely.Geometry | None = None) -> MapLayers:
    """A map from (class, polygon in metres from (X0, Y0)) rows; ``extent`` (metres) becomes meta bbox."""
    gdf = gpd.GeoDataFrame(
        {"class": [r[0] for r in rows], "segment_id": None, "street": None, "side": None},
        geometry=[shapely.affinity.translate(r[1], X0, Y0) for r in rows],
        crs=UTM10,
    )
    meta = {}
    if extent is not None:
        box = gpd.GeoSeries([shapely.affinity.translate(extent, X0, Y0)], crs=UTM10).to_crs(WGS84)
        meta["bbox"] = [float(v) for v in box.total_bounds]
    return MapLayers(gdf, meta)


def _common_extent_m(*layers: MapLayers) -> shapely.Geometry:
    """The intersection of the maps' WGS84 bboxes, in metres from (X0, Y0)."""
    bounds = np.array([m.meta["bbox"] for m in layers])
    box = shapely.box(*bounds[:, :2].max(axis=0), *bounds[:, 2:].min(axis=0))
    utm = gpd.GeoSeries([box], crs=WGS84).to_crs(UTM10).iloc[0]
    return shapely.affinity.translate(utm, -X0, -Y0)


def _brute_boundary_distances(
    a: shapely.Geometry, b: shapely.Geometry, step: float
) -> tuple[np.ndarray, np.ndarray]:
    """Independent oracle: densified outline vertices of one shape, distance to the other's outline."""
    out = []
    for src, dst in ((a, b), (b, a)):
        ring = shapely.segmentize(src.boundary, step / 4)
        points = shapely.points(shapely.get_coordinates(ring))
        out.append(shapely.distance(points, dst.boundary))
    return out[0], out[1]


def test_identical_maps_agree_perfectly(test_data):
    layers = read_map(test_data / "maps" / "crossroads.geojson")
    table = compare_maps(layers, layers).table
    assert list(table.index) == ["building", "street", "crosswalk", "sidewalk"]
    np.testing.assert_allclose(table["iou"], 1.0)
    np.testing.assert_allclose(table["boundary_mean_m"], 0.0, atol=1e-6)
    np.testing.assert_allclose(table["area_a_m2"], table["area_b_m2"])
    assert (table["count_a"] == table["count_b"]).all()


@pytest.mark.parametrize(("dx", "dy"), [(2.0, 0.0), (0.7, -1.3)])
def test_shifted_square_iou_and_boundary_distance(dx, dy):
    square = shapely.box(0, 0, 20, 20)
    moved = shapely.affinity.translate(square, dx, dy)
    extent = shapely.box(-10, -10, 30, 30)
    a, b = _layers([("building", square)], extent), _layers([("building", moved)], extent)
    result = compare_maps(a, b)
    row = result.table.loc["building"]
    assert row["iou"] == pytest.approx(square.intersection(moved).area / square.union(moved).area, rel=1e-6)
    assert row["area_a_m2"] == pytest.approx(400, rel=1e-6)
    a_to_b, b_to_a = _brute_boundary_distances(square, moved, result.boundary_step_m)
    both = np.concatenate([a_to_b, b_to_a])
    assert row["boundary_mean_m"] == pytest.approx(both.mean(), abs=0.05)
    assert row["boundary_median_m"] == pytest.approx(np.median(both), abs=0.1)
    assert row["boundary_a_to_b_m"] == pytest.approx(a_to_b.mean(), abs=0.05)
    assert row["boundary_b_to_a_m"] == pytest.approx(b_to_a.mean(), abs=0.05)


def test_directed_boundary_distances_point_at_the_map_with_extra_outlines():
    extent = shapely.box(-10, -10, 100, 60)
    shared, extra = shapely.box(0, 0, 20, 20), shapely.box(60, 30, 80, 50)
    row = compare_maps(
        _layers([("building", shared), ("building", extra)], extent), _layers([("building", shared)], extent)
    ).table.loc["building"]
    assert row["boundary_b_to_a_m"] == pytest.approx(0.0, abs=1e-6)
    assert row["boundary_a_to_b_m"] > 10


def test_only_the_overlap_of_the_extents_is_compared():
    inside, outside = shapely.box(10, 10, 30, 30), shapely.box(70, 10, 90, 30)
    a = _layers([("building", inside), ("building", outside)], shapely.box(0, 0, 100, 50))
    b = _layers([("building", inside)], shapely.box(0, 0, 50, 50))
    result = compare_maps(a, b)
    row = result.table.loc["building"]
    assert row["count_a"] == 1 and row["count_b"] == 1
    assert row["iou"] == pytest.approx(1.0)
    assert row["area_a_m2"] == pytest.approx(inside.area, rel=1e-6)
    assert result.extent_area_m2 == pytest.approx(_common_extent_m(a, b).area, rel=1e-6)
    assert result.extent_area_m2 == pytest.approx(50 * 50, rel=0.05)  # B's, not A's twice as large


def test_a_building_cut_by_the_extent_counts_only_its_inside_part():
    crossing = shapely.box(40, 10, 60, 30)  # half inside the common extent x < 50
    a = _layers([("building", crossing)], shapely.box(0, 0, 100, 50))
    b = _layers([("building", shapely.box(10, 10, 20, 20))], shapely.box(0, 0, 50, 50))
    row = compare_maps(a, b).table.loc["building"]
    assert row["area_a_m2"] == pytest.approx(crossing.intersection(_common_extent_m(a, b)).area, rel=1e-6)
    assert row["area_a_m2"] < 0.6 * crossing.area
    assert row["iou"] == pytest.approx(0.0)
    # the extent's edge at x = 50 is no outline: A's nearest outline to B's square is x = 40
    assert row["boundary_mean_m"] > 10


def test_missing_classes_are_not_applicable_and_absent_ones_in_range_are_zero():
    extent = shapely.box(0, 0, 100, 100)
    a = _layers([("building", shapely.box(0, 0, 10, 10)), ("sidewalk", shapely.box(0, 12, 10, 14)),
                 ("street", shapely.box(0, 20, 100, 30))], extent)
    b = _layers([("building", shapely.box(0, 0, 10, 10)), ("street", shapely.box(0, 200, 100, 210))],
                shapely.box(0, 0, 100, 300))
    table = compare_maps(a, b).table
    assert "crosswalk" not in table.index
    assert math.isnan(table.loc["sidewalk", "area_b_m2"]) and math.isnan(table.loc["sidewalk", "iou"])
    assert math.isnan(table.loc["sidewalk", "count_b"])
    assert table.loc["street", "area_b_m2"] == 0 and table.loc["street", "iou"] == 0
    assert math.isnan(table.loc["street", "boundary_mean_m"])


def test_maps_that_do_not_overlap_are_an_input_error():
    a = _layers([("building", shapely.box(0, 0, 10, 10))])
    b = _layers([("building", shapely.box(500, 500, 510, 510))])
    with pytest.raises(CurbsideInputError, match="does not overlap"):
        compare_maps(a, b, name_b="b.geojson")


def test_compare_cli_prints_the_table_and_writes_json(tmp_path, test_data, capsys):
    a = test_data / "maps" / "crossroads.geojson"
    layers = read_map(a)
    layers.gdf["geometry"] = layers.gdf.geometry.translate(1.5, 0.0)
    keep = layers.gdf["class"] != "sidewalk"
    b = write_map(MapLayers(layers.gdf[keep], {}), tmp_path / "b.geojson")
    out = tmp_path / "cmp.json"
    assert main(["compare", str(a), str(b), "--json", str(out)]) == 0
    text = capsys.readouterr().out
    assert "overlap of the two maps' extents" in text
    assert "n/a" in text.splitlines()[-1] and text.splitlines()[-1].startswith("sidewalk")
    doc = json.loads(out.read_text())
    assert doc["classes"]["sidewalk"]["iou"] is None
    assert 0 < doc["classes"]["building"]["iou"] < 1
    assert doc["classes"]["building"]["count_a"] == 4


def test_compare_cli_missing_map_exits_2(tmp_path, test_data, capsys):
    out = tmp_path / "cmp.json"
    code = main(["compare", str(test_data / "maps" / "crossroads.geojson"), str(tmp_path / "no.geojson"),
                 "--json", str(out)])
    assert code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "no.geojson: no such map file" in err
    assert not out.exists()


# --- DataSF ---------------------------------------------------------------------------------------


@pytest.fixture
def tiles(test_data):
    """Two DataSF tiles trimmed to the same small box: overlapping coverage, holes, invalid rings."""
    return [test_data / "maps" / f"datasf-{tile}-trimmed.topojson" for tile in ("3_1", "4_1")]


def _raw(tiles) -> np.ndarray:
    raw = gpd.GeoSeries(
        np.concatenate([gpd.read_file(t).geometry.to_numpy() for t in tiles]), crs=WGS84
    ).to_crs(UTM10)
    return shapely.make_valid(raw.to_numpy())


def test_datasf_reader_repairs_dedupes_and_keeps_area(tiles):
    layers = read_datasf(tiles)
    geoms = layers.gdf.to_crs(UTM10).geometry.to_numpy()
    assert set(layers.gdf["class"]) == {"building"}
    assert shapely.is_valid(geoms).all()
    assert set(shapely.get_type_id(geoms)) == {shapely.GeometryType.POLYGON}
    left, right = shapely.STRtree(geoms).query(geoms, predicate="intersects")
    pair = left < right
    iou = shapely.area(shapely.intersection(geoms[left[pair]], geoms[right[pair]])) / shapely.area(
        shapely.union(geoms[left[pair]], geoms[right[pair]])
    )
    assert (iou < layers.meta["params"]["duplicate_iou"]).all()
    raw = _raw(tiles)
    assert len(geoms) < sum(len(shapely.get_parts(g)) for g in raw)  # the cross-tile copy went
    assert shapely.union_all(geoms).area == pytest.approx(shapely.union_all(raw).area, rel=0.01)
    assert "DataSF" in layers.meta["attribution"]


def test_datasf_inner_rings_are_holes_unless_filled(tiles):
    holes = read_datasf(tiles)
    filled = read_datasf(tiles, fill_holes=True)
    assert shapely.get_num_interior_rings(holes.gdf.geometry.to_numpy()).sum() > 0
    assert shapely.get_num_interior_rings(filled.gdf.geometry.to_numpy()).sum() == 0
    assert filled.gdf.area.sum() > holes.gdf.area.sum()


def test_datasf_bbox_keeps_the_footprints_that_touch_it(tiles):
    everything = read_datasf(tiles)
    lon, lat = everything.gdf.to_crs(WGS84).union_all().centroid.xy
    bbox = (lon[0] - 2e-4, lat[0] - 2e-4, lon[0] + 2e-4, lat[0] + 2e-4)
    some = read_datasf(tiles, bbox=bbox)
    assert 0 < len(some.gdf) < len(everything.gdf)
    assert shapely.intersects(some.gdf.to_crs(WGS84).geometry.to_numpy(), shapely.box(*bbox)).all()
    assert some.meta["bbox"] == list(bbox)
    with pytest.raises(CurbsideInputError, match="no building footprint"):
        read_datasf(tiles, bbox=(-122.5, 37.5, -122.49, 37.51))


def test_import_datasf_cli_writes_a_map_compare_reads(tmp_path, tiles, capsys):
    out = tmp_path / "datasf.geojson"
    assert main(["import-datasf", *map(str, tiles), "-o", str(out)]) == 0
    assert "building" in capsys.readouterr().out
    table = compare_maps(read_map(out), read_datasf(tiles)).table
    assert list(table.index) == ["building"]
    assert table.loc["building", "iou"] == pytest.approx(1.0, abs=1e-3)


def test_import_datasf_over_a_maps_streets_is_the_benchmarks_third_map(tmp_path, tiles, test_data, capsys):
    from curbside.evaluate.benchmark import datasf_osm_map

    streets = test_data / "evaluate" / "sf-path3.geojson"
    out = tmp_path / "datasf-over-osm.geojson"
    assert main(["import-datasf", *map(str, tiles), "--streets-from", str(streets), "-o", str(out)]) == 0
    assert "sidewalk" in capsys.readouterr().out
    combined, osm = read_map(out), read_map(streets)
    buildings = combined.layer("building").geometry.to_crs(WGS84)
    assert buildings.intersects(shapely.box(*osm.meta["bbox"])).all()
    for cls in ("street", "crosswalk", "sidewalk"):
        assert len(combined.layer(cls)) == len(osm.layer(cls))
    assert "DataSF" in combined.meta["attribution"] and "OpenStreetMap" in combined.meta["attribution"]
    same = datasf_osm_map(streets, tiles, tmp_path / "benchmark.geojson")
    assert same.read_bytes() == out.read_bytes()


def _truncated_tile(tmp_path, tiles):
    path = tmp_path / "tile.topojson"
    path.write_text(tiles[0].read_text()[:500])
    return [str(path)]


@pytest.mark.parametrize(
    ("make_args", "message"),
    [
        (lambda tmp, tiles: [str(tmp / "none.topojson")], "no such DataSF tile"),
        (_truncated_tile, "not readable as TopoJSON"),
        (lambda tmp, tiles: [str(tiles[0]), "--bbox", "-122.39", "37.80", "-122.40", "37.79"], "west"),
        (lambda tmp, tiles: [str(tiles[0]), "--bbox", "-122.5", "37.5", "-122.49", "37.51"], "no building"),
    ],
    ids=["missing", "truncated", "bbox-order", "bbox-empty"],
)
def test_import_datasf_bad_input_exits_2_and_writes_nothing(tmp_path, tiles, capsys, make_args, message):
    out = tmp_path / "out.geojson"
    assert main(["import-datasf", *make_args(tmp_path, tiles), "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and message in err and "Traceback" not in err
    assert not out.exists()
