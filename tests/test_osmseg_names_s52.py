"""Street names in the walker's language: ``osmseg build --name-tag name:<language>``.

The scene is the divided road of ``test_osmseg_medians_s52`` with names in three scripts; the bundled
extract's ``name:zh`` values are ``???`` (lost to an encoding step upstream), which must not become
street names.
"""

from __future__ import annotations

import json
import logging

import pytest
from test_osmseg_medians_s52 import divided_road

from curbside.cli.osmseg import main as osmseg_main
from curbside.osmseg.build import build_map
from curbside.osmseg.config import SegmentationConfig
from curbside.osmseg.reader import read_osm_file

NAMES = {"name": "Rue de la Loi", "name:nl": "Wetstraat", "name:zh-Hant": "法律街",
         "name:etymology": "la loi"}  # fmt: skip


def _streets(layers) -> set[str]:
    gdf = layers.gdf
    return set(gdf["street"][gdf["class"] == "sidewalk"].dropna())


@pytest.fixture
def scene(tmp_path):
    return divided_road(tmp_path / "brussels.osm", east=NAMES, west=NAMES)


def test_the_reader_keeps_names_in_a_language_and_nothing_else(scene):
    ways = read_osm_file(scene).ways
    assert {"name:nl", "name:zh-Hant"} <= set(ways.columns)
    assert "name:etymology" not in ways.columns  # a name's meaning, not a language
    assert set(ways["name:zh-Hant"].dropna()) == {"法律街"}


def test_streets_are_named_from_the_chosen_tag_then_name(scene):
    assert _streets(build_map(osm_file=scene)) == {"Rue de la Loi", "Cross Street"}
    def named_from(key: str) -> set[str]:
        config = SegmentationConfig(street_name_keys=(key, "name", "ref"))
        return _streets(build_map(osm_file=scene, config=config))

    # The divided road has a Dutch name; the cross street has none and keeps its own.
    assert named_from("name:nl") == {"Wetstraat", "Cross Street"}
    assert named_from("name:zh-Hant") == {"法律街", "Cross Street"}


def test_name_tag_on_the_command_line_is_recorded_and_written_as_text(scene, tmp_path):
    out = tmp_path / "map.geojson"
    assert osmseg_main(["build", "--osm", str(scene), "--name-tag", "name:zh-Hant", "-o", str(out)]) == 0
    written = json.loads(out.read_text(encoding="utf-8"))
    assert written["curbside"]["params"]["street_name_keys"] == ["name:zh-Hant", "name", "ref"]
    assert "法律街" in {f["properties"].get("street") for f in written["features"]}


@pytest.mark.parametrize("tag", ["chinese", "name", "name:etymology", "alt_name"])
def test_a_name_tag_that_is_not_a_language_is_one_line_and_status_2(scene, tmp_path, capsys, tag):
    out = tmp_path / "map.geojson"
    assert osmseg_main(["build", "--osm", str(scene), "--name-tag", tag, "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--name-tag" in err and "name:en" in err
    assert not out.exists()


def test_street_name_keys_are_checked():
    with pytest.raises(ValueError, match="street_name_keys"):
        SegmentationConfig(street_name_keys=("name:etymology",))
    with pytest.raises(ValueError, match="street_name_keys"):
        SegmentationConfig(street_name_keys=())


def test_names_lost_to_an_encoding_step_are_not_street_names(tmp_path, caplog):
    # As in the bundled extract: name:zh="???" on the ways of Chinatown.
    lost = {**NAMES, "name:zh": "???"}
    path = divided_road(tmp_path / "lost.osm", east=lost, west=lost)
    config = SegmentationConfig(street_name_keys=("name:zh", "name", "ref"))
    with caplog.at_level(logging.WARNING):
        streets = _streets(build_map(osm_file=path, config=config))
    assert streets == {"Rue de la Loi", "Cross Street"}
    assert any("name:zh='???'" in r.getMessage() and "encoding" in r.getMessage() for r in caplog.records)
