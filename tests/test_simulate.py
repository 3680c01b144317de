"""The simulator: routes on real SF sidewalks, the urban-canyon GNSS model, sensors, determinism."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
import shapely

from curbside.evaluate import gnss_model, routes
from curbside.evaluate import simulate as sim
from curbside.evaluate.groundtruth import groundtruth_at
from curbside.evaluate.osmsource import load_osm, parse_height_m
from curbside.localize.session import read_session, write_session


@pytest.fixture(scope="module")
def sf():
    """The bundled OSM extract's routes (cached on disk after the first read)."""
    route_list, frame, osm = sim.sf6_routes()
    return route_list, frame, osm


def test_parse_height_units_and_levels():
    heights = parse_height_m(
        pd.Series(["93 m", "300 ft", "40'", None, "tall", "12.5"]),
        pd.Series([None, None, None, "4", None, "99"]),
    )
    np.testing.assert_allclose(heights[:3], [93.0, 91.44, 12.192])
    assert heights[3] == 4 * 3.5
    assert heights[4] == 10.0  # the default height
    assert heights[5] == 12.5  # height wins over levels


def test_sf6_routes_match_table1(sf):
    route_list, _, _ = sf
    expected = {s.name: s for s in routes.SF6}
    for r in route_list:
        spec = expected[r.spec.name]
        assert r.length_m == pytest.approx(spec.length_m, abs=0.5)
        assert (r.crossings, r.jaywalks) == (spec.crossings, spec.jaywalks)
        assert routes._runs(r.kinds, "crossing") == spec.crossings
        assert r.covered_share >= spec.covered_share


def test_routes_avoid_buildings(sf):
    route_list, _, osm = sf
    buildings = shapely.union_all(osm.buildings[osm.buildings["height_m"] < 15].geometry.values)
    for r in route_list:
        pts = np.vstack([np.linspace(r.xy[i], r.xy[i + 1], 10) for i in range(len(r.xy) - 1)])
        inside = shapely.contains_xy(buildings, pts[:, 0], pts[:, 1])
        assert inside.mean() < 0.02, r.spec.name


def test_same_seed_same_session_and_different_seed_differs(sf):
    route_list, frame, osm = sf
    a = sim.simulate_session(route_list[2], osm, frame, 5)
    b = sim.simulate_session(route_list[2], osm, frame, 5)
    c = sim.simulate_session(route_list[2], osm, frame, 6)
    for kind in ("gnss", "velocity", "steps", "waypoints"):
        pd.testing.assert_frame_equal(getattr(a, kind), getattr(b, kind))
    assert np.abs(a.gnss["lat"].to_numpy()[:50] - c.gnss["lat"].to_numpy()[:50]).max() > 1e-6


def test_session_round_trips_and_velocity_integrates_to_the_route(sf, tmp_path):
    route_list, frame, osm = sf
    session = sim.simulate_session(route_list[2], osm, frame, 3)
    back = read_session(write_session(session, tmp_path / "s"))
    assert back.start_pose is not None and back.meta["simulation"]["route"] == "path3"
    v = back.velocity
    dist = np.sum(np.hypot(v["ve"], v["vn"]).to_numpy()[1:] * np.diff(v["t"].to_numpy()))
    assert dist == pytest.approx(route_list[2].length_m, rel=0.15)
    # footsteps at the cadence, ground truth at each footstep on the route
    steps = back.steps["t"].to_numpy()
    assert 1.5 < len(steps) / steps[-1] < 2.2
    gx, gy = groundtruth_at(back.waypoints, steps, frame)
    line = shapely.linestrings(route_list[2].xy)
    assert shapely.distance(line, shapely.points(np.column_stack([gx, gy]))).max() < 0.05


