"""The replay viewer in headless Chromium: it loads with no console error, the slider moves the particle
cloud and the panel, play advances the time, and the layers toggle; the fitted walk lies clear of the
panel and the layer control, the panel folds, and the panel and legend show only what the runs hold."""

from __future__ import annotations

import time

import numpy as np
import pandas as pd
import pytest
from browser import chromium, console_errors, wait_for_mark
from viewer_fixtures import CROSSROADS, FRAME, START_XY, write_runs

from curbside import settings
from curbside.cli.localize import main as localize_main
from curbside.localize.view import ViewRun, view_page
from curbside.osmseg.mapio import read_map
from curbside.osmseg.places import sidewalk_places

# The centre of the cloud canvas's drawn pixels, in CSS pixels of the map container.
CLOUD_CENTRE_JS = """
const canvas = document.querySelector("canvas.curbside-time-canvas");
const ratio = window.devicePixelRatio || 1;
const {data, width, height} = canvas.getContext("2d").getImageData(0, 0, canvas.width, canvas.height);
let n = 0, sx = 0, sy = 0;
for (let y = 0; y < height; y++) for (let x = 0; x < width; x++) {
  if (data[4 * (y * width + x) + 3] > 0) { n++; sx += x; sy += y; }
}
return n ? [sx / n / ratio, sy / n / ratio, n] : null;
"""
CLOUD_CANVASES_JS = "return document.querySelectorAll('canvas.curbside-time-canvas').length"


@pytest.fixture(scope="module")
def page(tmp_path_factory):
    root = tmp_path_factory.mktemp("view")
    cache = settings.cache_dir
    settings.cache_dir = root / "cache"
    try:
        runs = write_runs(root, CROSSROADS)
    finally:
        settings.cache_dir = cache
    out = root / "view.html"
    assert localize_main(["view", *map(str, runs), "-o", str(out)]) == 0
    return out, runs


@pytest.fixture(scope="module")
def driver(page):
    with chromium(1200, 800) as d:
        d.get(page[0].as_uri())
        wait_for_mark(d, "curbside:slider-ready")
        yield d


def _set_slider(driver, keys):
    slider = driver.find_element("id", "slider")
    slider.send_keys(keys)
    return int(slider.get_attribute("value"))


def test_loads_offline_with_no_console_error(driver):
    assert console_errors(driver) == []
    assert driver.find_element("id", "slider").is_enabled()
    assert driver.execute_script(CLOUD_CANVASES_JS) == 1
    attribution = driver.find_element("class name", "leaflet-control-attribution").text
    assert "OpenStreetMap contributors" in attribution


def test_the_slider_moves_the_cloud_and_the_panel(driver, page):
    from selenium.webdriver.common.keys import Keys

    driver.execute_script("map.setZoom(18, {animate: false});")
    assert _set_slider(driver, Keys.HOME) == 0
    start = driver.execute_script(CLOUD_CENTRE_JS)
    clock_start = driver.find_element("id", "clock").text
    index = _set_slider(driver, Keys.ARROW_RIGHT * 60)
    assert index == 60
    moved = driver.execute_script(CLOUD_CENTRE_JS)
    assert start is not None and moved is not None
    # the walker goes east at 1.3 m/s: about 33 s later the cloud is tens of pixels to the right
    assert moved[0] - start[0] > 20 and abs(moved[1] - start[1]) < 15
    assert driver.find_element("id", "clock").text != clock_start
    track = pd.read_csv(page[1][1] / "track.csv")
    t = driver.execute_script("return curbsideView.state.time")
    k = int((track["t"] <= t + 1e-9).sum()) - 1
    fused_row = driver.find_elements("css selector", "#run-table tbody tr")[1]
    segment = fused_row.find_elements("css selector", "td")[1]
    segment_id = track["sidewalk_segment_id"].iat[k]
    # the street and its compass side in words; the map's segment id in the tooltip
    place = sidewalk_places(read_map(CROSSROADS))[segment_id]
    assert segment.text == place.label == "Market Street, north side"
    assert segment.get_attribute("title") == segment_id
    assert f"/ {track['accuracy_m'].iat[k]:.1f} m" in fused_row.text  # the estimate's 68 % radius
    radius = "return curbsideView.runs[1].radius.getRadius()"
    assert driver.execute_script(radius) == pytest.approx(track["accuracy_m"].iat[k], abs=0.051)
    assert console_errors(driver) == []


def test_play_advances_and_pauses(driver):
    from selenium.webdriver.common.keys import Keys

    start = _set_slider(driver, Keys.HOME)
    driver.find_element("id", "play").click()
    time.sleep(1.5)
    driver.find_element("id", "play").click()
    stopped = int(driver.find_element("id", "slider").get_attribute("value"))
    assert stopped > start  # 4x real time for 1.5 s: about 6 s of walk, about 10 footsteps
    time.sleep(0.5)
    assert int(driver.find_element("id", "slider").get_attribute("value")) == stopped


def _toggle(driver, label_text):
    for label in driver.find_elements("css selector", ".leaflet-control-layers-overlays label"):
        if label_text in label.text:
            box = label.find_element("css selector", "input")
            box.click()
            return box.is_selected()
    raise AssertionError(f"no layer {label_text!r} in the layer control")


