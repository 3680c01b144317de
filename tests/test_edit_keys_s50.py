"""The map editor's vertex mode (s50): the selected polygon reshaped without a pointer.

A polygon picked in the list by keyboard, ``V`` enters vertex mode; ``N``/``P`` step through its vertices,
the arrow keys move the current one by metres (Shift finer, Ctrl larger), ``I`` inserts one, ``Delete``
removes it, ``Esc`` leaves. Each edit takes the pointer's path (the self-intersection check, the 3-vertex
rule, the undo stack, the saved file), and is announced in the page's live region.
"""

from __future__ import annotations

import json
import math
import time
from pathlib import Path

import pytest
from browser import chromium, console_errors, wait_for_mark
from pyproj import Geod

from curbside.cli.osmseg import main as osmseg_main

POLYGON = 6  # crossroads.geojson: a sidewalk, 4 m (north-south) by 54 m; its 2nd vertex is the NW corner
STATE_JS = """
const ui = (id) => document.getElementById(id), area = ui("map");
const mark = document.querySelector(".current-vertex"), box = mark && mark.getBoundingClientRect();
const origin = area.getBoundingClientRect();
return {title: ui("selection-title").textContent, count: ui("edit-count").textContent,
  message: ui("edit-message").textContent, refused: ui("edit-message").className === "refused",
  live: ui("edit-message").getAttribute("aria-live"), focus: document.activeElement.id,
  role: area.getAttribute("role"), label: area.getAttribute("aria-label"),
  pressed: ui("vertex-mode").getAttribute("aria-pressed"), mark: mark ? mark.textContent : null,
  mark_px: box ? [box.x + box.width / 2 - origin.x, box.y + box.height / 2 - origin.y] : null};
"""
# Where a vertex of a polygon is drawn, in map container pixels.
VERTEX_PX_JS = """
const layer = curbsideEditor.editor.byId.get(arguments[0]);
const p = map.latLngToContainerPoint(layer.getLatLngs()[0][arguments[1]]);
return [p.x, p.y];
"""
RING_JS = """
return curbsideEditor.editor.byId.get(arguments[0]).toGeoJSON(7).geometry.coordinates[0];
"""
GEOD = Geod(ellps="WGS84")


def _offset_m(a: list[float], b: list[float]) -> tuple[float, float]:
    """(east, north) metres from lon/lat ``a`` to ``b`` on the WGS84 ellipsoid."""
    azimuth_deg, _, distance_m = GEOD.inv(a[0], a[1], b[0], b[1])
    azimuth = math.radians(azimuth_deg)
    return distance_m * math.sin(azimuth), distance_m * math.cos(azimuth)


class Keys:
    """The editor in headless Chromium, driven by keyboard only."""

    def __init__(self, driver):
        from selenium.webdriver.common.action_chains import ActionChains
        from selenium.webdriver.common.keys import Keys as SeleniumKeys

        self.driver, self.keys, self.chain = driver, SeleniumKeys, ActionChains

    def state(self) -> dict:
        return self.driver.execute_script(STATE_JS)

    def ring(self, feature_id: int | str) -> list[list[float]]:
        return self.driver.execute_script(RING_JS, str(feature_id))

    def press(self, *keys: str, modifier: str | None = None) -> None:
        actions = self.chain(self.driver)
        if modifier:
            actions.key_down(modifier)
        actions.send_keys(*keys)
        if modifier:
            actions.key_up(modifier)
        actions.perform()
        time.sleep(0.1)

    def tab_to(self, element_id: str) -> None:
        for _ in range(30):
            if self.state()["focus"] == element_id:
                return
            self.press(self.keys.TAB)
        raise AssertionError(f"Tab never reached #{element_id}")

    def pick(self, feature_id: int) -> None:
        """Tab to the list of polygons, then Home and the down arrow to the polygon's line."""
        self.tab_to("feature-list")
        line = self.driver.execute_script(
            "return [...document.getElementById('feature-list').options]"
            ".findIndex((o) => o.value === arguments[0])",
            str(feature_id),
        )
        self.press(self.keys.HOME, *[self.keys.ARROW_DOWN] * line)
        assert self.state()["title"] == f"polygon {feature_id}"


