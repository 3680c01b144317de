"""An estimate far from the sidewalk segment it names says so: ``segment_distance_m`` in ``track.csv`` and
the service's estimates, and "off the sidewalk, 19 m from Market Street, north side" in their words and
the replay page's panel; ``track.csv``'s other columns are what the code before it wrote, byte for byte.
"""

from __future__ import annotations

import json
import re
from types import SimpleNamespace

import numpy as np
import pandas as pd
import pyproj
import pytest
import shapely
from viewer_fixtures import CROSSROADS, write_session

from curbside import settings
from curbside.cli.localize import main as localize_main
from curbside.localize.engine import Row
from curbside.localize.serve.answers import estimate_of
from curbside.localize.serve.models import Estimate
from curbside.localize.track_result import OFF_SIDEWALK_M, place_text, sidewalk_shapes
from curbside.localize.view import ViewRun, view_page
from curbside.osmseg.mapio import read_map
from curbside.osmseg.places import sidewalk_places
from curbside.projection import LocalFrame

#: The modes the fixture walk is run in: the distance under a fix (gnss) and off a crossing (fused).
MODES = ("gnss", "fused")
#: On the crossroads map: inside segment s0 (Market Street's north sidewalk, y 4182747.9-4182751.9 m),
#: and 19.1 m north of it, farther still from every other sidewalk.
ON_S0 = (553080.0, 4182750.0)
FAR_NORTH_OF_S0 = (553080.0, 4182771.0)


@pytest.fixture(scope="module")
def layers():
    return read_map(CROSSROADS)


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    root = tmp_path_factory.mktemp("offwalk")
    cache, settings.cache_dir = settings.cache_dir, root / "cache"
    try:
        walk = write_session(root / "walk")
        for mode in MODES:
            args = ["run", str(walk), "--map", str(CROSSROADS), "--mode", mode, "--particles", "200",
                    "--seed", "5", "-o", str(root / mode)]
            assert localize_main(args) == 0
    finally:
        settings.cache_dir = cache
    return root


def _estimate(layers, xy: tuple[float, float]) -> dict:
    """The service's answer for a session whose latest update is at ``xy`` and names segment s0."""
    row = Row(t=10.0, x=xy[0], y=xy[1], kind="step", fix_used=True, n_eff=400.0, segment_id="s0",
              segment_prob=0.97, accuracy_m=2.0, motion="default")
    live = SimpleNamespace(rows=[row], frame=LocalFrame(pyproj.CRS(layers.crs)), map_layers=layers,
                           notices=list, failed=None, recoveries=0, engine=None, received_until=10.5)
    out = estimate_of(live, sidewalk_places(layers))
    return Estimate.model_validate(out).model_dump()


def test_place_text_says_off_the_sidewalk_beyond_the_threshold():
    label = "Fremont Street, southwest side"
    assert place_text(label, 18.68) == "off the sidewalk, 19 m from Fremont Street, southwest side"
    just_off = place_text(label, OFF_SIDEWALK_M + 0.01)
    assert just_off == "off the sidewalk, 3 m from Fremont Street, southwest side"
    for on in (0.0, 1.5, OFF_SIDEWALK_M, None, float("nan")):
        assert place_text(label, on) == label


def test_an_estimate_far_from_every_sidewalk_is_off_the_sidewalk(layers):
    sidewalks = layers.layer("sidewalk").geometry.to_numpy()
    far = shapely.Point(FAR_NORTH_OF_S0)
    assert shapely.distance(sidewalks, far).min() > OFF_SIDEWALK_M  # far from every sidewalk
    s0 = layers.gdf.loc[layers.gdf["segment_id"] == "s0", "geometry"].iloc[0]
    estimate = _estimate(layers, FAR_NORTH_OF_S0)
    assert estimate["segment_id"] == "s0" and estimate["segment_prob"] == 0.97  # as the filter said
    assert estimate["segment_distance_m"] == pytest.approx(s0.distance(far)) == pytest.approx(19.1, abs=0.05)
    assert estimate["place"] == "off the sidewalk, 19 m from Market Street, north side"
    assert (estimate["street"], estimate["side"]) == ("Market Street", "north")


