"""osmseg build: derivation invariants on hand-written scenes and the bundled extract, CLI, bad input."""

from __future__ import annotations

import bz2
import gzip
import itertools
import json
from pathlib import Path

import numpy as np
import osmium
import pytest
import shapely

from curbside import settings
from curbside.cli.osmseg import main as osmseg_main
from curbside.configio import from_dict, to_dict
from curbside.osmseg.build import build_map
from curbside.osmseg.config import SegmentationConfig
from curbside.osmseg.mapio import CLASSES, MapLayers, read_map, write_map
from curbside.osmseg.reader import read_osm_file
from curbside.osmseg.streets import mapped_sidewalks, share_of_length_inside

OSM_DATA = Path(__file__).parent / "data" / "osm"

def class_overlaps_m2(layers: MapLayers) -> dict[tuple[str, str], float]:
    """Overlap area (m^2) of every pair of classes."""
    unions = {cls: layers.union(cls) for cls in CLASSES}
    return {
        (a, b): shapely.intersection(unions[a], unions[b]).area for a, b in itertools.combinations(CLASSES, 2)
    }


def sidewalk_overlaps_m2(layers: MapLayers) -> float:
    """Total area shared by two different sidewalk segments."""
    geoms = layers.layer("sidewalk").geometry.values
    a, b = shapely.STRtree(geoms).query(geoms, predicate="intersects")
    keep = a < b
    return float(shapely.area(shapely.intersection(geoms[a[keep]], geoms[b[keep]])).sum())


def crosswalk_sidewalk_contacts(layers: MapLayers, tolerance_m: float = 0.05) -> np.ndarray:
    """For each crosswalk, how many distinct sidewalk segments touch it."""
    walks = layers.layer("crosswalk").geometry.values
    sidewalks = layers.layer("sidewalk").geometry.values
    walk_i, _ = shapely.STRtree(sidewalks).query(walks, predicate="dwithin", distance=tolerance_m)
    return np.bincount(walk_i, minlength=len(walks))


def crosswalk_ends_joined(layers: MapLayers, tolerance_m: float = 0.05) -> np.ndarray:
    """For each crosswalk, whether sidewalks touch both of its ends.

    The ends are the two halves of the crosswalk cut across its long axis (minimum rotated
    rectangle); each half must come within ``tolerance_m`` of some sidewalk segment.
    """
    walks = layers.layer("crosswalk").geometry.values
    sidewalk_union = layers.union("sidewalk")
    shapely.prepare(sidewalk_union)
    joined = np.zeros(len(walks), dtype=bool)
    rects = shapely.oriented_envelope(walks)
    for i, (walk, rect) in enumerate(zip(walks, rects, strict=True)):
        xy = shapely.get_coordinates(rect)[:4]
        edges = np.roll(xy, -1, axis=0) - xy
        long_edge = int(np.argmax(np.linalg.norm(edges, axis=1)))
        a, b = xy[long_edge], xy[(long_edge + 1) % 4]
        c, d = xy[(long_edge + 2) % 4], xy[(long_edge + 3) % 4]
        mid_ab, mid_cd = (a + b) / 2, (c + d) / 2
        halves = [shapely.Polygon([a, mid_ab, mid_cd, d]), shapely.Polygon([mid_ab, b, c, mid_cd])]
        joined[i] = all(
            shapely.dwithin(shapely.intersection(walk, h), sidewalk_union, tolerance_m) for h in halves
        )
    return joined


# --- Hand-written scenes ------------------------------------------------------------------------------

SCENES = ("crossroads-mapped-sidewalks", "crossroads-crossing-nodes", "wide-road", "building-passage")


@pytest.fixture(scope="module")
def scenes() -> dict[str, MapLayers]:
    return {name: build_map(osm_file=OSM_DATA / f"{name}.osm") for name in SCENES}


