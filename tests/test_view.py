"""The replay viewer's data path: the compact particle store, the page's contents, the CLI and its errors,
and the waypoint error. The page in a real browser: ``test_view_browser.py``."""

from __future__ import annotations

import base64
import json
import re

import numpy as np
import pandas as pd
import pyproj
import pytest
from viewer_fixtures import CROSSROADS, write_runs

from curbside import settings
from curbside.cli.localize import main as localize_main
from curbside.errors import CurbsideInputError
from curbside.evaluate.metrics import format_waypoint_summary, waypoint_errors, waypoint_summary
from curbside.localize.particle_store import (
    FORMAT,
    ParticleClouds,
    pack_particles,
    pack_snapshots,
    read_particles,
    unpack_particles,
    write_particles,
)
from curbside.localize.view import ViewRun, _result_track, label_runs, load_run, view_page
from curbside.localize.view_data import MAX_DRAWN_PARTICLES, PAGE_OFFSET_UNIT_DEG
from curbside.localize.view_data import cloud_data as _cloud_data
from curbside.osmseg.mapio import read_map
from curbside.osmseg.places import sidewalk_places
from curbside.projection import LocalFrame

UTM10N = "EPSG:32610"


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    root = tmp_path_factory.mktemp("runs")
    cache = settings.cache_dir
    settings.cache_dir = root / "cache"
    try:
        return write_runs(root, CROSSROADS)
    finally:
        settings.cache_dir = cache


def _page_data(page: str) -> dict:
    match = re.search(r"const VIEW = ", page)
    return json.JSONDecoder().raw_decode(page, match.end())[0]


# -- the particle store ---------------------------------------------------------------------------------


def _clouds(k=40, n=300, seed=1):
    rng = np.random.default_rng(seed)
    ref_x = 553000.0 + np.cumsum(rng.uniform(0.5, 0.8, k))
    ref_y = 4182750.0 + rng.normal(0, 0.2, k)
    x = ref_x[:, None] + rng.normal(0, 4, (k, n))
    y = ref_y[:, None] + rng.normal(0, 4, (k, n))
    theta = rng.normal(0, 0.3, (k, n))
    scale = rng.normal(1.0, 0.05, (k, n))
    return np.arange(k) * 0.55, x, y, ref_x, ref_y, theta, scale


def test_pack_round_trip_within_the_stated_rounding(tmp_path):
    t, x, y, ref_x, ref_y, theta, scale = _clouds()
    packed = pack_particles(t, x, y, ref_x, ref_y, UTM10N, theta_rad=theta, scale=scale)
    assert packed["dx_dm"].dtype == np.int16 and packed["scale_e4"].dtype == np.uint16
    clouds = read_particles(write_particles(packed, tmp_path / "particles.npz"))
    assert np.abs(clouds.x - x).max() <= 0.05 + 1e-9 and np.abs(clouds.y - y).max() <= 0.05 + 1e-9
    assert np.abs(clouds.theta_deg - np.degrees(theta)).max() <= 0.05 + 1e-9
    assert np.abs(clouds.scale - scale).max() <= 0.5e-4 + 1e-9
    assert clouds.weight is None and clouds.n_particles == 300 and clouds.crs == UTM10N
    np.testing.assert_array_equal(clouds.t, t)


def test_packed_store_is_a_third_of_the_float32_one(tmp_path):
    t, x, y, ref_x, ref_y, theta, scale = _clouds(k=200, n=500)
    origin = np.array([ref_x[0], ref_y[0]])
    snapshots = {
        "t": t, "x": (x - origin[0]).astype(np.float32), "y": (y - origin[1]).astype(np.float32),
        "theta": theta.astype(np.float32), "scale": np.ones_like(scale, np.float32), "origin": origin,
        "crs": np.array(UTM10N),
    }
    with open(tmp_path / "float32.npz", "wb") as fh:
        np.savez_compressed(fh, **snapshots)
    write_particles(pack_snapshots(snapshots, ref_x, ref_y), tmp_path / "packed.npz")
    assert (tmp_path / "packed.npz").stat().st_size < 0.4 * (tmp_path / "float32.npz").stat().st_size


