"""The legend's free-space line says where the map's buildings came from (``buildings_source``), in the
PNG and the HTML page alike, and maps written before that metadata existed still read and get a true
label."""

from __future__ import annotations

import json

import pytest
from matplotlib.figure import Figure

from curbside import settings
from curbside.osmseg.build import build_map
from curbside.osmseg.datasf import over_streets_of, read_datasf
from curbside.osmseg.edit import editor_data, file_features
from curbside.osmseg.mapio import MapLayers, buildings_source, read_map, write_map
from curbside.osmseg.plot import html_page, plot_map
from curbside.osmseg.style import BACKGROUND_LABEL, background_label

OSM_LABEL = "free space (no building mapped in OSM)"
DATASF_LABEL = "free space (no building in the DataSF 2013 footprints)"
EDITED_LABEL = "free space (no building in this hand-edited map)"
GENERIC_LABEL = "free space (no building in this map)"


def _legend(layers: MapLayers) -> list[str]:
    ax = plot_map(layers, Figure(figsize=(6, 6)).add_axes((0.05, 0.05, 0.6, 0.85)))
    return [t.get_text() for t in ax.get_legend().get_texts()]


def _credit(layers: MapLayers) -> str:
    ax = plot_map(layers, Figure(figsize=(6, 6)).add_axes((0.05, 0.05, 0.6, 0.85)))
    return " ".join(t.get_text() for t in ax.texts)


def _free_space_lines(layers: MapLayers) -> tuple[list[str], list[str]]:
    """The free-space legend lines of the PNG and of the HTML page."""
    page = html_page(layers)
    in_page = [label for label in (OSM_LABEL, DATASF_LABEL, EDITED_LABEL, GENERIC_LABEL) if label in page]
    return [t for t in _legend(layers) if t.startswith("free space")], in_page


@pytest.fixture
def osm_map(tmp_path, test_data) -> MapLayers:
    """A map `osmseg build` made, written and read back."""
    layers = build_map(osm_file=test_data / "osm" / "crossroads-crossing-nodes.osm")
    return read_map(write_map(layers, tmp_path / "osm.geojson"))


@pytest.fixture
def datasf_map(tmp_path, test_data) -> MapLayers:
    tiles = [test_data / "maps" / f"datasf-{t}-trimmed.topojson" for t in ("3_1", "4_1")]
    return read_map(write_map(read_datasf(tiles), tmp_path / "datasf.geojson"))


def _saved_by_editor(tmp_path, path) -> MapLayers:
    """What the editor's *save* writes (curbside-edit.js ``editedDocument``), one building deleted."""
    data = editor_data(read_map(path), path.name, file_features(path))
    deleted = next(f["id"] for f in data["features"] if f["properties"]["class"] == "building")
    doc = {
        "type": "FeatureCollection",
        "curbside": {**data["meta"], "edits": {"from": path.name, "deleted": [deleted]}},
        "features": [f for f in data["features"] if f["id"] != deleted],
    }
    saved = tmp_path / "edited.geojson"
    saved.write_text(json.dumps(doc), encoding="utf-8")
    return read_map(saved)


def test_osm_map_says_mapped_in_osm_and_credits_osm(osm_map):
    assert osm_map.meta["buildings_source"] == "osm"
    assert _free_space_lines(osm_map) == ([OSM_LABEL], [OSM_LABEL])
    assert settings.osm_attribution in _credit(osm_map)


def test_datasf_map_says_datasf_footprints(datasf_map):
    assert datasf_map.meta["buildings_source"] == "datasf"
    assert _free_space_lines(datasf_map) == ([DATASF_LABEL], [DATASF_LABEL])
    assert "OpenStreetMap" not in _credit(datasf_map)  # no OSM data on it


def test_datasf_buildings_over_osm_streets_say_datasf_and_keep_the_osm_credit(tmp_path, osm_map, datasf_map):
    combined = read_map(write_map(over_streets_of(datasf_map, osm_map), tmp_path / "combined.geojson"))
    assert combined.meta["buildings_source"] == "datasf"
    assert _free_space_lines(combined) == ([DATASF_LABEL], [DATASF_LABEL])
    assert settings.osm_attribution in _credit(combined)


def test_map_saved_by_the_editor_says_hand_edited(tmp_path, osm_map):
    source = write_map(osm_map, tmp_path / "to-edit.geojson")
    edited = _saved_by_editor(tmp_path, source)
    assert edited.meta["buildings_source"] == "edited"
    assert _free_space_lines(edited) == ([EDITED_LABEL], [EDITED_LABEL])
    assert settings.osm_attribution in _credit(edited)  # still OSM's streets and buildings


def test_hand_drawn_map_without_provenance_gets_the_generic_label(test_data):
    crossroads = read_map(test_data / "maps" / "crossroads.geojson")  # "hand-drawn test crossroads"
    assert buildings_source(crossroads.meta) is None
    assert _free_space_lines(crossroads) == ([GENERIC_LABEL], [GENERIC_LABEL])


def _without_field(tmp_path, layers: MapLayers, name: str) -> MapLayers:
    """``layers`` as a file written before ``buildings_source`` existed."""
    doc = json.loads(write_map(layers, tmp_path / f"{name}-new.geojson").read_text(encoding="utf-8"))
    del doc["curbside"]["buildings_source"]
    old = tmp_path / f"{name}.geojson"
    old.write_text(json.dumps(doc), encoding="utf-8")
    return read_map(old)


def test_old_files_without_the_field_still_read_and_get_a_true_label(
    tmp_path, test_data, osm_map, datasf_map
):
    committed = read_map(test_data / "evaluate" / "sf-path3.geojson")  # built by curbside 0.1.0
    assert "buildings_source" not in committed.meta
    assert background_label(committed.meta) == OSM_LABEL
    assert background_label(_without_field(tmp_path, osm_map, "osm").meta) == OSM_LABEL
    assert background_label(_without_field(tmp_path, datasf_map, "datasf").meta) == DATASF_LABEL
    combined = _without_field(tmp_path, over_streets_of(datasf_map, osm_map), "combined")
    assert background_label(combined.meta) == DATASF_LABEL  # the OSM map's osm_timestamp came along
    hand = test_data / "maps" / "crossroads.geojson"
    edited = _without_field(tmp_path, _saved_by_editor(tmp_path, hand), "edited-old")
    assert background_label(edited.meta) == EDITED_LABEL


@pytest.mark.parametrize("value", ["lidar", 3, ""])
def test_an_unknown_source_gets_the_generic_label(value):
    assert background_label({"buildings_source": value, "osm_timestamp": None}) == BACKGROUND_LABEL
    assert BACKGROUND_LABEL == GENERIC_LABEL