@pytest.fixture
def page(test_data, tmp_path):
    out = tmp_path / "edit.html"
    assert osmseg_main(["edit", str(test_data / "maps" / "crossroads.geojson"), "-o", str(out)]) == 0
    with chromium(1280, 860, downloads=tmp_path) as driver:
        driver.get(out.as_uri())
        wait_for_mark(driver, "curbside:editor-ready")
        yield Keys(driver)
        assert console_errors(driver) == []


def _save(page: Keys, folder: Path) -> dict:
    """Tab to *save*, press Enter; the saved file."""
    page.tab_to("save")
    page.press(page.keys.ENTER)
    target = folder / "crossroads-edited.geojson"
    deadline = time.monotonic() + 20
    while not target.is_file() and time.monotonic() < deadline:
        time.sleep(0.1)
    return json.loads(target.read_text(encoding="utf-8"))


def test_a_vertex_moved_by_keyboard_is_saved_moved_by_those_metres_and_ctrl_z_undoes_it(page, tmp_path):
    page.pick(POLYGON)
    before = page.ring(POLYGON)
    page.press("v")
    state = page.state()
    assert (state["focus"], state["pressed"], state["role"]) == ("map", "true", "application")
    assert state["live"] == "polite" and state["message"].startswith("vertex mode:")
    assert (
        f"vertex 1 of 4 of polygon {POLYGON}, at lat {before[0][1]:.7f}, lon {before[0][0]:.7f}"
        in (state["message"])
    )
    page.press("n")
    state = page.state()
    assert state["message"].startswith(f"vertex 2 of 4 of polygon {POLYGON}") and state["mark"] == "2"
    vertex_px = page.driver.execute_script(VERTEX_PX_JS, str(POLYGON), 1)
    assert state["mark_px"] == pytest.approx(vertex_px, abs=1.5)  # highlighted there
    page.press(*[page.keys.ARROW_UP] * 3)  # 3 x 1 m north
    page.press(page.keys.ARROW_LEFT, page.keys.ARROW_LEFT, modifier=page.keys.SHIFT)  # 2 x 0.1 m west
    state = page.state()
    assert state["message"].startswith("moved 0.1 m west: 0.2 m west, 3 m north of where it was; vertex 2")
    assert state["count"] == "edits: 1 geometry" and state["focus"] == "map" and not state["refused"]

    doc = _save(page, tmp_path)
    feature = next(f for f in doc["features"] if f["id"] == POLYGON)
    after = feature["geometry"]["coordinates"][0]
    assert _offset_m(before[1], after[1]) == pytest.approx((-0.2, 3.0), abs=0.02)
    assert after[:1] + after[2:] == before[:1] + before[2:]  # the other vertices stay, to the digit
    # recorded exactly as a pointer's vertex drag is
    assert feature["properties"]["edited"] == "geometry" and doc["curbside"]["edits"]["geometry"] == [POLYGON]

    page.press("z", modifier=page.keys.CONTROL)  # one key press, one edit: back 0.1 m east
    state = page.state()
    assert state["message"].startswith(f"undone: vertex move of polygon {POLYGON}; vertex 2 of 4")
    assert (state["focus"], state["pressed"], state["mark"]) == ("save", "true", "2")  # vertex mode goes on
    assert _offset_m(before[1], page.ring(POLYGON)[1]) == pytest.approx((-0.1, 3.0), abs=0.02)
    for _ in range(4):
        page.press("z", modifier=page.keys.CONTROL)
    assert page.ring(POLYGON) == before and page.state()["count"] == "no edits yet"


def test_the_large_step_is_refused_where_the_outline_would_cross_itself(page):
    page.pick(POLYGON)
    before = page.ring(POLYGON)
    page.press("v")  # vertex 1, the SW corner: 10 m north puts it beyond the north side, 4 m away
    page.press(page.keys.ARROW_UP, modifier=page.keys.CONTROL)
    state = page.state()
    assert state["refused"] and "cross itself; it stays where it was" in state["message"]
    assert page.ring(POLYGON) == before and state["count"] == "no edits yet" and state["focus"] == "map"
    page.press(page.keys.ARROW_DOWN, modifier=page.keys.CONTROL)  # outward: allowed, 10 m south
    assert _offset_m(before[0], page.ring(POLYGON)[0]) == pytest.approx((0, -10), abs=0.02)