@pytest.mark.parametrize("name", SCENES)
def test_scene_polygons_valid_and_classes_disjoint(scenes, name):
    layers = scenes[name]
    assert shapely.is_valid(layers.gdf.geometry.values).all()
    assert set(layers.gdf.geom_type) == {"Polygon"}
    for pair, area in class_overlaps_m2(layers).items():
        assert area < 0.01, pair
    assert sidewalk_overlaps_m2(layers) < 0.01


@pytest.mark.parametrize("name", ["crossroads-mapped-sidewalks", "crossroads-crossing-nodes"])
def test_crossroads_blocks_and_crosswalks(scenes, name):
    layers = scenes[name]
    sidewalks = layers.layer("sidewalk")
    # Two streets, each split at the junction into two blocks, two sides each.
    assert len(sidewalks) == 8
    assert sidewalks["segment_id"].is_unique
    assert sidewalks["segment_id"].str.fullmatch(r"w\d+-[01]-[LR]").all()
    assert (sidewalks["segment_id"].str[-1] == sidewalks["side"].str[0].str.upper()).all()
    assert set(sidewalks["side"]) == {"left", "right"}
    assert set(sidewalks["street"]) == {"East Street", "North Street"}
    # East Street runs west to east: its left sidewalks lie north of it, its right ones south.
    east = sidewalks[sidewalks["street"] == "East Street"]
    road_y = shapely.get_coordinates(layers.layer("street").geometry.values).mean(axis=0)[1]
    side_y = shapely.get_coordinates(shapely.centroid(east.geometry.values))[:, 1]
    assert (side_y[east["side"].to_numpy() == "left"] > road_y).all()
    assert (side_y[east["side"].to_numpy() == "right"] < road_y).all()
    walks = layers.layer("crosswalk")
    assert len(walks) == 4
    assert crosswalk_ends_joined(layers).all()
    # Each crosswalk spans the 8 m carriageway and reaches just past both curbs.
    bounds = shapely.bounds(walks.geometry.values)
    spans = np.maximum(bounds[:, 2] - bounds[:, 0], bounds[:, 3] - bounds[:, 1])
    assert ((spans >= 8.0) & (spans <= 8.0 + 2 * SegmentationConfig().crosswalk_overlap_m + 0.2)).all()


def test_unmarked_crossings_can_stay_street():
    path = OSM_DATA / "crossroads-crossing-nodes.osm"
    as_crosswalk = build_map(osm_file=path, config=SegmentationConfig(unmarked_crossing_as="crosswalk"))
    as_street = build_map(osm_file=path, config=SegmentationConfig(unmarked_crossing_as="street"))
    # The two crossings tagged crossing=unmarked go; the two signalised ones stay.
    assert len(as_crosswalk.layer("crosswalk")) == 4
    assert len(as_street.layer("crosswalk")) == 2
    street_gain = as_street.union("street").area - as_crosswalk.union("street").area
    assert street_gain == pytest.approx(as_crosswalk.union("crosswalk").area / 2, rel=0.2)


def test_segmentation_config_changes_the_map_and_is_recorded_in_its_metadata():
    path = OSM_DATA / "crossroads-crossing-nodes.osm"
    default = build_map(osm_file=path)
    wide = build_map(osm_file=path, config=SegmentationConfig(crosswalk_width_m=4.5))
    assert default.meta["params"] == to_dict(SegmentationConfig())
    assert default.meta["params"]["crosswalk_width_m"] == 3.0
    assert wide.meta["params"]["crosswalk_width_m"] == 4.5
    # The crossing nodes carry no width: each strip is 1.5 times as wide, as long as before.
    ratio = wide.union("crosswalk").area / default.union("crosswalk").area
    assert ratio == pytest.approx(1.5, rel=0.1)
    assert len(wide.layer("crosswalk")) == len(default.layer("crosswalk"))
    # The sidewalks give way to the wider crosswalks.
    assert wide.union("sidewalk").area < default.union("sidewalk").area


