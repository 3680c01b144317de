"""The streaming engine: the same track however the rows arrive, time-grid updates, fix association."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest
from hypothesis import HealthCheck, given
from hypothesis import settings as hsettings
from hypothesis import strategies as st
from test_run import block_layers, write_walk

from curbside import settings
from curbside.localize.engine import SessionEngine, StartPose
from curbside.localize.filter.parts import GnssFix
from curbside.localize.pipeline import _frame_for, _start_of, track_session
from curbside.localize.raster import rasterize_map
from curbside.localize.runconfig import EngineConfig, RunConfig
from curbside.localize.session import read_session
from curbside.localize.streams import DisplacementIntegrator, FixStore


@pytest.fixture(scope="module")
def walk(tmp_path_factory):
    return read_session(write_walk(tmp_path_factory.mktemp("engine") / "walk", duration_s=30.0))


@pytest.fixture(scope="module")
def raster():
    return rasterize_map(block_layers(), 0.5)


def _engine(session, raster, config: RunConfig) -> SessionEngine:
    start, t_begin = _start_of(session)
    return SessionEngine(config, _frame_for(session, block_layers()), raster, start=start, t_begin=t_begin)


def _stream(session, raster, config: RunConfig, cuts: list[float]) -> pd.DataFrame:
    """Push the session's rows in time windows ending at ``cuts``, advancing after each; then finish."""
    engine = _engine(session, raster, config)
    v, s, g = session.velocity, session.steps, session.gnss
    lo = -math.inf
    for hi in [*sorted(cuts), math.inf]:
        vv, ss, gg = (tab[(tab["t"] > lo) & (tab["t"] <= hi)] for tab in (v, s, g))
        engine.push_velocity(vv["t"].to_numpy(), vv[["ve", "vn"]].to_numpy())
        engine.push_steps(ss["t"].to_numpy(), min(hi, float(s["t"].iat[-1])))
        engine.push_gnss(gg)
        engine.advance()
        lo = hi
    engine.finish()
    return pd.DataFrame(
        [(r.t, r.x, r.y, r.kind, r.n_eff) for r in engine.rows], columns=["t", "x", "y", "kind", "n"]
    )


