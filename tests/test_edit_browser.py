"""The map editor in headless Chromium: select a polygon, move a vertex, change a class, draw one, save;
the saved file reads like any map and ``osmseg compare`` compares it with the original."""

from __future__ import annotations

import json
import time

import pytest
import shapely
from browser import chromium, console_errors, wait_for_mark

from curbside.cli.osmseg import main as osmseg_main
from curbside.osmseg.mapio import read_map

# Zoom to the k-th polygon of a class; its centre in container pixels (inside it: the polygons are boxes).
CENTRE_JS = """
const layer = curbsideEditor.editor.groups[arguments[0]].getLayers()[arguments[1]];
map.fitBounds(layer.getBounds(), {maxZoom: 20, animate: false, padding: [150, 150]});
const p = map.latLngToContainerPoint(layer.getCenter());
return [p.x, p.y, layer.curbside.id];
"""


@pytest.fixture
def saved(tmp_path, test_data, capsys):
    """Edit the crossroads map in the browser: move a vertex, reclassify a polygon, draw one; save."""
    from selenium.webdriver.common.action_chains import ActionChains
    from selenium.webdriver.support.ui import Select

    source = test_data / "maps" / "crossroads.geojson"
    page = tmp_path / "edit.html"
    assert osmseg_main(["edit", str(source), "-o", str(page)]) == 0
    assert "editor for 17 polygons" in capsys.readouterr().out
    downloads = tmp_path / "downloads"
    downloads.mkdir()
    with chromium(1200, 800, downloads=downloads) as driver:
        driver.get(page.as_uri())
        wait_for_mark(driver, "curbside:editor-ready")
        area = driver.find_element("id", "map")
        origin = area.rect["width"] / 2, area.rect["height"] / 2

        def click_at(x, y):
            actions = ActionChains(driver).move_to_element_with_offset(area, x - origin[0], y - origin[1])
            actions.click().perform()

        # select a sidewalk by clicking it, then drag its first vertex 25 px east
        x, y, moved_id = driver.execute_script(CENTRE_JS, "sidewalk", 0)
        click_at(x, y)
        assert driver.find_element("id", "selection-title").text == f"polygon {moved_id}"
        vertices = driver.find_elements("css selector", ".marker-icon:not(.marker-icon-middle)")
        vertex = next(v for v in vertices if v.is_displayed())
        drag = ActionChains(driver).click_and_hold(vertex).move_by_offset(10, 0).move_by_offset(15, 0)
        drag.release().perform()
        time.sleep(0.3)
        # reclassify another sidewalk as a crosswalk through the panel
        x, y, reclassified_id = driver.execute_script(CENTRE_JS, "sidewalk", 1)
        click_at(x, y)
        Select(driver.find_element("id", "feature-class")).select_by_value("crosswalk")
        assert "1 geometry, 1 class" in driver.find_element("id", "edit-count").text
        # draw a building: the toolbar's rectangle, two clicks in the block north-west of the crossroads
        driver.execute_script("map.setView([37.7905, -122.3975], 19, {animate: false});")
        Select(driver.find_element("id", "draw-class")).select_by_value("building")
        driver.find_element("css selector", ".leaflet-pm-icon-rectangle").click()
        click_at(300, 300)
        click_at(360, 340)
        assert "1 drawn" in driver.find_element("id", "edit-count").text
        driver.find_element("id", "save").click()
        target = downloads / "crossroads-edited.geojson"
        deadline = time.monotonic() + 20
        while not target.is_file() and time.monotonic() < deadline:
            time.sleep(0.1)
        assert console_errors(driver) == []
    assert target.is_file(), sorted(p.name for p in downloads.iterdir())
    return source, target, moved_id, reclassified_id


def test_saved_map_records_the_edits_and_loads_like_any_map(saved):
    source, target, moved_id, reclassified_id = saved
    doc = json.loads(target.read_text(encoding="utf-8"))
    original = json.loads(source.read_text(encoding="utf-8"))
    edits = doc["curbside"]["edits"]
    assert edits["from"] == "crossroads.geojson" and edits["geometry"] == [moved_id]
    assert edits["class"] == [reclassified_id] and edits["deleted"] == [] and edits["drawn"] == ["new-1"]
    by_id = {f["id"]: f for f in doc["features"]}
    assert len(by_id) == len(original["features"]) + 1
    drawn = by_id["new-1"]
    assert drawn["properties"] == {"class": "building", "edited": "drawn"}
    assert shapely.geometry.shape(drawn["geometry"]).area > 0
    assert by_id[reclassified_id]["properties"] == {"class": "crosswalk", "edited": "class"}
    assert by_id[moved_id]["properties"]["edited"] == "geometry"
    before = shapely.geometry.shape(original["features"][moved_id]["geometry"])
    after = shapely.geometry.shape(by_id[moved_id]["geometry"])
    assert not before.equals(after) and after.is_valid
    # untouched features are saved exactly as they came
    untouched = [i for i in by_id if i not in (moved_id, reclassified_id, "new-1")]
    assert all(by_id[i]["geometry"] == original["features"][i]["geometry"] for i in untouched)
    layers = read_map(target)
    counts = layers.gdf["class"].value_counts()
    assert (counts["crosswalk"], counts["sidewalk"], counts["building"]) == (5, 7, 5)


def test_saved_map_compares_with_the_original(saved, tmp_path, capsys):
    source, target, _, _ = saved
    out = tmp_path / "compare.json"
    assert osmseg_main(["compare", str(source), str(target), "--json", str(out)]) == 0
    assert "crosswalk" in capsys.readouterr().out
    classes = json.loads(out.read_text())["classes"]
    assert (classes["crosswalk"]["count_a"], classes["crosswalk"]["count_b"]) == (4, 5)
    assert (classes["sidewalk"]["count_a"], classes["sidewalk"]["count_b"]) == (8, 7)
    assert classes["crosswalk"]["area_b_m2"] > classes["crosswalk"]["area_a_m2"]
    assert classes["sidewalk"]["iou"] < 1.0
    assert (classes["building"]["count_a"], classes["building"]["count_b"]) == (4, 5)