def test_mapped_sidewalks_are_not_inside_street(scenes):
    layers = scenes["crossroads-mapped-sidewalks"]
    osm = read_osm_file(OSM_DATA / "crossroads-mapped-sidewalks.osm")
    lines = osm.ways[osm.ways["footway"] == "sidewalk"].geometry.values
    assert len(lines) == 8
    street = layers.union("street")
    assert shapely.length(shapely.intersection(lines, street)).sum() == 0
    # ... and they lie in sidewalk segments.
    covered = shapely.length(shapely.intersection(lines, layers.union("sidewalk"))).sum()
    assert covered > 0.9 * shapely.length(lines).sum() - 4 * 12.0


def test_share_of_length_inside_is_the_share_inside_walls():
    lines = np.array([shapely.LineString([(0, 0), (100, 0)]), shapely.LineString([(0, 10), (100, 10)])])
    buildings = np.array([shapely.box(10, -1, 30, 1), shapely.box(60, 9, 65, 20), shapely.box(0, 50, 9, 60)])
    assert share_of_length_inside(lines, buildings) == pytest.approx((20 + 5) / 200)
    assert share_of_length_inside(lines[:0], buildings) == 0.0
    assert share_of_length_inside(lines, buildings[:0]) == 0.0


def test_buildings_misaligned_with_mapped_sidewalks_soften_the_walls(scenes, monkeypatch, tmp_path, capsys):
    from curbside.localize.filter import MapConfig, MapLikelihood
    from curbside.localize.raster import rasterize_map
    from curbside.osmseg import build as build_mod

    aligned = scenes["crossroads-mapped-sidewalks"]
    assert aligned.meta["sidewalk_ways_in_buildings"] == 0.0
    derive = build_mod.derive_buildings

    def shifted(*args, **kwargs):  # the footprints drawn 4 m off, as from offset imagery
        gdf = derive(*args, **kwargs)
        return gdf.set_geometry(shapely.transform(gdf.geometry.values, lambda xy: xy + np.array([4.0, 4.0])))

    monkeypatch.setattr(build_mod, "derive_buildings", shifted)
    misaligned = build_map(osm_file=OSM_DATA / "crossroads-mapped-sidewalks.osm")
    assert misaligned.meta["sidewalk_ways_in_buildings"] > 0.02
    for pair, area in class_overlaps_m2(misaligned).items():
        assert area < 0.01, pair  # the classes stay disjoint: only the footways show the conflict
    again = read_map(write_map(misaligned, tmp_path / "misaligned.geojson"))
    raster = rasterize_map(again, 0.5)
    assert raster.sidewalk_under_buildings == misaligned.meta["sidewalk_ways_in_buildings"]
    assert MapLikelihood(raster, MapConfig()).wall_tolerance_m == 1.5
    assert MapLikelihood(rasterize_map(aligned, 0.5), MapConfig()).wall_tolerance_m == 0.0
    osm_file = str(OSM_DATA / "crossroads-mapped-sidewalks.osm")
    assert osmseg_main(["build", "--osm", osm_file, "-o", str(tmp_path / "cli.geojson")]) == 0
    assert "run inside buildings: are the buildings misaligned" in capsys.readouterr().out
    monkeypatch.setattr(build_mod, "derive_buildings", derive)
    assert osmseg_main(["build", "--osm", osm_file, "-o", str(tmp_path / "aligned.geojson")]) == 0
    assert "inside buildings" not in capsys.readouterr().out


def test_width_tag_sets_carriageway(scenes):
    layers = scenes["wide-road"]
    street = layers.union("street")
    osm = read_osm_file(OSM_DATA / "wide-road.osm")
    centreline = osm.ways.geometry.values[0]
    assert street.area == pytest.approx(20.0 * centreline.length, rel=0.01)
    # The curbs run 10 m either side of the centreline.
    assert shapely.hausdorff_distance(street.exterior, centreline) == pytest.approx(10.0, abs=0.3)
    sides = layers.layer("sidewalk")
    assert sorted(sides["side"]) == ["left", "right"]
    assert set(sides["street"]) == {"Wide Avenue"}


