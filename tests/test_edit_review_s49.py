"""The map editor after review s49: a keyboard path to the polygons (the list), a name on every control,
Delete only where it means the selected polygon, a visible and announced refusal, undo (Ctrl+Z and a
button), and ``--bbox`` saving the whole map file with its own ids (the window only chooses what is shown).
"""

from __future__ import annotations

import json
import re
import time
from pathlib import Path

import pytest
import shapely
from browser import chromium, console_errors, wait_for_mark

from curbside.cli.osmseg import main as osmseg_main
from curbside.osmseg.mapio import read_map

WINDOW = ("-122.3976", "37.7904", "-122.3974", "37.7906")

# Focusable, visible elements without an accessible name (aria-label, aria-labelledby, <label>, text, title).
NAMELESS_JS = """
const name = (e) => (e.getAttribute("aria-label") || "").trim()
  || [...(e.getAttribute("aria-labelledby") || "").split(/\\s+/)].map((id) => document.getElementById(id))
       .filter(Boolean).map((l) => l.textContent).join(" ").trim()
  || [...(e.labels || [])].map((l) => l.textContent).join(" ").trim()
  || e.textContent.trim() || (e.title || "").trim();
return [...document.querySelectorAll("a[href], button, input, select, [tabindex]")]
  .filter((e) => e.tabIndex >= 0 && !e.disabled && e.getClientRects().length && !name(e))
  .map((e) => e.outerHTML.slice(0, 120));
"""
STATE_JS = """
const e = curbsideEditor.editor, ui = (id) => document.getElementById(id);
return {title: ui("selection-title").textContent, count: ui("edit-count").textContent,
  message: ui("edit-message").textContent, refused: ui("edit-message").className === "refused",
  live: ui("edit-message").getAttribute("role"), focus: document.activeElement.id,
  list: ui("feature-list").value, options: ui("feature-list").options.length,
  cls: ui("feature-class").value, street: ui("field-street").value,
  undo_disabled: ui("undo").disabled, deleted: e.deleted.slice()};
"""
# The selected polygon fitted to the map; its outer ring's vertices in container pixels.
RING_JS = """
const layer = curbsideEditor.editor.byId.get(arguments[0]);
map.fitBounds(layer.getBounds(), {maxZoom: 21, animate: false, padding: [150, 150]});
return layer.getLatLngs()[0].map((ll) => { const p = map.latLngToContainerPoint(ll); return [p.x, p.y]; });
"""
GEOMETRY_JS = "return curbsideEditor.editor.byId.get(arguments[0]).toGeoJSON(7).geometry;"


def _edit_data(page: Path) -> tuple[dict, list[dict]]:
    """The page's ``EDIT`` and the features it keeps, unseen, to save them (its JSON element)."""
    text = page.read_text(encoding="utf-8")
    data = json.JSONDecoder().raw_decode(text, re.search(r"const EDIT = ", text).end())[0]
    kept = re.search(r'<script type="application/json" id="edit-kept">(.*?)</script>', text, re.S)
    return data, json.loads(kept.group(1))


def _original(path: Path) -> list[dict]:
    return [{**f, "id": i} for i, f in enumerate(json.loads(path.read_text(encoding="utf-8"))["features"])]


@pytest.fixture
def crossroads(test_data) -> Path:
    return test_data / "maps" / "crossroads.geojson"


