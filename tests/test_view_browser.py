"""The replay viewer in headless Chromium: it loads with no console error, the slider moves the particle
cloud and the panel, play advances the time, and the layers toggle."""

from __future__ import annotations

import time

import pandas as pd
import pytest
from browser import chromium, console_errors, wait_for_mark
from viewer_fixtures import CROSSROADS, write_runs

from curbside import settings
from curbside.cli.localize import main as localize_main

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
    assert track["sidewalk_segment_id"].iat[k] in fused_row.text
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