def test_building_passage_is_carved_and_upper_levels_are_not(scenes):
    layers = scenes["building-passage"]
    osm = read_osm_file(OSM_DATA / "building-passage.osm")
    ways = osm.ways.set_index("osm_id")
    passage = ways.loc[ways["tunnel"] == "building_passage", "geometry"].iloc[0]
    roof_path = ways.loc[ways["layer"] == "4", "geometry"].iloc[0]
    buildings = layers.union("building")
    assert shapely.intersection(passage, buildings).length == 0
    assert shapely.intersection(roof_path, buildings).length > 0.5 * roof_path.length
    # A station's upper-level platform opens it; an office's does not.
    platforms = ways.loc[ways["highway"] == "platform", "geometry"]
    station_deck, office_deck = sorted(platforms, key=lambda g: g.centroid.y)
    assert shapely.intersection(station_deck, buildings).length == 0
    assert shapely.intersection(office_deck, buildings).length == pytest.approx(office_deck.length)
    # building=roof is not impenetrable.
    roof = osm.areas.loc[osm.areas["building"] == "roof", "geometry"].iloc[0]
    assert shapely.intersection(roof, buildings).area == 0


def test_multipolygon_relation_building():
    osm = read_osm_file(OSM_DATA / "relation-building.osm")
    assert list(osm.areas["osm_id"]) == ["r5000"]
    layers = build_map(osm_file=OSM_DATA / "relation-building.osm")
    building = layers.union("building")
    # 40 x 30 m with a 10 x 10 m courtyard (scene metres are approximate in UTM: 1%).
    assert building.area == pytest.approx(40 * 30 - 10 * 10, rel=0.01)
    assert len(shapely.get_interior_ring(layers.layer("building").geometry.values[0], 0).coords) == 5


# --- The bundled extract --------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def downtown() -> MapLayers:
    return build_map()


@pytest.fixture(scope="module")
def downtown_osm():
    return read_osm_file(settings.default_osm_file)


@pytest.mark.slow
def test_bundled_extract_invariants(downtown):
    layers = downtown
    gdf = layers.gdf
    assert shapely.is_valid(gdf.geometry.values).all()
    counts = gdf["class"].value_counts()
    assert all(counts.get(cls, 0) > 500 for cls in ("building", "street", "crosswalk", "sidewalk"))
    for pair, area in class_overlaps_m2(layers).items():
        assert area < 0.01, pair
    assert sidewalk_overlaps_m2(layers) < 0.01
    assert layers.layer("sidewalk")["segment_id"].is_unique
    assert layers.meta["generator"].startswith("curbside ")
    assert layers.meta["source"] == settings.default_osm_file.name


@pytest.mark.slow
def test_bundled_extract_crosswalks_join_sidewalks(downtown):
    joined = crosswalk_ends_joined(downtown)
    assert joined.mean() > 0.85


@pytest.mark.slow
def test_bundled_extract_mapped_sidewalks_not_in_street(downtown, downtown_osm):
    sidewalks = mapped_sidewalks(downtown_osm.ways).geometry.values
    assert len(sidewalks) > 500
    street = downtown.layer("street").geometry.values
    line_i, street_i = shapely.STRtree(street).query(sidewalks, predicate="intersects")
    inside = shapely.length(shapely.intersection(sidewalks[line_i], street[street_i])).sum()
    assert inside < 1e-6 * shapely.length(sidewalks).sum()