def test_insert_and_remove_a_vertex_and_a_removal_below_3_vertices_is_refused_and_announced(page):
    page.pick(POLYGON)
    before = page.ring(POLYGON)
    page.press("v", "i")  # a vertex midway along the first edge
    ring = page.ring(POLYGON)
    assert len(ring) == 6 and ring[1] == pytest.approx(
        [(before[0][0] + before[1][0]) / 2, (before[0][1] + before[1][1]) / 2], abs=2e-7
    )
    assert page.state()["message"].startswith("vertex added midway to the next one: vertex 2 of 5")
    page.press(page.keys.DELETE, page.keys.DELETE)  # back to 4, then 3 vertices
    state = page.state()
    assert len(page.ring(POLYGON)) == 4 and state["message"].startswith("vertex removed; now vertex 2 of 3")
    assert state["count"] == "edits: 1 geometry" and state["title"] == f"polygon {POLYGON}"
    page.press(page.keys.DELETE)  # 3 to 2: refused, visibly and in the live region
    state = page.state()
    assert state["refused"] and "a ring keeps at least 3 vertices" in state["message"]
    assert len(page.ring(POLYGON)) == 4 and state["focus"] == "map"  # 3 + the closing one
    assert page.driver.find_element("id", "edit-message").is_displayed()
    page.press(page.keys.ESCAPE)
    state = page.state()
    assert (state["pressed"], state["role"], state["label"]) == ("false", "region", "map")
    assert state["mark"] is None  # the highlight is gone
    assert state["title"] == f"polygon {POLYGON}" and state["focus"] == "map"  # still selected, focus kept
    assert "vertex mode off" in state["message"]
    page.press(page.keys.DELETE)  # out of vertex mode, Delete is the polygon's again
    assert page.driver.execute_script("return curbsideEditor.editor.deleted") == [POLYGON]


def test_the_button_enters_vertex_mode_and_the_keys_are_in_the_help(page):
    help_text = page.driver.find_element("id", "vertex-help").text
    keys = ("N / P", "1 m", "Shift 0.1 m", "Ctrl 10 m", "I inserts", "Del", "Esc")
    assert all(k in help_text for k in keys)
    page.tab_to("map")
    page.press("v")  # nothing selected: says what to do
    assert page.state()["refused"] and "select a polygon first" in page.state()["message"]
    page.pick(POLYGON)
    page.tab_to("vertex-mode")
    page.press(page.keys.ENTER)
    state = page.state()
    assert (state["focus"], state["pressed"], state["mark"]) == ("map", "true", "1")
    page.press("p")  # wraps to the last vertex
    assert page.state()["message"].startswith(f"vertex 4 of 4 of polygon {POLYGON}")


def test_a_reshaped_sidewalk_keeps_its_bearing_and_one_whose_side_changed_drops_it(test_data, tmp_path):
    from selenium.webdriver.support.select import Select

    doc = json.loads((test_data / "maps" / "crossroads.geojson").read_text(encoding="utf-8"))
    for index, bearing in ((6, 0.0), (7, 270.0), (9, 180.0)):  # as `osmseg build` records them
        doc["features"][index]["properties"]["facing_deg"] = bearing
    source = tmp_path / "crossroads.geojson"
    source.write_text(json.dumps(doc), encoding="utf-8")
    out = tmp_path / "edit.html"
    assert osmseg_main(["edit", str(source), "-o", str(out)]) == 0
    with chromium(1280, 860, downloads=tmp_path) as driver:
        driver.get(out.as_uri())
        wait_for_mark(driver, "curbside:editor-ready")
        page = Keys(driver)
        page.pick(6)
        page.press("v", page.keys.ARROW_DOWN, page.keys.ESCAPE)  # a 1 m reshape
        page.pick(7)
        Select(driver.find_element("id", "field-side")).select_by_visible_text("left")  # was right
        saved = _save(page, tmp_path)
        assert console_errors(driver) == []
    props = {f["id"]: f["properties"] for f in saved["features"]}
    assert props[6]["edited"] == "geometry" and props[6]["facing_deg"] == 0.0
    assert props[7]["edited"] == "fields" and props[7]["side"] == "left" and "facing_deg" not in props[7]
    assert props[9] == doc["features"][9]["properties"]  # unedited: as in the file