@hsettings(max_examples=8, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(cuts=st.lists(st.floats(0.0, 30.0), max_size=25))
def test_any_chunking_gives_the_batch_track(walk, raster, cuts):
    config = RunConfig.for_mode("fused", seed=3)
    batch = _stream(walk, raster, config, [])
    streamed = _stream(walk, raster, config, cuts)
    pd.testing.assert_frame_equal(batch, streamed)


def test_streaming_returns_estimates_before_the_end(walk, raster):
    engine = _engine(walk, raster, RunConfig.for_mode("fused"))
    v, s, g = walk.velocity, walk.steps, walk.gnss
    first = v["t"] <= 10.0
    engine.push_velocity(v["t"][first].to_numpy(), v[["ve", "vn"]][first].to_numpy())
    engine.push_steps(s["t"][s["t"] <= 10.0].to_numpy(), 10.0)
    engine.push_gnss(g[g["t"] <= 10.0])
    rows = engine.advance()
    # every update up to 10 s minus the 2 s the fix interpolation looks ahead
    assert rows and 7.0 < rows[-1].t <= 8.0


def test_without_footsteps_the_filter_advances_on_the_time_grid(tmp_path):
    folder = write_walk(tmp_path / "walk", duration_s=20.0)
    steps = pd.read_csv(folder / "steps.csv")
    steps[(steps["t"] < 5.0) | (steps["t"] > 12.0)].to_csv(folder / "steps.csv", index=False)  # 7 s missed
    track = track_session(read_session(folder), block_layers(), "fused", seed=0).track
    gap = track[(track["t"] > 5.0) & (track["t"] < 12.0)]
    assert (gap["update"] == "time").all() and len(gap) == 7
    assert np.diff(track["t"]).max() <= 1.0 + 1e-9
    assert track["t"].iat[-1] > 19.0  # the whole walk is tracked
    # the inertial velocity still moves the estimate through the gap, at walking pace
    speed = np.hypot(np.diff(gap["x_m"]), np.diff(gap["y_m"])) / np.diff(gap["t"])
    assert 0.8 < np.median(speed) < 1.8


def test_standing_rule_stops_phantom_motion_but_not_a_walk_with_missed_steps(tmp_path):
    folder = write_walk(tmp_path / "walk", duration_s=20.0)
    steps = pd.read_csv(folder / "steps.csv")
    steps[(steps["t"] < 5.0) | (steps["t"] > 12.0)].to_csv(folder / "steps.csv", index=False)
    walking = read_session(folder)
    velocity = walking.velocity.copy()
    still = (velocity["t"] > 5.0) & (velocity["t"] < 12.0)
    velocity.loc[still, ["ve", "vn"]] = [0.25, -0.15]  # a handled phone's drift while standing
    standing = read_session(folder)
    standing.velocity = velocity

    def gap_speed(session, standing_speed_mps):
        config = RunConfig.for_mode("inertial", seed=0).with_overrides(
            {"engine.standing_speed_mps": standing_speed_mps})
        track = track_session(session, block_layers(), config=config).track
        gap = track[(track["t"] > 5.5) & (track["t"] < 12.0)]
        assert (gap["update"] == "time").all()
        return np.median(np.hypot(np.diff(gap["x_m"]), np.diff(gap["y_m"])) / np.diff(gap["t"]))

    assert 0.2 < gap_speed(standing, 0.0) < 0.4  # off: the drift moves the walker
    assert gap_speed(standing, 0.6) < 0.05  # on: no footsteps and slow, so standing
    assert 0.8 < gap_speed(walking, 0.6) < 1.8  # missed footsteps at walking pace still move
    with pytest.raises(ValueError, match="standing_speed_mps must be non-negative"):
        EngineConfig(standing_speed_mps=-1.0)


def test_fix_store_interpolates_holds_expires_and_applies_each_fix_once():
    store = FixStore("interpolate", interp_max_gap_s=2.0, max_fix_age_s=3.0)
    tf = np.array([0.0, 1.0, 2.0, 10.0])
    store.push(tf, tf * 10.0, np.zeros(4), np.array([4.0, 6.0, 8.0, 8.0]))
    assert store.at(0.5) == GnssFix(5.0, 0.0, 5.0)  # interpolated
    assert store.at(2.5) == GnssFix(20.0, 0.0, 8.0)  # held: the next fix is 7.5 s away
    assert store.at(6.0) is None  # 4 s stale
    assert store.at(6.0, hold_forever=True) == GnssFix(20.0, 0.0, 8.0)
    assert store.at(-1.0) is None
    once = FixStore("once", 2.0, 3.0)
    tf = np.array([0.2, 1.2, 2.2, 2.4])
    once.push(tf, tf * 10.0, np.zeros(4), np.full(4, 5.0))
    used = [(t, once.at(t)) for t in np.arange(0.0, 6.01, 0.5)]
    got = [(t, f.x) for t, f in used if f is not None]
    assert got == [(0.5, 2.0), (1.5, 12.0), (2.5, 24.0)]  # two fixes in one step: the newer one


def test_invalid_fixes_are_dropped():
    store = FixStore("interpolate", 2.0, 3.0)
    store.push(np.array([0.0, 1.0, 2.0]), np.zeros(3), np.zeros(3), np.array([-1.0, np.nan, 5.0]))
    assert len(store.fixes.rows()) == 1


def test_displacement_integrates_velocity_in_any_chunks_and_skips_gaps():
    t = np.array([0.0, 1.0, 2.0, 5.0, 6.0])
    v = np.column_stack([np.ones(5), [0.0, 0.0, 0.0, 0.0, 2.0]])
    whole, parts = DisplacementIntegrator(1.0), DisplacementIntegrator(1.0)
    whole.push(t, v)
    parts.push(t[:2], v[:2])
    parts.push(t[2:3], v[2:3])
    parts.push(t[3:], v[3:])
    for integ in (whole, parts):
        np.testing.assert_allclose(
            [integ.at(x) for x in (0.0, 2.0, 5.0, 6.0)], [[0, 0], [2.0, 0], [2.0, 0], [3.0, 1.0]]
        )
    pdr = DisplacementIntegrator(1.0, step_means=True)
    pdr.push(np.array([0.0, 1.0, 3.0]), np.array([[0.0, 0.0], [2.0, 0.0], [1.0, 0.0]]))
    np.testing.assert_allclose(pdr.at(3.0), [4.0, 0.0])


@pytest.mark.parametrize(
    "heading, first, expected",
    [(0.0, (1.0, 0.0), math.pi / 2), (90.0, (1.0, 0.0), 0.0), (270.0, (0.0, 1.0), math.pi / 2)],
)
def test_heading_offset_turns_the_first_motion_onto_the_start_heading(raster, heading, first, expected):
    engine = SessionEngine(
        RunConfig(),
        _frame_for(read_session_stub(), block_layers()),
        raster,
        start=StartPose(0.0, 0.0, heading, 0.0),
        t_begin=0.0,
    )
    t = np.arange(0.0, 10.0, 0.1)
    engine.push_velocity(t, np.tile(first, (len(t), 1)))
    assert engine._heading_offset(0.0, heading) == pytest.approx(expected)


def read_session_stub():
    from curbside.localize.session import Session

    return Session(meta={"start": {"lat": 37.78, "lon": -122.4, "heading_deg": 0.0}})


def test_run_json_replays_the_same_track_byte_for_byte(tmp_path, monkeypatch):
    from curbside.cli.localize import main
    from curbside.osmseg.mapio import write_map

    monkeypatch.setattr(settings, "cache_dir", tmp_path / "cache")
    folder = write_walk(tmp_path / "walk", duration_s=20.0)
    map_file = write_map(block_layers(), tmp_path / "block.geojson")
    assert (
        main(
            [
                "run",
                str(folder),
                "--map",
                str(map_file),
                "--seed",
                "5",
                "--particles",
                "300",
                "--set",
                "filter.gnss.sigma_factor=1.2",
                "--set",
                "engine.fix_association=once",
                "-o",
                str(tmp_path / "a"),
            ]
        )
        == 0
    )
    assert main(["run", "--config", str(tmp_path / "a" / "run.json"), "-o", str(tmp_path / "b")]) == 0
    assert (tmp_path / "a" / "track.csv").read_bytes() == (tmp_path / "b" / "track.csv").read_bytes()
    replayed = RunConfig.from_dict(
        __import__("json").loads((tmp_path / "b" / "run.json").read_text())["config"]
    )
    assert replayed.filter.gnss.sigma_factor == 1.2 and replayed.engine == EngineConfig(
        fix_association="once", velocity_source="file"  # the replay keeps the source the run resolved
    )
    assert replayed.filter.n_particles == 300 and replayed.seed == 5


def test_unseen_velocity_flag_applies_its_preset_and_set_wins(tmp_path, monkeypatch):
    import json

    from curbside.cli.localize import main

    monkeypatch.setattr(settings, "cache_dir", tmp_path / "cache")
    folder = write_walk(tmp_path / "walk", duration_s=10.0)

    switched = []

    def config(*options):
        out = tmp_path / f"run{len(list(tmp_path.glob('run*')))}"
        assert main(["run", str(folder), *options, "-o", str(out)]) == 0
        info = json.loads((out / "run.json").read_text())
        switched.append(info["unseen_velocity_from_s"])
        return RunConfig.from_dict(info["config"])

    plain, unseen, auto = config(), config("--unseen-velocity"), config("--unseen-velocity", "auto")
    assert plain.unseen_velocity.mode == "auto" and plain == auto
    assert switched[0] is None and switched[1] == 0.0  # the walk's clean velocity never reads a standstill
    assert unseen == plain.with_overrides({"unseen_velocity.mode": "on"})
    assert RunConfig.for_mode("paper").unseen_velocity.mode == "off"
    older = {key: value for key, value in plain.to_dict().items() if key != "unseen_velocity"}
    assert RunConfig.from_dict(older).unseen_velocity.mode == "off"  # run.json from before the block
    assert config("--unseen-velocity", "off").unseen_velocity.mode == "off"
    effective = unseen.with_unseen_velocity()
    assert effective.filter.motion.step_noise_fraction == 0.55 and effective.engine.standing_speed_mps == 0.6
    assert effective.filter.scale_correction.fraction == 0.05
    assert effective.filter.motion.step_noise_across_fraction == 0.25  # wider along the step only
    assert plain.filter.motion.step_noise_across_fraction is None
    mixed = config("--unseen-velocity", "--set", "unseen_velocity.standing_speed_mps=0.3")
    assert mixed.with_unseen_velocity().engine.standing_speed_mps == 0.3


def _standstill(tmp_path, velocity_en) -> object:
    """A 30 s walk whose footsteps stop from 5 to 16 s while the velocity reads ``velocity_en``."""
    folder = write_walk(tmp_path / "walk", duration_s=30.0)
    steps = pd.read_csv(folder / "steps.csv")
    steps[(steps["t"] < 5.0) | (steps["t"] > 16.0)].to_csv(folder / "steps.csv", index=False)
    session = read_session(folder)
    if velocity_en is not None:
        still = (session.velocity["t"] > 5.0) & (session.velocity["t"] < 16.0)
        session.velocity.loc[still, ["ve", "vn"]] = velocity_en
    return session


@pytest.mark.parametrize(
    "velocity_en, switches",
    [((0.25, -0.15), True), ((0.0, 0.0), False), (None, False)],  # handled drift, a still model, missed steps
)
def test_auto_switches_to_the_unseen_preset_when_the_model_reads_motion_at_a_standstill(
    tmp_path, raster, velocity_en, switches
):
    session = _standstill(tmp_path, velocity_en)
    config = RunConfig.for_mode("fused", seed=1).with_overrides({"unseen_velocity.mode": "auto"})
    engine = _engine(session, raster, config)
    engine.push_velocity(session.velocity["t"].to_numpy(), session.velocity[["ve", "vn"]].to_numpy())
    engine.push_steps(session.steps["t"].to_numpy(), math.inf)
    engine.push_gnss(session.gnss)
    rows = engine.finish()
    noise = engine.tracker.predictor.config.step_noise_fraction
    if not switches:
        assert engine.unseen_since_t is None and noise == 0.25 and engine.standing_speed == 0.0
        return
    times = [r.t for r in rows if r.kind == "time"]
    assert engine.unseen_since_t == times[5]  # the fifth standstill update 2 s after the last footstep
    assert noise == 0.55 and engine.standing_speed == 0.6 and engine.tracker.scale.config.fraction == 0.05
    after = [(r.t, r.x, r.y) for r in rows if r.kind == "time" and r.t > times[6]]
    assert np.allclose(np.diff(np.array(after)[:, 1:], axis=0), 0.0, atol=0.1)  # standing from then on
    streamed = _stream(session, raster, config, [6.2, 9.7, 10.05, 13.3])
    pd.testing.assert_frame_equal(_stream(session, raster, config, []), streamed)


def test_auto_ignores_the_last_steps_still_in_the_velocity_window(tmp_path, raster):
    session = _standstill(tmp_path, (0.0, 0.0))
    v = session.velocity
    v.loc[(v["t"] > 5.0) & (v["t"] < 8.0), ["ve", "vn"]] = (0.5, 0.0)  # the window still walking
    config = RunConfig.for_mode("fused").with_overrides({"unseen_velocity.mode": "auto"})
    for settle_s, switches in ((2.0, False), (0.0, True)):
        engine = _engine(session, raster, config.with_overrides({"unseen_velocity.settle_s": settle_s}))
        engine.push_velocity(v["t"].to_numpy(), v[["ve", "vn"]].to_numpy())
        engine.push_steps(session.steps["t"].to_numpy(), math.inf)
        engine.push_gnss(session.gnss)
        engine.finish()
        assert (engine.unseen_since_t is not None) == switches