@pytest.mark.slow
def test_transit_center_bus_plaza_is_walkable(downtown, downtown_osm):
    osm = downtown_osm
    ways = osm.ways
    platforms = ways[(ways["highway"] == "platform") & (ways["tunnel"] == "building_passage")].geometry.values
    assert len(platforms) >= 3
    buildings = downtown.union("building")
    assert shapely.length(shapely.intersection(platforms, buildings)).sum() == 0
    center = osm.areas.loc[osm.areas["osm_id"] == "w542375290", "geometry"].iloc[0]
    # The transit center is still a building (it stands 30 m tall) around its passages.
    assert 0.3 * center.area < shapely.intersection(center, buildings).area < 0.95 * center.area


# --- CLI and bad input ---------------------------------------------------------------------------------


def test_cli_builds_writes_and_summarises(tmp_path, capsys):
    out = tmp_path / "out" / "map.geojson"
    status = osmseg_main(["build", "--osm", str(OSM_DATA / "crossroads-crossing-nodes.osm"), "-o", str(out)])
    assert status == 0
    doc = json.loads(out.read_text())
    assert doc["curbside"]["source"] == "crossroads-crossing-nodes.osm"
    assert doc["curbside"]["osm_timestamp"] == "2026-01-02T03:04:05Z"
    assert doc["curbside"]["params"]["unmarked_crossing_as"] == "crosswalk"
    stdout = capsys.readouterr().out
    for cls in CLASSES:
        assert cls in stdout
    back = read_map(out)
    assert len(back.layer("sidewalk")) == 8
    assert class_overlaps_m2(back)[("street", "sidewalk")] < 0.05


def test_cli_set_changes_build_parameters(tmp_path):
    out = tmp_path / "map.geojson"
    sets = ["--set", "crosswalk_width_m=4.5", "--set", "default_carriageway_width_m.residential=9"]
    argv = ["--osm", str(OSM_DATA / "crossroads-crossing-nodes.osm"), "--unmarked-as", "street", *sets]
    assert osmseg_main(["build", *argv, "-o", str(out)]) == 0
    params = json.loads(out.read_text())["curbside"]["params"]
    assert params["unmarked_crossing_as"] == "street"
    assert params["crosswalk_width_m"] == 4.5
    assert params["default_carriageway_width_m"]["residential"] == 9
    assert params["default_carriageway_width_m"]["primary"] == 13.0
    # The map's params rebuild the config that made it.
    widths = {**SegmentationConfig().default_carriageway_width_m, "residential": 9.0}
    expected = SegmentationConfig(
        unmarked_crossing_as="street", crosswalk_width_m=4.5, default_carriageway_width_m=widths
    )
    assert from_dict(SegmentationConfig, params) == expected


@pytest.mark.parametrize(
    ("pair", "message"),
    [
        ("crosswalk_width=4", "no parameter"),
        ("crosswalk_width_m=-1", "positive"),
        ("crosswalk_width_m", "KEY=VALUE"),
    ],
)
def test_bad_set(capsys, tmp_path, pair, message):
    err = _bad(capsys, tmp_path, ["--osm", str(OSM_DATA / "wide-road.osm"), "--set", pair])
    assert message in err