class Page:
    """The editor open in headless Chromium, with the few gestures the tests make."""

    def __init__(self, driver):
        from selenium.webdriver.common.action_chains import ActionChains
        from selenium.webdriver.common.keys import Keys

        self.driver, self.keys, self.chain = driver, Keys, ActionChains
        self.area = driver.find_element("id", "map")

    def state(self) -> dict:
        return self.driver.execute_script(STATE_JS)

    def press(self, *keys, ctrl: bool = False) -> None:
        actions = self.chain(self.driver)
        if ctrl:
            actions.key_down(self.keys.CONTROL)
        actions.send_keys(*keys)
        if ctrl:
            actions.key_up(self.keys.CONTROL)
        actions.perform()
        time.sleep(0.15)

    def focus(self, element_id: str) -> None:
        self.driver.execute_script(f"document.getElementById({element_id!r}).focus()")

    def pick(self, feature_id: int) -> None:
        """Select a polygon in the list by keyboard: Home, then the down arrow to its line."""
        self.focus("feature-list")
        line = self.driver.execute_script(
            "return [...document.getElementById('feature-list').options]"
            ".findIndex((o) => o.value === arguments[0])", str(feature_id))
        self.press(self.keys.HOME, *[self.keys.ARROW_DOWN] * line)

    def _to(self, x: float, y: float):
        rect = self.area.rect
        return self.chain(self.driver).move_to_element_with_offset(
            self.area, x - rect["width"] / 2, y - rect["height"] / 2)

    def drag(self, start: list[float], end: list[float]) -> None:
        dx, dy = end[0] - start[0], end[1] - start[1]
        actions = self._to(*start).click_and_hold().move_by_offset(round(dx / 2), round(dy / 2))
        actions.move_by_offset(round(dx) - round(dx / 2), round(dy) - round(dy / 2)).release().perform()
        time.sleep(0.3)

    def right_click(self, at: list[float]) -> None:
        self._to(*at).context_click().perform()
        time.sleep(0.3)


@pytest.fixture
def page(crossroads, tmp_path):
    out = tmp_path / "edit.html"
    assert osmseg_main(["edit", str(crossroads), "-o", str(out)]) == 0
    with chromium(1280, 860, downloads=tmp_path) as driver:
        driver.get(out.as_uri())
        wait_for_mark(driver, "curbside:editor-ready")
        yield Page(driver)
        assert console_errors(driver) == []


# -- 1. keyboard and screen reader ---------------------------------------------------------------------
def test_tab_reaches_the_polygon_list_and_the_arrows_select_and_show_a_polygon(page):
    for _ in range(20):
        page.press(page.keys.TAB)
        if page.state()["focus"] == "feature-list":
            break
    assert page.state()["focus"] == "feature-list"
    page.press(page.keys.HOME)
    assert page.state()["title"] == "polygon 0" and page.state()["cls"] == "street"
    page.press(*[page.keys.ARROW_DOWN] * 7)
    state = page.state()
    assert (state["title"], state["list"], state["cls"]) == ("polygon 7", "7", "sidewalk")
    assert state["street"] == "2nd Street"
    assert page.driver.find_element("id", "selection-state").text == "as in crossroads.geojson"
    page.press("1", "3")  # type-ahead: the line that starts with the id
    assert page.state()["title"] == "polygon 13"


def test_every_control_has_a_name_with_a_polygon_selected_and_while_drawing(page):
    assert page.driver.execute_script(NAMELESS_JS) == []
    names = page.driver.execute_script(
        "return [...document.querySelectorAll('a.leaflet-buttons-control-button')]"
        ".map((a) => a.getAttribute('aria-label'))")
    assert names[0].startswith("Draw Rectangle") and names[1].startswith("Draw Polygons")
    page.pick(6)  # its vertex handles appear
    assert page.driver.find_elements("css selector", ".marker-icon")
    assert page.driver.execute_script(NAMELESS_JS) == []
    page.driver.find_element("css selector", ".leaflet-pm-icon-polygon").click()
    assert page.driver.execute_script(NAMELESS_JS) == []


def test_delete_acts_only_with_the_focus_on_the_map_or_the_list(page):
    page.pick(3)
    for other in ("save", "draw-class"):
        page.focus(other)
        page.press(page.keys.DELETE)
        assert page.state()["title"] == "polygon 3" and page.state()["deleted"] == []
    page.focus("feature-list")
    page.press(page.keys.DELETE)
    state = page.state()
    assert state["deleted"] == [3] and state["options"] == 16 and state["title"] == "nothing selected"
    assert state["live"] == "status" and "polygon 3 deleted" in state["message"]
    page.pick(5)
    page.focus("map")
    page.press(page.keys.DELETE)
    assert page.state()["deleted"] == [3, 5]


