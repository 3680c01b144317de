"""Review s49 (viewer accessibility, phone width, the demo's particle count).

The replay page speaks to a screen reader: the slider's value in words (time, step, place), a polite
live region that says the place (throttled while the walk plays), a play button named before its first
press, full names for the "p" and "n_eff" headings. On a phone-wide screen (360-500 CSS px) the open
panel fits beside the layer control and scrolls its table, and the opened layer control shows above it.
The demo's replay tracks its walk as the benchmark report scores it (same N, jaywalk weight and seed), and
the report states N and, in ``report.md`` too, the OpenStreetMap attribution.
"""

from __future__ import annotations

import json
import time

import numpy as np
import pandas as pd
import pytest
from browser import chromium, console_errors, wait_for_mark
from viewer_fixtures import CROSSROADS, FRAME, START_XY, write_session

from curbside import demo, settings
from curbside.cli.localize import main as localize_main
from curbside.evaluate.report import write_report
from curbside.evaluate.runner import RunSpec, run_one
from curbside.localize.session import read_session
from curbside.localize.view import ViewRun, view_page
from curbside.osmseg.mapio import read_map

#: Footsteps of the synthetic walk, half a second apart; its place changes every other footstep.
STEPS = 160
# Records, from now on, when (ms) and while playing or not the live region, the slider's value text and
# the fused run's place in the panel change.
WATCH_LIVE_JS = """
const live = document.querySelector('[aria-live="polite"]'), slider = document.getElementById('slider');
const place = curbsideView.runs[curbsideView.runs.length - 1].cells[0];
window.changes = {said: [], valued: [], place: []};
const note = (name) => () => window.changes[name].push([performance.now(), curbsideView.state.playing]);
const text = {childList: true, characterData: true, subtree: true};
new MutationObserver(note('said')).observe(live, text);
new MutationObserver(note('valued')).observe(slider, {attributeFilter: ['aria-valuetext']});
new MutationObserver(note('place')).observe(place, text);
"""
PLACE_JS = "return curbsideView.runs[curbsideView.runs.length - 1].cells[0].textContent"