def test_layers_toggle(driver):
    assert _toggle(driver, "fused: particles") is False
    assert driver.execute_script(CLOUD_CANVASES_JS) == 0
    assert _toggle(driver, "fused: particles") is True
    assert driver.execute_script(CLOUD_CANVASES_JS) == 1
    buildings = (
        "return layers._layers.filter(o => o.name.includes('building')).map(o => map.hasLayer(o.layer))"
    )
    assert driver.execute_script(buildings) == [True]
    assert _toggle(driver, "building") is False
    assert driver.execute_script(buildings) == [False]
    assert console_errors(driver) == []


# -- the view, the panel and the legend ---------------------------------------------------------------

# Every drawn track point in map-container pixels, and the boxes of the panel (with the zoom buttons)
# and of the layer control.
LAYOUT_JS = """
const m = map.getContainer().getBoundingClientRect();
const box = (el) => { const r = el.getBoundingClientRect();
  return [r.left - m.left, r.top - m.top, r.right - m.left, r.bottom - m.top]; };
const points = curbsideView.runs.flatMap((v) => v.data.lat.map((lat, i) => [lat, v.data.lon[i]]))
  .filter((p) => p[0] !== null).map((p) => { const q = map.latLngToContainerPoint(p); return [q.x, q.y]; });
return {points, panel: box(document.getElementById("panel")), legend: box(layers.getContainer()),
  zoom: box(document.querySelector(".leaflet-control-zoom")), size: [map.getSize().x, map.getSize().y]};
"""


def _inside(point, box):
    return box[0] <= point[0] <= box[2] and box[1] <= point[1] <= box[3]


def _overlap(a, b):
    return a[0] < b[2] and b[0] < a[2] and a[1] < b[3] and b[1] < a[3]


@pytest.fixture(scope="module")
def corner_walk(tmp_path_factory):
    """A run over the crossroads map that starts at the north-west corner of its extent (under the panel
    of a view fitted edge to edge), goes 160 m east then 100 m south (the screen's aspect, so that such a
    view would reach the top left corner); no ground truth, 68 % radius or n_eff."""
    along = np.linspace(0.0, 260.0, 131)
    x = START_XY[0] - 40.0 + np.minimum(along, 160.0)
    y = START_XY[1] + 40.0 - np.maximum(along - 160.0, 0.0)
    lon, lat = FRAME.to_lonlat(x, y)
    track = pd.DataFrame({"t": along / 1.3, "lat": lat, "lon": lon,
                          "sidewalk_segment_id": "s4", "segment_prob": 0.9})
    page = tmp_path_factory.mktemp("corner") / "view.html"
    run = ViewRun("paper PF", track, mode="paper")
    page.write_text(view_page([run], maps={"crossroads": read_map(CROSSROADS)}), encoding="utf-8")
    return page


@pytest.mark.parametrize(("width", "height"), [(1400, 900), (800, 600)])
def test_the_fitted_walk_lies_clear_of_the_panel_and_the_legend(corner_walk, width, height):
    with chromium(width, height) as d:
        d.get(corner_walk.as_uri())
        wait_for_mark(d, "curbside:slider-ready")
        layout = d.execute_script(LAYOUT_JS)
        assert not _overlap(layout["panel"], layout["legend"])  # the panel leaves the legend readable
        covered = [p for p in layout["points"]
                   if any(_inside(p, layout[k]) for k in ("panel", "legend", "zoom"))]
        assert covered == []
        # the whole walk is on screen, the start included
        assert all(0 <= x <= layout["size"][0] and 0 <= y <= layout["size"][1] for x, y in layout["points"])
        assert console_errors(d) == []


def test_the_panel_folds_and_unfolds(corner_walk):
    with chromium(1400, 900) as d:
        d.get(corner_walk.as_uri())
        wait_for_mark(d, "curbside:slider-ready")
        table, toggle = d.find_element("id", "run-table"), d.find_element("id", "panel-toggle")
        assert table.is_displayed() and toggle.get_attribute("aria-expanded") == "true"
        toggle.click()
        assert not table.is_displayed() and toggle.get_attribute("aria-expanded") == "false"
        assert d.find_element("id", "clock").is_displayed()  # the time stays in the folded panel
        toggle.click()
        assert table.is_displayed() and toggle.text == "hide"


def test_the_panel_and_legend_show_only_what_the_run_holds(corner_walk):
    with chromium(1400, 900) as d:
        d.get(corner_walk.as_uri())
        wait_for_mark(d, "curbside:slider-ready")
        legend = d.find_element("css selector", ".leaflet-control-layers-overlays").text
        assert "paper PF: track and estimate" in legend and "68 % radius" not in legend
        # each heading's first line: a short one's full name, visually hidden, follows for screen readers
        headings = [th.text.split("\n")[0] for th in d.find_elements("css selector", "#run-table th")
                    if th.is_displayed()]
        assert headings == ["run", "sidewalk segment", "p", "recoveries"]  # no truth, radius or n_eff
        cells = [td.text for td in d.find_elements("css selector", "#run-table td") if td.is_displayed()]
        assert cells[1:] == ["s4", "0.90", "0 / 0"]  # a run with no map to name its segments by: the id


def test_on_a_small_screen_the_panel_starts_folded_off_the_legend(page):
    with chromium(800, 600) as d:
        d.get(page[0].as_uri())
        wait_for_mark(d, "curbside:slider-ready")
        layout = d.execute_script(LAYOUT_JS)
        assert not _overlap(layout["panel"], layout["legend"])
        assert not d.find_element("id", "run-table").is_displayed()
        assert d.find_element("id", "panel-toggle").text == "show"
        covered = [p for p in layout["points"] if _inside(p, layout["panel"]) or _inside(p, layout["legend"])]
        assert covered == []