def test_a_refused_vertex_drag_and_vertex_removal_say_so_visibly_and_to_screen_readers(page):
    page.pick(6)
    a, b, c, _ = page.driver.execute_script(RING_JS, "6")
    before = page.driver.execute_script(GEOMETRY_JS, "6")
    beyond_bc = [(b[0] + c[0]) * 0.75 - a[0] * 0.5, (b[1] + c[1]) * 0.75 - a[1] * 0.5]
    page.drag(a, beyond_bc)  # the edge from the last vertex now crosses B-C: Geoman puts A back
    state = page.state()
    assert state["refused"] and "cross itself" in state["message"] and state["live"] == "status"
    assert page.driver.find_element("id", "edit-message").is_displayed()
    assert page.driver.execute_script(GEOMETRY_JS, "6") == before and state["count"] == "no edits yet"
    page.right_click(a)  # four vertices to three: allowed
    assert page.state()["count"] == "edits: 1 geometry" and not page.state()["refused"]
    b, c, _ = page.driver.execute_script(RING_JS, "6")
    page.right_click(b)  # three to two: refused
    state = page.state()
    assert state["refused"] and "at least 3 vertices" in state["message"]
    assert len(page.driver.execute_script(GEOMETRY_JS, "6")["coordinates"][0]) == 4  # 3 + the closing one


def test_a_vertex_removal_that_makes_the_outline_cross_itself_is_refused(page):
    page.driver.execute_script("map.setView([37.7905, -122.3975], 19, {animate: false});")
    page.driver.find_element("css selector", ".leaflet-pm-icon-polygon").click()
    corners = [[200, 200], [400, 200], [400, 400], [300, 240], [200, 400]]  # a notch at the top
    for at in [*corners, corners[0]]:
        page._to(*at).click().perform()
    assert page.state()["title"] == "polygon new-1"
    before = page.driver.execute_script(GEOMETRY_JS, "new-1")
    page.right_click(corners[1])  # without it the edge from the corner crosses the notch's side
    state = page.state()
    assert state["refused"] and "cross itself" in state["message"] and state["count"] == "edits: 1 drawn"
    assert page.driver.execute_script(GEOMETRY_JS, "new-1") == before


# -- 2. undo -------------------------------------------------------------------------------------------
def test_ctrl_z_and_the_undo_button_take_back_moves_fields_classes_and_deletions(page, crossroads):
    from selenium.webdriver.support.ui import Select

    original = _original(crossroads)
    assert page.state()["undo_disabled"]
    page.pick(10)
    a, b, *_ = page.driver.execute_script(RING_JS, "10")
    page.drag(a, [a[0] + (a[0] - b[0]) * 0.2, a[1] + (a[1] - b[1]) * 0.2])  # outward along an edge
    assert page.state()["count"] == "edits: 1 geometry"
    street = page.driver.find_element("id", "field-street")
    street.send_keys(page.keys.CONTROL, "a")  # select the text: clear() would commit ''
    street.send_keys("Mission Street", page.keys.TAB)
    Select(page.driver.find_element("id", "feature-class")).select_by_value("crosswalk")
    assert page.state()["count"] == "edits: 1 geometry, 1 class, 1 fields"
    page.focus("feature-list")
    page.press(page.keys.DELETE)
    assert page.state()["deleted"] == [10] and page.state()["count"] == "edits: 1 deleted"

    page.press("z", ctrl=True)
    state = page.state()
    assert state["deleted"] == [] and state["options"] == 17 and state["title"] == "polygon 10"
    assert state["count"] == "edits: 1 geometry, 1 class, 1 fields" and "undone: deletion" in state["message"]
    page.driver.find_element("id", "undo").click()
    assert page.state()["cls"] == "sidewalk" and page.state()["count"] == "edits: 1 geometry, 1 fields"
    page.press("z", ctrl=True)  # the focus is on the undo button
    assert page.state()["street"] == "2nd Street" and page.state()["count"] == "edits: 1 geometry"
    page.press("z", ctrl=True)
    state = page.state()
    assert state["count"] == "no edits yet" and state["undo_disabled"]
    assert page.driver.execute_script(GEOMETRY_JS, "10") == original[10]["geometry"]
    # back to the file: the saved document holds its features exactly
    assert page.driver.execute_script("return curbsideEditor.editedDocument().features") == original