def test_gnss_errors_larger_across_than_along_in_a_canyon():
    osm = load_osm()
    # a straight walk along the middle of a canyon: walls 10 m either side, 60 m tall
    walls = [shapely.box(-200, 10, 200, 30), shapely.box(-200, -30, 200, -10)]
    canyon = sim.OsmSource(
        osm.buildings.iloc[:0]._constructor(
            {"height_m": [60.0, 60.0], "osm_id": ["a", "b"]}, geometry=walls, crs=osm.crs
        ),
        osm.footways.iloc[:0],
        osm.roads.iloc[:0],
    )
    t = np.arange(0.0, 3000.0)
    xy = np.column_stack([np.linspace(-100, 100, len(t)), np.zeros(len(t))])
    model = gnss_model.GnssErrorModel(wrong_side_rate_per_s=0.0, outlier_rate_per_s=0.0)
    fixes = gnss_model.simulate_gnss(t, xy, canyon, model, np.random.default_rng(0))
    ex = fixes["x_m"] - fixes["true_x_m"]
    ey = fixes["y_m"] - fixes["true_y_m"]
    assert ey.std() > 1.5 * ex.std()  # across (north-south) > along (east-west)
    # Gauss-Markov: neighbouring fixes are strongly correlated
    assert np.corrcoef(ey[:-1], ey[1:])[0, 1] > 0.9
    mask = gnss_model.sky_mask(xy[:1], canyon, model)
    north = int(np.argmax(mask.azimuth[:, 1]))
    assert mask.elevation_deg[0, north] == pytest.approx(np.degrees(np.arctan2(60, 10)), abs=0.5)
    assert mask.wall_m[0, north] == pytest.approx(10.0, abs=0.1)


def test_gnss_drops_fixes_under_cover():
    osm = load_osm()
    deck = sim.OsmSource(
        osm.buildings.iloc[:0]._constructor(
            {"height_m": [30.0], "osm_id": ["deck"]}, geometry=[shapely.box(-50, -50, 50, 50)], crs=osm.crs
        ),
        osm.footways.iloc[:0],
        osm.roads.iloc[:0],
    )
    t = np.arange(0.0, 400.0)
    xy = np.zeros((len(t), 2))
    fixes = gnss_model.simulate_gnss(t, xy, deck, gnss_model.GnssErrorModel(), np.random.default_rng(1))
    assert fixes["covered"].all()
    assert 0.25 < len(fixes) / len(t) < 0.55  # dropout probability 0.6


def test_imu_has_gravity_gait_and_consistent_orientation(sf):
    route_list, frame, osm = sf
    rng = np.random.default_rng(0)
    walk = sim.simulate_walk(route_list[5], sim.WalkerModel(), rng)
    imu = sim.simulate_imu(walk, sim.ImuModel(), sim.VelocityErrorModel(), rng)
    from scipy.spatial.transform import Rotation

    acc = np.array(imu[["ax", "ay", "az"]], dtype=float)
    world = Rotation.from_quat(np.array(imu[["qx", "qy", "qz", "qw"]], dtype=float)).apply(acc)
    assert world[:, 2].mean() == pytest.approx(sim.GRAVITY, abs=0.1)
    # the vertical bounce oscillates at the step frequency
    z = world[:, 2] - world[:, 2].mean()
    spectrum = np.abs(np.fft.rfft(z))
    freqs = np.fft.rfftfreq(len(z), 1 / sim.ImuModel().rate_hz)
    assert freqs[np.argmax(spectrum[1:]) + 1] == pytest.approx(walk.cadence_hz, abs=0.05)


def test_writing_imu_leaves_the_other_files_unchanged(sf):
    route_list, frame, osm = sf
    plain = sim.simulate_session(route_list[5], osm, frame, 2)
    with_imu = sim.simulate_session(route_list[5], osm, frame, 2, sim.SimulationConfig(write_imu=True))
    assert plain.imu is None and with_imu.imu is not None
    for kind in ("gnss", "velocity", "steps", "waypoints"):
        pd.testing.assert_frame_equal(getattr(plain, kind), getattr(with_imu, kind))