def test_the_float32_snapshots_of_earlier_versions_still_read(tmp_path):
    t, x, y, ref_x, ref_y, theta, scale = _clouds()
    origin = np.array([553000.0, 4182750.0])
    legacy = {"t": t, "x": (x - origin[0]).astype(np.float32), "y": (y - origin[1]).astype(np.float32),
              "theta": theta.astype(np.float32), "scale": scale.astype(np.float32), "origin": origin,
              "crs": np.array(UTM10N)}
    with open(tmp_path / "particles.npz", "wb") as fh:
        np.savez_compressed(fh, **legacy)
    clouds = read_particles(tmp_path / "particles.npz")
    assert np.abs(clouds.x - x).max() < 0.06 and np.abs(clouds.y - y).max() < 0.06


def test_weights_are_kept_when_not_uniform_and_far_particles_clipped(caplog):
    t, x, y, ref_x, ref_y, _, _ = _clouds(k=3, n=4)
    x[0, 0] = ref_x[0] + 5000.0  # beyond the int16 decimetre range
    weight = np.array([[1, 2, 3, 4]] * 3, float)
    with caplog.at_level("WARNING"):
        clouds = unpack_particles(pack_particles(t, x, y, ref_x, ref_y, UTM10N, weight=weight))
    assert "1 particle x offset value(s) out of the stored range were clipped" in caplog.text
    assert clouds.x[0, 0] == pytest.approx(ref_x[0] + 3276.7)
    np.testing.assert_allclose(clouds.weight[0], weight[0] / weight[0].sum(), atol=0.01)


def test_other_files_are_refused_with_one_line(tmp_path):
    (tmp_path / "bad.npz").write_bytes(b"not a zip")
    with pytest.raises(CurbsideInputError, match="not a readable particle store"):
        read_particles(tmp_path / "bad.npz")
    with pytest.raises(CurbsideInputError, match=FORMAT):
        unpack_particles({"format": np.array("something/else")})


# -- the page -------------------------------------------------------------------------------------------


def test_page_holds_each_run_its_cloud_and_the_session(runs):
    views = label_runs([load_run(r) for r in runs])
    page = view_page(views)
    data = _page_data(page)
    assert [r["label"] for r in data["runs"]] == ["GNSS", "curbside fused"]  # the reports' METHOD_LABELS
    gnss, fused = data["runs"]
    assert gnss["cloud"] is None and fused["cloud"]["n"] == 100
    track = pd.read_csv(runs[1] / "track.csv")
    assert fused["t"] == pytest.approx(track["t"].round(3).tolist())
    assert fused["segment"] == track["sidewalk_segment_id"].tolist()
    # the cloud drawn at a footstep is the stored one, to the page's 1e-6 degree rounding
    clouds = read_particles(runs[1] / "particles.npz")
    k = len(clouds.t) // 2
    cloud = fused["cloud"]
    dlat = np.frombuffer(base64.b64decode(cloud["dlat"]), "<i2").reshape(-1, 100)
    lon, lat = LocalFrame(pyproj.CRS(clouds.crs)).to_lonlat(clouds.x[k], clouds.y[k])
    np.testing.assert_allclose(cloud["ref_lat"][k] + dlat[k] * PAGE_OFFSET_UNIT_DEG, lat, atol=1.5e-6)
    # errors against the ground truth: the walker is on y = START_XY[1] at constant speed
    assert max(e for e in fused["error_m"] if e is not None) < 15
    assert fused["waypoint_summary"].startswith("error at 2 waypoints: median")
    (session,) = data["sessions"]
    assert len(session["gnss"]["t"]) == len(pd.read_csv(runs[0].parent / "walk" / "gnss.csv"))
    assert len(session["truth"]["t"]) == 4
    assert "© OpenStreetMap contributors" in page and "sidewalk segment (" in page


