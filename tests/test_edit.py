"""The map editor page without a browser: what it inlines and holds, its command line and bad input, and
how a hand-edited file with bad geometry is refused on load. In a real browser: ``test_edit_browser.py``."""

from __future__ import annotations

import json
import re

import pytest

from curbside.cli.osmseg import main as osmseg_main
from curbside.osmseg.edit import editor_page, file_features
from curbside.osmseg.mapio import read_map
from curbside.osmseg.webmap import WEB_ASSETS

# A resource the page would load (links, such as Leaflet's own credit, load nothing).
REMOTE = re.compile(r"""(\bsrc\s*=\s*["']?|url\(\s*["']?|@import\s+["']?)(https?:)?//""", re.IGNORECASE)


def _edit_data(page: str) -> dict:
    match = re.search(r"const EDIT = ", page)
    return json.JSONDecoder().raw_decode(page, match.end())[0]


@pytest.fixture
def crossroads(test_data):
    return test_data / "maps" / "crossroads.geojson"


def test_page_inlines_leaflet_and_geoman_and_the_maps_features(crossroads):
    page = editor_page(read_map(crossroads), crossroads.name, file_features(crossroads))
    geoman = (WEB_ASSETS / "leaflet-geoman.min.js").read_text(encoding="utf-8")
    assert geoman.splitlines()[0] in page and "sourceMappingURL" not in page
    assert "Leaflet 1.9.4" in page and not REMOTE.search(page) and "L.tileLayer" not in page
    data = _edit_data(page)
    original = json.loads(crossroads.read_text(encoding="utf-8"))
    assert [f["id"] for f in data["features"]] == list(range(len(original["features"])))
    assert [f["geometry"] for f in data["features"]] == [f["geometry"] for f in original["features"]]
    assert data["filename"] == "crossroads-edited.geojson" and data["source"] == "crossroads.geojson"
    assert list(data["classes"]) == ["street", "crosswalk", "sidewalk", "building"]
    assert "MIT" in (WEB_ASSETS / "leaflet-geoman.LICENSE").read_text()


def test_cli_with_bbox_shows_the_polygons_of_its_window(crossroads, tmp_path, capsys):
    out = tmp_path / "edit.html"
    bbox = ["-122.3976", "37.7904", "-122.3974", "37.7906"]
    assert osmseg_main(["edit", str(crossroads), "--bbox", *bbox, "-o", str(out)]) == 0
    assert f"{out}: editor for" in capsys.readouterr().out
    features = _edit_data(out.read_text(encoding="utf-8"))["features"]
    assert 0 < len(features) < 17


@pytest.mark.parametrize(
    ("args", "words"),
    [
        (["edit", "{map}", "-o", "{tmp}/edit.png"], "name it .html"),
        (["edit", "{tmp}/missing.geojson", "-o", "{tmp}/edit.html"], "no such map file"),
        (["edit", "{tmp}", "-o", "{tmp}/edit.html"], "is a folder, not a map file"),
        (["edit", "{map}", "--bbox", "0", "0", "0.001", "0.001", "-o", "{tmp}/edit.html"], "no polygon"),
    ],
)
def test_bad_input_is_one_line_and_exit_2(crossroads, tmp_path, capsys, args, words):
    argv = [a.format(map=crossroads, tmp=tmp_path) for a in args]
    assert osmseg_main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith("osmseg: error: ") and words in err and err.count("\n") == 1
    assert not (tmp_path / "edit.html").exists()


def test_a_saved_map_with_bad_geometry_is_refused_in_one_line(crossroads, tmp_path, capsys):
    doc = json.loads(crossroads.read_text(encoding="utf-8"))
    ring = doc["features"][3]["geometry"]["coordinates"][0]
    doc["features"][3]["geometry"]["coordinates"] = [ring[:2]]  # a ring of two points
    doc["features"][3]["properties"]["edited"] = "geometry"
    bad = tmp_path / "hand.geojson"
    bad.write_text(json.dumps(doc))
    assert osmseg_main(["compare", str(crossroads), str(bad)]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"osmseg: error: {bad}: bad feature geometry") and err.count("\n") == 1