def _track(t: np.ndarray, offset_m: float, every: int) -> pd.DataFrame:
    lon, lat = FRAME.to_lonlat(START_XY[0] + 1.3 * t, np.full(len(t), START_XY[1] + offset_m))
    side = np.where((np.arange(len(t)) // every) % 2 == 0, "s4", "s2")
    return pd.DataFrame({"t": t, "lat": lat, "lon": lon, "sidewalk_segment_id": side, "segment_prob": 0.8,
                         "accuracy_m": 4.0, "n_eff": 90.0, "recovered": 0})


@pytest.fixture(scope="module")
def page(tmp_path_factory):
    """A GNSS run and a curbside fused run of the crossroads walk whose sidewalk changes every other
    footstep (s4, s2: Market Street's north and south sides), with every column of the panel and the
    waypoint summaries."""
    root = tmp_path_factory.mktemp("a11y")
    session = read_session(write_session(root / "walk"))
    t = np.arange(STEPS) * 0.5
    kinds = (("GNSS", "gnss", -4.0, 7), ("curbside fused", "fused", 0.0, 2))
    runs = [ViewRun(label, _track(t, offset_m, every), session, "walk", mode, segment_map=str(CROSSROADS))
            for label, mode, offset_m, every in kinds]
    out = root / "view.html"
    out.write_text(view_page(runs, maps={"crossroads": read_map(CROSSROADS)}), encoding="utf-8")
    return out


@pytest.fixture(scope="module")
def driver(page):
    with chromium(1200, 800) as d:
        d.get(page.as_uri())
        wait_for_mark(d, "curbside:slider-ready")
        yield d


def test_the_slider_says_the_time_the_step_and_the_place(driver):
    from selenium.webdriver.common.keys import Keys

    slider = driver.find_element("id", "slider")
    slider.send_keys(Keys.HOME + Keys.ARROW_RIGHT * 6)
    place = driver.execute_script(PLACE_JS)  # the panel's words for the fused run's place (on s2)
    assert "Market Street" in place
    assert slider.get_attribute("aria-valuetext") == f"t = 3.0 s, step 7 of {STEPS}, {place}"
    assert console_errors(driver) == []


def test_the_play_button_and_the_short_headings_have_names(driver):
    play = driver.find_element("id", "play")
    assert play.get_attribute("aria-label") == "play" and play.accessible_name == "play"  # not "▶"
    prob = driver.find_element("css selector", '#run-table th[data-col="prob"]')
    assert prob.accessible_name == "probability of the sidewalk segment"
    assert "probability" in prob.find_element("tag name", "abbr").get_attribute("title")
    neff = driver.find_element("css selector", '#run-table th[data-col="neff"]')
    assert neff.accessible_name == "effective sample size"
    assert "probability" not in prob.text.split("\n")[0]  # the full name is not shown


def test_stepping_says_the_place_and_playing_says_it_no_more_than_every_few_seconds(driver):
    live = driver.find_element("css selector", '[aria-live="polite"]')
    assert live.get_attribute("role") == "status" and live.size["width"] <= 1  # heard, not shown
    driver.execute_script("document.activeElement.blur(); curbsideView.setIndex(10)")
    south = driver.execute_script(PLACE_JS)
    assert live.get_attribute("textContent") == south
    driver.execute_script("curbsideView.setIndex(12)")
    assert live.get_attribute("textContent") == driver.execute_script(PLACE_JS) != south

    driver.execute_script(WATCH_LIVE_JS + "document.getElementById('speed').value = '4';")
    driver.find_element("id", "play").click()  # the place changes about 4 times a second at 4x
    time.sleep(9.0)
    driver.find_element("id", "play").click()
    changes = driver.execute_script("return window.changes")
    assert not driver.execute_script("return curbsideView.state.playing")
    assert sum(playing for _, playing in changes["place"]) >= 8  # the place changed, time and again
    for name in ("said", "valued"):  # while playing, at most every ANNOUNCE_EVERY_MS (4 s)
        times = [ms for ms, playing in changes[name] if playing]
        assert len(times) >= 1 and (np.diff(times) >= 3990).all(), (name, changes)
    assert live.get_attribute("textContent") == driver.execute_script(PLACE_JS)  # where it stopped
    stopped_at, t = driver.execute_script("return [curbsideView.state.index, curbsideView.state.time]")
    assert stopped_at > 12 + 60  # it played some 36 s of the walk
    assert driver.find_element("id", "slider").get_attribute("aria-valuetext").startswith(
        f"t = {t:.1f} s, step {stopped_at + 1} of {STEPS}")  # where it stopped


def test_a_step_of_the_slider_in_focus_says_the_place_in_its_value_alone(driver):
    from selenium.webdriver.common.keys import Keys

    driver.execute_script("document.activeElement.blur(); curbsideView.setIndex(20)")
    live = driver.find_element("css selector", '[aria-live="polite"]')
    assert live.get_attribute("textContent") == driver.execute_script(PLACE_JS)
    slider = driver.find_element("id", "slider")
    slider.send_keys(Keys.ARROW_RIGHT * 2)  # 20 -> 22: the other side of the street
    place = driver.execute_script(PLACE_JS)
    assert slider.get_attribute("aria-valuetext").endswith(place)
    assert live.get_attribute("textContent") == ""  # not said twice


@pytest.mark.parametrize("width", [360, 420, 500])
def test_on_a_phone_the_open_panel_fits_beside_the_layer_control(page, width):
    with chromium(500, 800) as d:  # headless Chromium's window is 500 px wide at least: emulate the phone
        d.execute_cdp_cmd("Emulation.setDeviceMetricsOverride",
                          {"width": width, "height": 740, "deviceScaleFactor": 1, "mobile": False})
        d.get(page.as_uri())
        wait_for_mark(d, "curbside:slider-ready")
        toggle = d.find_element("id", "panel-toggle")
        assert toggle.get_attribute("aria-expanded") == "false"  # a phone starts with the map
        toggle.click()
        box = d.execute_script("""
          const box = (e) => { const r = e.getBoundingClientRect();
            return [r.left, r.top, r.right, r.bottom]; };
          const table = document.getElementById('run-table').parentElement;
          return {panel: box(document.getElementById('panel')), legend: box(layers.getContainer()),
                  items: [...document.querySelectorAll('#summaries li, #gnss-now')].map(box),
                  table: box(table), scrolls: getComputedStyle(table).overflowX,
                  width: window.innerWidth};""")
        panel, legend = box["panel"], box["legend"]
        assert box["width"] == width
        assert panel[2] <= legend[0] - 4, box  # clear of the layer control's button
        assert box["table"][2] <= panel[2] and box["scrolls"] == "auto"  # a wide table scrolls in its box
        assert all(item[2] <= panel[2] for item in box["items"])  # the summaries wrap inside
        # the layer control, opened, lies over the panel (not under it)
        d.execute_script("layers.expand()")
        inside = d.execute_script("""
          const l = layers.getContainer().getBoundingClientRect(), p = document.getElementById('panel')
            .getBoundingClientRect();
          const x = (Math.max(l.left, p.left) + Math.min(l.right, p.right)) / 2;
          const y = (Math.max(l.top, p.top) + Math.min(l.bottom, p.bottom)) / 2;
          return document.elementFromPoint(x, y).closest('.leaflet-control-layers') !== null;""")
        assert inside
        assert console_errors(d) == []


# -- the demo's replay and the report's N ---------------------------------------------------------------

BASE = {"map": "osm", "jaywalk_weight": 0.4, "particles": 100, "gnss_sigma_factor": None}


def _report_dir(root, base=BASE):
    folder = root / "report"
    folder.mkdir(parents=True)
    (folder / "metrics.json").write_text(json.dumps({"base": base}))
    return folder


def test_the_demo_replays_with_the_reports_options(tmp_path, monkeypatch):
    assert demo.report_run_options(_report_dir(tmp_path)) == [
        "--particles", "100", "--jaywalk-weight", "0.4", "--seed", "0"]
    sigma = _report_dir(tmp_path / "s", {**BASE, "gnss_sigma_factor": 2.0})
    assert demo.report_run_options(sigma)[-2:] == ["--set", "filter.gnss.sigma_factor=2.0"]

    calls = []
    monkeypatch.setattr("curbside.cli.localize.main", lambda args: calls.append(args) or 0)
    (tmp_path / "sessions" / "path1-s1").mkdir(parents=True)
    ctx = demo.DemoContext(tmp_path, {"benchmark": {"sessions": tmp_path / "sessions",
                                                    "report": tmp_path / "report"}})
    demo.replay_stage(ctx)
    runs = [args for args in calls if args[1] == "run"]
    assert len(runs) == 3
    for args in runs:
        at = args.index("--particles")
        assert args[at:at + 6] == ["--particles", "100", "--jaywalk-weight", "0.4", "--seed", "0"]


@pytest.fixture(scope="module")
def scored(tmp_path_factory):
    """The crossroads walk scored by the benchmark's runner at the base parameters (N = 100)."""
    root = tmp_path_factory.mktemp("scored")
    cache = settings.cache_dir
    settings.cache_dir = root / "cache"
    try:
        session = write_session(root / "walk")
        specs = [RunSpec(str(session), "gnss", None, "osm", str(CROSSROADS), particles=100),
                 RunSpec(str(session), "fused", str(CROSSROADS), "osm", str(CROSSROADS), particles=100)]
        yield root, session, [run_one(spec) for spec in specs]
    finally:
        settings.cache_dir = cache


def test_localize_run_with_the_reports_options_tracks_what_the_report_scored(scored):
    root, session, results = scored
    options = demo.report_run_options(_report_dir(root))
    out = root / "fused"
    assert localize_main(["run", str(session), "--map", str(CROSSROADS), "--mode", "fused", *options,
                          "-o", str(out)]) == 0
    track = pd.read_csv(out / "track.csv")
    for axis in ("x_m", "y_m"):  # UTM metres: to the millimetre
        np.testing.assert_allclose(track[axis], results[1]["track"][axis], rtol=0, atol=1e-3)
    # localize run's own default (N = 2000) tracks another walk: the figures the demo used to show
    assert localize_main(["run", str(session), "--map", str(CROSSROADS), "--mode", "fused",
                          "-o", str(root / "default")]) == 0
    assert np.abs(pd.read_csv(root / "default" / "track.csv")["x_m"] - track["x_m"]).max() > 0.1


def test_the_report_states_n_and_report_md_credits_openstreetmap(scored, tmp_path):
    from curbside.evaluate.report import base_text

    _, _, results = scored
    write_report(results, tmp_path / "report", BASE, read_map(CROSSROADS))
    said = base_text(BASE)
    assert said.startswith("Base parameters: N = 100 particles in every particle filter (localize run's "
                           "default: RoNIN+PF 2000, paper PF 500, curbside fused 2000), jaywalk weight "
                           "w = 0.4")
    md = (tmp_path / "report" / "report.md").read_text(encoding="utf-8")
    html = (tmp_path / "report" / "report.html").read_text(encoding="utf-8")
    assert f"\n{said}\n" in md and f"<p>{said.replace(chr(39), '&#x27;')}</p>" in html
    assert md.rstrip().endswith(settings.osm_attribution)
    assert "N = 500 particles in every particle filter (localize run's default: RoNIN+PF 2000, curbside " \
           "fused 2000)" in base_text({**BASE, "particles": 500})