def test_segments_are_named_by_street_and_compass_side(runs):
    fused = _page_data(view_page([load_run(runs[1])]))["runs"][0]
    places = sidewalk_places(read_map(CROSSROADS))
    visited = {s for s in fused["segment"] if s is not None}
    assert fused["segment_names"] == {s: places[s].label for s in visited}
    # the walker goes east along the north sidewalks of Market Street
    assert "Market Street, north side" in fused["segment_names"].values()
    # a run tracked on a map that cannot be read keeps its raw ids (and says why in the log)
    gone = ViewRun("x", pd.read_csv(runs[1] / "track.csv"), map_path=str(runs[1] / "gone.geojson"))
    assert _page_data(view_page([gone], maps={}))["runs"][0]["segment_names"] is None


def test_cli_writes_the_page_and_says_so(runs, tmp_path, capsys):
    out = tmp_path / "view.html"
    assert localize_main(["view", *map(str, runs), "-o", str(out), "--labels", "GNSS", "fused PF"]) == 0
    assert f"{out}: 2 run(s), 1 with particle clouds" in capsys.readouterr().out
    assert [r["label"] for r in _page_data(out.read_text(encoding="utf-8"))["runs"]] == ["GNSS", "fused PF"]


@pytest.mark.parametrize(
    ("make_args", "words"),
    [
        (lambda runs, tmp: ["view", str(tmp), "-o", str(tmp / "v.html")], "not a run folder"),
        (lambda runs, tmp: ["view", str(tmp / "gone"), "-o", str(tmp / "v.html")], "no such run folder"),
        (lambda runs, tmp: ["view", str(runs[0]), "-o", str(tmp / "v.png")], "name it .html"),
        (lambda runs, tmp: ["view", str(runs[0]), "--session", str(tmp / "gone"), "-o", str(tmp / "v.html")],
         "gone"),
        (lambda runs, tmp: ["view", *map(str, runs), "--labels", "one", "-o", str(tmp / "v.html")],
         "one label per run"),
    ],
)
def test_bad_input_is_one_line_and_exit_2(runs, tmp_path, capsys, make_args, words):
    assert localize_main(make_args(runs, tmp_path)) == 2
    err = capsys.readouterr().err
    assert err.startswith("localize: error: ") and words in err and err.count("\n") == 1
    assert not (tmp_path / "v.html").exists()


def test_a_moved_session_says_how_to_point_at_it(runs, tmp_path, capsys):
    moved = tmp_path / "moved"
    moved.mkdir()
    info = json.loads((runs[1] / "run.json").read_text())
    for name in ("track.csv", "particles.npz"):
        (moved / name).write_bytes((runs[1] / name).read_bytes())
    (moved / "run.json").write_text(json.dumps({**info, "session": str(tmp_path / "gone")}))
    assert localize_main(["view", str(moved), "-o", str(tmp_path / "v.html")]) == 2
    assert "pass --session if the session moved" in capsys.readouterr().err
    session = runs[1].parent / "walk"
    assert localize_main(["view", str(moved), "--session", str(session), "-o", str(tmp_path / "v.html")]) == 0


# -- the waypoint error ---------------------------------------------------------------------------------


