"""The simulator: routes on real SF sidewalks, the urban-canyon GNSS model, sensors, determinism."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
import shapely

from curbside.evaluate import gnss_model, routes
from curbside.evaluate import simulate as sim
from curbside.evaluate.groundtruth import groundtruth_at
from curbside.evaluate.inertial_model import inertial_errors
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
    errors = inertial_errors(walk, sim.VelocityErrorModel(), rng, rng)
    imu = sim.simulate_imu(walk, sim.ImuModel(), errors, rng)
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


# -- the phone profile: each error component shows its magnitude ------------------------------------------


def _straight_route(length_m: float = 1500.0, kinds: tuple[str, ...] = ("sidewalk",)) -> routes.Route:
    """A synthetic route east along y = 0, split into equal legs of the given kinds."""
    xs = np.linspace(0.0, length_m, len(kinds) + 1)
    spec = routes.RouteSpec("synthetic", (0.0, 0.0), length_m, 0, 0, "test")
    return routes.Route(spec, np.column_stack([xs, np.zeros_like(xs)]), np.asarray(kinds), 0, 0, 0.0, 0)


def _quiet(**fields) -> sim.VelocityErrorModel:
    """A velocity model with every error off except ``fields``."""
    off = dict(
        heading_bias_deg=0.0, heading_drift_deg_per_min=0.0, heading_walk_deg_per_sqrt_min=0.0,
        scale_sd=0.0, scale_wander_sd=0.0, noise_mps=0.0,
    )
    return sim.VelocityErrorModel(**{**off, **fields})


def _velocity(route, model, seed=0, walker=None):
    rng = np.random.default_rng(seed)
    walk = sim.simulate_walk(route, walker or sim.WalkerModel(wander_m=0.0), rng, stop_rng=rng)
    errors = inertial_errors(walk, model, rng, np.random.default_rng(seed + 1))
    return walk, errors, sim.simulate_velocity(walk, model, errors, rng)


def _heading_error_deg(velocity: pd.DataFrame) -> np.ndarray:
    """Compass heading of the velocity minus the true heading (due east, 90 deg), unwrapped."""
    return np.degrees(np.unwrap(np.arctan2(velocity["ve"], velocity["vn"]))) - 90.0


def test_phone_bias_is_the_recorded_constant_heading_error():
    _, errors, velocity = _velocity(_straight_route(), _quiet(heading_bias_deg=10.0))
    bias = errors.events["heading_bias_deg"]
    assert abs(bias) > 0.5
    inner = slice(20, -20)  # away from the walk's start and end, where the 1 s window sees a stop
    np.testing.assert_allclose(_heading_error_deg(velocity)[inner], bias, atol=0.05)


def test_phone_jumps_happen_at_the_recorded_times_with_the_recorded_sizes():
    model = _quiet(heading_jump_rate_per_min=1.0, heading_jump_deg=(20.0, 40.0))
    _, errors, velocity = _velocity(_straight_route(3000.0), model, seed=3)
    jumps = errors.events["heading_jumps"]
    assert len(jumps) >= 2
    err = _heading_error_deg(velocity)
    t = velocity["t"].to_numpy()
    times = np.array([j["t_s"] for j in jumps])
    checked = 0
    for jump in jumps:
        alone = np.sum(np.abs(times - jump["t_s"]) < 4) == 1
        if not (alone and 3 < jump["t_s"] < t[-1] - 3):
            continue
        checked += 1
        before = err[(t > jump["t_s"] - 3) & (t < jump["t_s"] - 1)].mean()
        after = err[(t > jump["t_s"] + 1) & (t < jump["t_s"] + 3)].mean()
        assert 20 <= abs(jump["deg"]) <= 40
        assert after - before == pytest.approx(jump["deg"], abs=0.1)
    assert checked >= 2


def test_phone_heading_random_walk_grows_at_its_rate():
    # the variogram of the realised heading error: E[(h(t + tau) - h(t))^2] = q^2 tau (tau in minutes)
    model = _quiet(heading_walk_deg_per_sqrt_min=5.0)
    route = _straight_route(1200.0)
    rng = np.random.default_rng(0)
    walk = sim.simulate_walk(route, sim.WalkerModel(wander_m=0.0), rng)
    lag = 600  # samples at 10 Hz: one minute
    sq = []
    for seed in range(40):
        errors = inertial_errors(walk, model, np.random.default_rng(seed), np.random.default_rng(seed))
        h = errors.heading_deg
        sq.append((h[lag:] - h[:-lag]) ** 2)
    assert np.sqrt(np.mean(np.concatenate(sq))) == pytest.approx(5.0, rel=0.15)


def test_phone_drift_is_linear_at_the_recorded_rate():
    _, errors, velocity = _velocity(_straight_route(2000.0), _quiet(heading_drift_deg_per_min=3.0), seed=5)
    rate = errors.events["heading_drift_deg_per_min"]
    t = velocity["t"].to_numpy()
    inner = (t > 5) & (t < t[-1] - 5)
    slope = np.polyfit(t[inner] / 60.0, _heading_error_deg(velocity)[inner], 1)[0]
    assert abs(rate) > 0.3 and slope == pytest.approx(rate, abs=0.02)


def test_phone_speed_scale_and_step_noise():
    route = _straight_route(1500.0)
    _, errors, velocity = _velocity(route, _quiet(scale_sd=0.12), seed=2)
    dist = np.sum(np.hypot(velocity["ve"], velocity["vn"]).to_numpy()[1:] * np.diff(velocity["t"]))
    assert dist / route.length_m == pytest.approx(errors.events["speed_scale"], abs=0.01)
    walk, _, noisy = _velocity(route, _quiet(speed_noise_cv=0.15), seed=2)
    speed = np.hypot(noisy["ve"], noisy["vn"]).to_numpy()[20:-20]
    assert np.std(speed / walk.speed_mps) == pytest.approx(0.15, rel=0.25)


def test_stops_give_exact_ground_truth_no_footsteps_and_phantom_motion(tmp_path):
    route = _straight_route(300.0, ("sidewalk", "crossing", "sidewalk"))
    walker = sim.WalkerModel(wander_m=0.0, crosswalk_stop_prob=1.0, crosswalk_wait_s=(20.0, 20.0))
    model = _quiet(phantom_mps=0.25)
    walk, errors, velocity = _velocity(route, model, seed=1, walker=walker)
    (stop,) = walk.stops
    assert stop.kind == "crossing" and stop.wait_s == pytest.approx(20.0)
    # two taps at the kerb, on arrival and departure; the ground truth holds still between them
    taps = pd.DataFrame({"t": walk.waypoint_t, "x": walk.waypoint_xy[:, 0], "y": walk.waypoint_xy[:, 1]})
    assert len(taps) == len(route.xy) + 1
    kerb = taps[np.isclose(taps["x"], 100.0)]
    assert kerb["t"].diff().iat[1] == pytest.approx(20.0)
    standing = walk.standing(walk.t)
    np.testing.assert_allclose(walk.xy[standing], [[100.0, 0.0]] * standing.sum(), atol=1e-9)
    gt_x = np.interp(walk.t, taps["t"], taps["x"])
    assert np.abs(gt_x - walk.xy[:, 0]).max() < 0.05
    # no footsteps while standing; the walking clock is unchanged by the stop
    steps = walk.step_t
    assert not ((steps > stop.t_s) & (steps < stop.t_s + stop.wait_s)).any()
    plain = sim.simulate_walk(route, sim.WalkerModel(wander_m=0.0), np.random.default_rng(1))
    assert len(steps) == len(plain.step_t)
    # phantom motion while standing, at its RMS speed; none while walking (no other noise here)
    v = velocity[["ve", "vn"]].to_numpy()
    still = walk.standing(velocity["t"].to_numpy())
    assert np.sqrt(np.mean(np.sum(v[still] ** 2, axis=1))) == pytest.approx(0.25, rel=0.5)
    _, _, without = _velocity(route, _quiet(), seed=1, walker=walker)
    np.testing.assert_array_equal(v[~still], without[["ve", "vn"]].to_numpy()[~still])
    tv = velocity["t"].to_numpy()
    inner = walk.standing(tv - 0.6) & walk.standing(tv + 0.6)  # RoNIN's 1 s window ramps at the edges
    assert inner.sum() > 150 and np.abs(without[["ve", "vn"]].to_numpy()[inner]).max() < 1e-9


def test_phone_session_records_its_events_and_nominal_is_unchanged(sf):
    route_list, frame, osm = sf
    phone = sim.simulate_session(route_list[0], osm, frame, 4, sim.SimulationConfig(profile="phone"))
    again = sim.simulate_session(route_list[0], osm, frame, 4, sim.SimulationConfig(profile="phone"))
    pd.testing.assert_frame_equal(phone.velocity, again.velocity)
    simulation = phone.meta["simulation"]
    assert simulation["profile"] == "phone"
    events = simulation["events"]
    expected = {"heading_bias_deg", "heading_drift_deg_per_min", "heading_jumps", "speed_scale", "stops"}
    assert expected <= set(events)
    for stop in events["stops"]:  # each stop is a pair of taps at one place
        wp = phone.waypoints
        at = wp[(wp["t"] - stop["t_s"]).abs() < 0.01].index[0]
        assert wp["t"].iat[at + 1] - wp["t"].iat[at] == pytest.approx(stop["wait_s"], abs=0.01)
        assert (wp["lat"].iat[at], wp["lon"].iat[at]) == (wp["lat"].iat[at + 1], wp["lon"].iat[at + 1])
    nominal = sim.simulate_session(route_list[0], osm, frame, 4)
    nominal_models = sim.SimulationConfig(walker=sim.WalkerModel(), velocity=sim.VelocityErrorModel())
    explicit = sim.simulate_session(route_list[0], osm, frame, 4, nominal_models)
    pd.testing.assert_frame_equal(nominal.velocity, explicit.velocity)
    assert nominal.meta["simulation"]["events"]["stops"] == []


def test_unknown_profile_is_refused():
    from curbside.errors import CurbsideInputError

    with pytest.raises(CurbsideInputError, match="unknown profile"):
        sim.SimulationConfig(profile="pocket")


def test_a_route_that_cannot_be_drawn_says_what_it_must_satisfy(sf):
    from curbside.errors import CurbsideInputError
    from curbside.evaluate import routes

    route_list, frame, osm = sf
    spec = routes.RouteSpec("custom", route_list[0].spec.start_lonlat, 6000.0, 0, 0, "custom")
    with pytest.raises(CurbsideInputError) as info:
        routes.generate_route(routes.build_walk_graph(osm), spec, frame, seed=1, max_attempts=50)
    assert "no route found in 50 random walks" in info.value.problem
    problem = info.value.problem
    assert "within 320 m of its start" in problem and "exactly 0 crosswalk(s)" in problem