def test_cli_default_output_in_cwd(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert osmseg_main(["build", "--osm", str(OSM_DATA / "wide-road.osm")]) == 0
    assert (tmp_path / "map.geojson").is_file()


def test_bbox_inside_bundled_extract(tmp_path):
    layers = build_map((-122.4016, 37.7914, -122.4003, 37.7924))
    assert layers.meta["bbox"] == [-122.4016, 37.7914, -122.4003, 37.7924]
    assert set(layers.gdf["class"]) == set(CLASSES)
    west, south, east, north = layers.gdf.to_crs(4326).total_bounds
    assert west >= -122.4016 - 1e-6 and east <= -122.4003 + 1e-6
    assert south >= 37.7914 - 1e-6 and north <= 37.7924 + 1e-6
    assert (west, east) == pytest.approx((-122.4016, -122.4003), abs=1e-5)


def _bad(capsys, tmp_path, argv):
    out = tmp_path / "map.geojson"
    status = osmseg_main(["build", *argv, "-o", str(out)])
    err = capsys.readouterr().err
    assert status == 2
    assert len(err.strip().splitlines()) == 1
    assert "Traceback" not in err
    assert not out.exists()
    assert list(tmp_path.iterdir()) == [] or all(p.name != "map.geojson" for p in tmp_path.iterdir())
    return err


@pytest.mark.parametrize(
    ("bbox", "message"),
    [
        (["-122.40", "37.78", "-122.41", "37.79"], "west"),
        (["-122.41", "37.79", "-122.40", "37.78"], "south"),
        (["-190", "37.78", "-122.40", "37.79"], "range"),
        (["-122.41", "37.78", "-122.40", "91"], "range"),
        (["-123.0", "37.0", "-122.0", "38.0"], "km^2"),
    ],
)
def test_bad_bbox(capsys, tmp_path, bbox, message):
    err = _bad(capsys, tmp_path, ["--bbox", *bbox])
    assert "--bbox" in err and message in err


def test_missing_file(capsys, tmp_path):
    err = _bad(capsys, tmp_path, ["--osm", str(tmp_path / "nope.osm.pbf")])
    assert "nope.osm.pbf" in err and "no such" in err


def test_unsupported_extension(capsys, tmp_path):
    path = tmp_path / "area.geojson"
    path.write_text("{}")
    err = _bad(capsys, tmp_path, ["--osm", str(path)])
    assert "unsupported" in err


def test_truncated_xml(capsys, tmp_path):
    text = (OSM_DATA / "wide-road.osm").read_text()
    path = tmp_path / "cut.osm"
    path.write_text(text[: len(text) // 2])
    err = _bad(capsys, tmp_path, ["--osm", str(path)])
    assert "cut.osm" in err and "not a readable OSM file" in err


def test_text_renamed_pbf(capsys, tmp_path):
    path = tmp_path / "fake.osm.pbf"
    path.write_text("this is not a protocol buffer\n" * 20)
    err = _bad(capsys, tmp_path, ["--osm", str(path)])
    assert "fake.osm.pbf" in err and "not a readable OSM file" in err


def test_corrupt_bz2(capsys, tmp_path):
    path = tmp_path / "broken.osm.bz2"
    path.write_bytes(bz2.compress((OSM_DATA / "wide-road.osm").read_bytes())[:200])
    err = _bad(capsys, tmp_path, ["--osm", str(path)])
    assert "broken.osm.bz2" in err


def test_file_without_relevant_elements(capsys, tmp_path):
    err = _bad(capsys, tmp_path, ["--osm", str(OSM_DATA / "nothing-relevant.osm")])
    assert "nothing-relevant.osm" in err and "no highways" in err


def test_empty_area_inside_extract(capsys, tmp_path):
    # A 20 m square inside the extract's bounds over the bay, where it has no elements.
    err = _bad(capsys, tmp_path, ["--bbox", "-122.3852", "37.8017", "-122.3850", "37.8019"])
    assert "no " in err


def test_gz_and_pbf_read_like_xml(tmp_path):
    source = OSM_DATA / "crossroads-crossing-nodes.osm"
    gz = tmp_path / "scene.osm.gz"
    gz.write_bytes(gzip.compress(source.read_bytes()))
    pbf = tmp_path / "scene.osm.pbf"
    with osmium.SimpleWriter(str(pbf)) as writer:
        for obj in osmium.FileProcessor(str(source)):
            writer.add(obj)
    reference = build_map(osm_file=source)
    for path in (gz, pbf):
        layers = build_map(osm_file=path)
        assert layers.gdf["class"].value_counts().to_dict() == reference.gdf["class"].value_counts().to_dict()
        assert layers.union("street").area == pytest.approx(reference.union("street").area, rel=1e-6)