def test_waypoint_error_interpolates_the_track_at_each_waypoint():
    # due east at 1 m/s from (lon0, lat0); waypoints 3 m north of the track, inside and outside its span
    frame = LocalFrame.around(-122.4, 37.79)
    x0, y0 = frame.to_xy(-122.4, 37.79)
    t = np.arange(0.0, 21.0)
    lon, lat = frame.to_lonlat(x0 + t, np.full_like(t, y0))
    track = pd.DataFrame({"t": t, "lat": lat, "lon": lon})
    wt = np.array([0.0, 5.5, 10.25, 30.0])
    wlon, wlat = frame.to_lonlat(x0 + wt, y0 + np.array([0.0, 3.0, 4.0, 3.0]))
    errors = waypoint_errors(track, pd.DataFrame({"t": wt, "lat": wlat, "lon": wlon}))
    assert errors["t"].tolist() == [5.5, 10.25]  # the first left out, the last outside the track
    np.testing.assert_allclose(errors["error_m"], [3.0, 4.0], atol=0.01)
    summary = waypoint_summary(errors)
    assert summary["n_waypoints"] == 2 and summary["waypoint_max_m"] == pytest.approx(4.0, abs=0.01)
    assert format_waypoint_summary(summary) == "error at 2 waypoints: median 3.5 m, p90 3.9 m, max 4.0 m"
    assert np.isnan(summary["waypoint_accuracy_held"])  # the track claims no radius
    assert waypoint_summary(errors.iloc[:0])["n_waypoints"] == 0
    # a 68 % radius interpolated like the position: 3.95 m at the first waypoint (3 m off: held) and
    # 3.475 m at the second (4 m off: not held)
    waypoints = pd.DataFrame({"t": wt, "lat": wlat, "lon": wlon})
    claimed = waypoint_errors(track.assign(accuracy_m=4.5 - 0.1 * t), waypoints)
    np.testing.assert_allclose(claimed["accuracy_m"], [3.95, 3.475])
    held = waypoint_summary(claimed)
    assert held["waypoint_accuracy_held"] == 0.5
    assert format_waypoint_summary(held).endswith("max 4.0 m; accuracy_m held 1 of 2")
    with pytest.raises(CurbsideInputError, match="at least two"):
        waypoint_errors(track, pd.DataFrame({"t": [1.0], "lat": [37.79], "lon": [-122.4]}))


# -- the pages of an evaluation report ------------------------------------------------------------------


def test_the_evaluation_report_links_each_session_to_its_replay(runs, tmp_path):
    from curbside.evaluate.report import write_report
    from curbside.evaluate.runner import RunSpec, run_one
    from curbside.osmseg.mapio import read_map

    hand = tmp_path / "hand.geojson"
    hand.write_bytes(CROSSROADS.read_bytes())
    session = str(runs[0].parent / "walk")
    maps = {"osm": str(CROSSROADS), "hand": str(hand)}
    specs = [RunSpec(session, "gnss", None, "osm", str(CROSSROADS), particles=100)]
    specs += [RunSpec(session, "fused", p, name, str(CROSSROADS), particles=100) for name, p in maps.items()]
    results = [run_one(spec) for spec in specs]
    base = {"map": "osm", "jaywalk_weight": specs[1].jaywalk_weight, "particles": 100,
            "gnss_sigma_factor": None}
    write_report(results, tmp_path / "report", base, read_map(CROSSROADS))
    assert "- [walk](view/walk.html)" in (tmp_path / "report" / "report.md").read_text()
    assert "<a href='view/walk.html'>walk</a>" in (tmp_path / "report" / "report.html").read_text()
    data = _page_data((tmp_path / "report" / "view" / "walk.html").read_text(encoding="utf-8"))
    labels = ["GNSS", "curbside fused · crossroads", "curbside fused · hand"]  # the reports' METHOD_LABELS
    assert [r["label"] for r in data["runs"]] == labels
    # the track drawn is the one scored, back in lon/lat
    gnss, fused = data["runs"][:2]
    scored = results[1]["track"]
    frame = LocalFrame(read_map(CROSSROADS).crs)
    lon, lat = frame.to_lonlat(scored["x_m"].to_numpy(), scored["y_m"].to_numpy())
    np.testing.assert_allclose(fused["lat"], lat, atol=1e-7)
    # the panel's columns the results hold: the 68 % radius, the MAP segment with its probability
    errors, mode = results[1]["errors"], results[1]["errors_mode"]
    assert fused["accuracy_m"] == pytest.approx(errors["accuracy_m"].round(1).tolist())
    assert fused["segment_prob"] == pytest.approx(mode["segment_prob"].round(3).tolist())
    assert fused["segment"] == mode["est_segment"].tolist()
    assert "Market Street, north side" in fused["segment_names"].values()
    assert gnss["accuracy_m"] == pytest.approx(results[0]["errors"]["accuracy_m"].round(1).tolist())
    assert gnss["segment_prob"] is None and gnss["segment"] == results[0]["errors"]["est_segment"].tolist()
    assert fused["n_eff"] is None  # run_one does not keep it (see test_result_columns_are_carried_when_held)