def test_undo_takes_back_a_drawn_polygon(page):
    from selenium.webdriver.support.ui import Select

    page.driver.execute_script("map.setView([37.7905, -122.3975], 19, {animate: false});")
    Select(page.driver.find_element("id", "draw-class")).select_by_value("building")
    page.driver.find_element("css selector", ".leaflet-pm-icon-rectangle").click()
    for at in ([300, 300], [360, 340]):
        page._to(*at).click().perform()
    assert page.state()["title"] == "polygon new-1" and page.state()["options"] == 18
    page.focus("map")
    page.press("z", ctrl=True)
    state = page.state()
    assert (state["options"], state["count"], state["title"]) == (17, "no edits yet", "nothing selected")
    ids = page.driver.execute_script("return curbsideEditor.editedDocument().features.map((f) => f.id)")
    assert ids == list(range(17))


# -- 3. --bbox saves the map file, ids and all --------------------------------------------------------------
def test_a_bbox_page_shows_whole_polygons_that_meet_the_window_and_keeps_the_others(crossroads, tmp_path):
    out = tmp_path / "edit.html"
    assert osmseg_main(["edit", str(crossroads), "--bbox", *WINDOW, "-o", str(out)]) == 0
    data, kept = _edit_data(out)
    original = _original(crossroads)
    shown = data["features"]
    assert data["kept_count"] == len(kept)
    assert 0 < len(shown) < 17 and sorted(f["id"] for f in shown + kept) == list(range(17))
    assert all(f == original[f["id"]] for f in shown + kept)  # the file's ids and geometry, unclipped
    window = shapely.box(*map(float, WINDOW))
    assert all(shapely.geometry.shape(f["geometry"]).intersects(window) for f in shown)
    assert not any(shapely.geometry.shape(f["geometry"]).intersects(window) for f in kept)
    assert data["window"] == [float(v) for v in WINDOW]
    assert data["meta"]["bbox"] == list(read_map(crossroads).gdf.to_crs(4326).total_bounds)


def test_a_bbox_edit_saves_every_feature_of_the_file_under_its_own_id(crossroads, tmp_path, capsys):
    out = tmp_path / "edit.html"
    assert osmseg_main(["edit", str(crossroads), "--bbox", *WINDOW, "-o", str(out)]) == 0
    assert "outside the window, saved as they are" in capsys.readouterr().out
    shown = [f["id"] for f in _edit_data(out)[0]["features"]]
    deleted = shown[1]
    with chromium(1280, 860, downloads=tmp_path) as driver:
        driver.get(out.as_uri())
        wait_for_mark(driver, "curbside:editor-ready")
        page = Page(driver)
        page.pick(deleted)
        assert page.state()["title"] == f"polygon {deleted}"
        page.press(page.keys.DELETE)
        driver.find_element("id", "save").click()
        target = tmp_path / "crossroads-edited.geojson"
        deadline = time.monotonic() + 20
        while not target.is_file() and time.monotonic() < deadline:
            time.sleep(0.1)
        assert console_errors(driver) == []
    doc = json.loads(target.read_text(encoding="utf-8"))
    assert doc["features"] == [f for f in _original(crossroads) if f["id"] != deleted]
    edits = doc["curbside"]["edits"]
    assert edits["deleted"] == [deleted] and edits["window"] == [float(v) for v in WINDOW]
    assert edits["from"] == "crossroads.geojson"
    cls = _original(crossroads)[deleted]["properties"]["class"]
    assert read_map(target).gdf["class"].value_counts()[cls] == (
        read_map(crossroads).gdf["class"].value_counts()[cls] - 1)
    report = tmp_path / "compare.json"
    assert osmseg_main(["compare", str(crossroads), str(target), "--json", str(report)]) == 0
    classes = json.loads(report.read_text())["classes"]
    assert classes[cls]["count_b"] == classes[cls]["count_a"] - 1
    others = [c for c in classes if c != cls]
    assert all(classes[c]["count_a"] == classes[c]["count_b"] for c in others)