def test_an_estimate_on_its_sidewalk_has_distance_zero_and_the_usual_words(layers):
    estimate = _estimate(layers, ON_S0)
    assert estimate["segment_distance_m"] == 0.0
    assert estimate["place"] == "Market Street, north side"


def test_distances_count_nothing_for_no_segment_or_an_unknown_one(layers):
    shapes = sidewalk_shapes(layers)
    assert sidewalk_shapes(layers) is shapes  # made once per map
    x, y = np.array([ON_S0[0]] * 4), np.array([ON_S0[1]] * 4)
    out = shapes.distances_m(["s0", None, np.nan, "nowhere"], x, y)
    assert out[0] == 0.0 and np.isnan(out[1:]).all()


@pytest.mark.parametrize("mode", MODES)
def test_track_csv_adds_the_distance_as_its_last_column(runs, layers, mode):
    path = runs / mode / "track.csv"
    lines = path.read_text().splitlines(keepends=True)
    assert lines[0].rstrip("\n").endswith(",mode_lat,mode_lon,segment_distance_m")
    track = pd.read_csv(path)
    named = track["sidewalk_segment_id"].notna().to_numpy()
    polygons = layers.gdf.set_index("segment_id").loc[track["sidewalk_segment_id"][named], "geometry"]
    expected = shapely.distance(polygons.to_numpy(), shapely.points(track["x_m"][named], track["y_m"][named]))
    # x_m, y_m are written to 0.1 mm (10 significant digits)
    np.testing.assert_allclose(track["segment_distance_m"][named], expected, rtol=0, atol=2e-4)
    assert track["segment_distance_m"][~named].isna().all()
    if mode == "gnss":  # the segment under the fix: on it
        assert (track["segment_distance_m"][named] == 0).all()
    else:  # on the north crosswalk, between the two north sidewalks, it is off them
        crossing = track["segment_distance_m"].to_numpy() > OFF_SIDEWALK_M
        assert crossing.any() and (track.loc[crossing, "x_m"].between(553042.3, 553054.3)).all()


def _page_run(page: str) -> dict:
    match = re.search(r"const VIEW = ", page)
    return json.JSONDecoder().raw_decode(page, match.end())[0]["runs"][0]


def _far_then_on_track() -> pd.DataFrame:
    frame = LocalFrame(pyproj.CRS(32610))
    (x0, y0), (x1, y1) = FAR_NORTH_OF_S0, ON_S0
    lon, lat = frame.to_lonlat(np.array([x0, x1]), np.array([y0, y1]))
    return pd.DataFrame({"t": [0.0, 1.0], "lat": lat, "lon": lon, "sidewalk_segment_id": ["s0", "s0"]})


def test_the_replay_page_gets_the_off_sidewalk_metres_with_or_without_the_column():
    bare = _far_then_on_track()  # a track written before segment_distance_m: worked out on its map
    data = _page_run(view_page([ViewRun("old", bare, map_path=str(CROSSROADS))], maps={}))
    assert data["off_sidewalk_m"] == [19.0, None]
    assert data["off_sidewalk_text"].format(distance_m=19, place="Market Street, north side") == place_text(
        "Market Street, north side", 19.1
    )
    given = bare.assign(segment_distance_m=[7.4, 0.0])  # the track's own column wins
    data = _page_run(view_page([ViewRun("new", given, map_path=str(CROSSROADS))], maps={}))
    assert data["off_sidewalk_m"] == [7.0, None]


def test_the_replay_panel_says_off_the_sidewalk(tmp_path):
    from browser import chromium, console_errors, wait_for_mark
    from selenium.webdriver.common.keys import Keys

    page = tmp_path / "view.html"
    run = ViewRun("walk", _far_then_on_track(), map_path=str(CROSSROADS))
    page.write_text(view_page([run], maps={}), encoding="utf-8")
    with chromium(1200, 800) as driver:
        driver.get(page.as_uri())
        wait_for_mark(driver, "curbside:slider-ready")
        slider = driver.find_element("id", "slider")
        cell = driver.find_elements("css selector", "#run-table tbody tr td")[1]
        slider.send_keys(Keys.HOME)
        assert cell.text == "off the sidewalk, 19 m from Market Street, north side"
        assert cell.get_attribute("title") == "s0"
        slider.send_keys(Keys.END)
        assert cell.text == "Market Street, north side"
        assert console_errors(driver) == []