def test_result_columns_are_carried_when_held():
    frame = LocalFrame(pyproj.CRS(UTM10N))
    t = np.arange(3.0)
    scored = pd.DataFrame({"t": t, "x_m": 553000.0 + t, "y_m": np.full(3, 4182750.0)})
    errors = pd.DataFrame(
        {"est_segment": ["a", "a", "b"], "accuracy_m": [2.0, 3.0, 4.0], "n_eff": [90, 80, 70]}
    )
    mode = pd.DataFrame({"est_segment": ["a", "b", "b"], "segment_prob": [0.9, 0.6, 0.8]})
    track = _result_track({"track": scored, "errors": errors, "errors_mode": mode}, frame)
    assert track["sidewalk_segment_id"].tolist() == ["a", "b", "b"]  # the segment its probability is of
    assert track["segment_prob"].tolist() == [0.9, 0.6, 0.8]
    assert track["accuracy_m"].tolist() == [2.0, 3.0, 4.0] and track["n_eff"].tolist() == [90, 80, 70]
    bare = _result_track({"track": scored, "errors": errors[["est_segment"]], "errors_mode": None}, frame)
    assert list(bare.columns) == ["t", "lat", "lon", "sidewalk_segment_id"]
    assert bare["sidewalk_segment_id"].tolist() == ["a", "a", "b"]


def test_cloud_every_keeps_fewer_clouds(runs, tmp_path):
    out = tmp_path / "view.html"
    assert localize_main(["view", *map(str, runs), "--cloud-every", "5", "-o", str(out)]) == 0
    cloud = _page_data(out.read_text(encoding="utf-8"))["runs"][1]["cloud"]
    every = read_particles(runs[1] / "particles.npz")
    assert cloud["t"] == pytest.approx(np.round(every.t[::5], 3).tolist())
    assert len(base64.b64decode(cloud["dlat"])) == 2 * 100 * len(every.t[::5])


def test_large_clouds_are_drawn_thinned_with_their_weights():
    rng = np.random.default_rng(0)
    x = 550_000.0 + rng.normal(0, 5, (3, 2000))
    y = 4_180_000.0 + rng.normal(0, 5, (3, 2000))
    weight = rng.random((3, 2000))
    weight /= weight.sum(axis=1, keepdims=True)
    weight[:, 4] = 1.0  # the 5th particle (kept: every 4th from the first) is each cloud's heaviest
    clouds = ParticleClouds(np.arange(3.0), x, y, None, None, weight, pyproj.CRS(UTM10N).to_wkt())
    page = _cloud_data(clouds, every=2)
    assert (page["n"], page["n_total"], len(page["t"])) == (MAX_DRAWN_PARTICLES, 2000, 2)
    dlat = np.frombuffer(base64.b64decode(page["dlat"]), "<i2")
    alpha = np.frombuffer(base64.b64decode(page["alpha"]), "u1").reshape(2, MAX_DRAWN_PARTICLES)
    assert len(dlat) == 2 * MAX_DRAWN_PARTICLES and (alpha[:, 1] == 255).all()
    small = ParticleClouds(np.arange(3.0), x[:, :300], y[:, :300], None, None, None, clouds.crs)
    assert _cloud_data(small)["n"] == 300  # at most MAX_DRAWN_PARTICLES: every particle is drawn


def test_every_maps_credit_is_on_the_page(runs):
    """A DataSF map first and an OSM map second: the OSM credit must not be dropped (ODbL)."""
    osm = read_map(CROSSROADS)
    datasf = read_map(CROSSROADS)
    datasf.meta = {**datasf.meta, "attribution": "City and County of San Francisco (DataSF)"}
    page = view_page([load_run(runs[1])], maps={"datasf.geojson": datasf, "osm.geojson": osm})
    assert "DataSF" in page and "© OpenStreetMap contributors" in page
