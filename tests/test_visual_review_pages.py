"""The pages a navigation-app builder opens, on a phone held upright (390 x 844 CSS pixels) in headless
Chromium: the map page, the replay page and the map editor keep their controls off each other and load
nothing from beside the page; a report fits the phone's width, its wide tables scrolling in their own box.
"""

from __future__ import annotations

from contextlib import contextmanager

import numpy as np
import pandas as pd
import pytest
from browser import chromium, console_errors, wait_for_mark
from viewer_fixtures import CROSSROADS, FRAME, START_XY

from curbside.cli.osmseg import main as osmseg_main
from curbside.evaluate.report import _html_page
from curbside.evaluate.report_tables import Table
from curbside.localize.view import ViewRun, view_page
from curbside.osmseg.mapio import read_map

PHONE = (390, 844)

# Boxes of the page's parts, in CSS pixels of the viewport ([left, top, right, bottom]; null when absent).
BOXES_JS = """
const box = (sel) => { const e = document.querySelector(sel); if (!e) return null;
  const r = e.getBoundingClientRect(); return [r.left, r.top, r.right, r.bottom]; };
return {scale: box(".leaflet-control-scale"), attribution: box(".leaflet-control-attribution"),
  layers: box(".leaflet-control-layers"), zoom: box(".leaflet-control-zoom"), panel: box("#panel"),
  map: box("#map"), editor: box("#editor"),
  expanded: document.querySelector(".leaflet-control-layers-expanded") !== null,
  toggle: getComputedStyle(document.querySelector(".leaflet-control-layers-toggle")).backgroundImage,
  resources: performance.getEntriesByType("resource").map((e) => e.name)};
"""


def _overlap(a, b) -> bool:
    return a[0] < b[2] and b[0] < a[2] and a[1] < b[3] and b[1] < a[3]


@contextmanager
def phone():
    """Chromium emulating a phone's screen (a headless window is at least 500 px wide)."""
    with chromium(1200, 900) as driver:
        driver.execute_cdp_cmd("Emulation.setDeviceMetricsOverride", {
            "width": PHONE[0], "height": PHONE[1], "deviceScaleFactor": 2, "mobile": True})
        yield driver


@pytest.fixture(scope="module")
def pages(tmp_path_factory):
    root = tmp_path_factory.mktemp("phone")
    assert osmseg_main(["show", str(CROSSROADS), "-o", str(root / "map.html")]) == 0
    assert osmseg_main(["edit", str(CROSSROADS), "-o", str(root / "edit.html")]) == 0
    along = np.linspace(0.0, 120.0, 61)
    lon, lat = FRAME.to_lonlat(START_XY[0] + along, np.full(len(along), START_XY[1]))
    track = pd.DataFrame({"t": along / 1.3, "lat": lat, "lon": lon, "accuracy_m": 3.0,
                          "sidewalk_segment_id": "s4", "segment_prob": 0.9})
    runs = [ViewRun("curbside fused", track, mode="fused")]
    page = view_page(runs, maps={"crossroads": read_map(CROSSROADS)})
    (root / "view.html").write_text(page, encoding="utf-8")
    headings = [f"column heading {k}" for k in range(14)]
    wide = Table("a wide table", headings, [[f"{k:.3f}" for k in range(14)]])
    (root / "report.html").write_text(_html_page("A report.", [wide], [], {}), encoding="utf-8")
    return root


@pytest.mark.parametrize("name", ["map.html", "view.html", "edit.html"])
def test_on_a_phone_the_legend_folds_and_no_control_covers_another(pages, name):
    with phone() as d:
        d.get((pages / name).as_uri())
        if name == "view.html":
            wait_for_mark(d, "curbside:slider-ready")
        boxes = d.execute_script(BOXES_JS)
        assert not boxes["expanded"]  # the layer control is its button: the legend is a tap away
        assert not _overlap(boxes["scale"], boxes["attribution"])
        others = [boxes[k] for k in ("layers", "zoom", "panel") if boxes[k] is not None]
        assert not any(_overlap(a, b) for i, a in enumerate(others) for b in others[i + 1:])
        # the button's icon is inlined: nothing is fetched from beside the page (images/layers.png)
        assert boxes["toggle"].startswith('url("data:image/svg+xml')
        assert boxes["resources"] == [] and console_errors(d) == []


def test_on_a_wide_screen_the_legend_stays_open(pages):
    with chromium(1200, 800) as d:
        d.get((pages / "map.html").as_uri())
        assert d.execute_script(BOXES_JS)["expanded"]


def test_the_editor_on_a_phone_keeps_a_usable_map_above_its_form(pages):
    with phone() as d:
        d.get((pages / "edit.html").as_uri())
        wait_for_mark(d, "curbside:editor-ready")
        boxes = d.execute_script(BOXES_JS)
        left, top, right, bottom = boxes["map"]
        assert right - left == pytest.approx(PHONE[0], abs=1) and bottom - top >= 0.4 * PHONE[1]
        assert boxes["editor"][1] >= bottom - 1  # the form below the map, not beside it


def test_a_report_fits_a_phone_and_its_wide_tables_scroll_in_their_box(pages):
    with phone() as d:
        d.get((pages / "report.html").as_uri())
        width = d.execute_script("return [window.innerWidth, document.documentElement.scrollWidth]")
        assert width == [PHONE[0], PHONE[0]]  # laid out for the phone, no page-wide sideways scroll
        box = d.execute_script(
            "const b = document.querySelector('table').parentElement;"
            "return [getComputedStyle(b).overflowX, b.scrollWidth > b.clientWidth];")
        assert box == ["auto", True]
