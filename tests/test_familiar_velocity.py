"""The familiar-velocity test: a velocity model that knows the walker reads a smooth speed, and the track
then follows a second filter with a calm motion model that has run beside the default one from the start."""

from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pandas as pd
import pytest
from test_engine import _engine, _stream
from test_run import block_layers, write_walk

from curbside import settings
from curbside.cli.localize import main as localize_main
from curbside.localize.engine import SessionEngine
from curbside.localize.pipeline import _frame_for, _start_of
from curbside.localize.raster import rasterize_map
from curbside.localize.runconfig import FamiliarVelocityConfig, RunConfig
from curbside.localize.session import read_session
from curbside.localize.streams import DisplacementIntegrator
from curbside.localize.velocity_checks import SpeedJitterCheck


def _integrator(t: np.ndarray, speed: np.ndarray) -> DisplacementIntegrator:
    d = DisplacementIntegrator(1.0)
    d.push(t, np.column_stack([speed, np.zeros_like(speed)]))
    return d


def _check_over(speed_of_t, duration_s: float) -> SpeedJitterCheck:
    t = np.arange(0.0, duration_s, 0.05)
    d = _integrator(t, speed_of_t(t))
    check = SpeedJitterCheck(FamiliarVelocityConfig(), 0.0, d.at(0.0))
    for now in np.arange(0.5, duration_s, 0.37):  # updates at any times: the windows stay on their grid
        check.observe(d.at, float(now))
    return check


def test_a_smooth_speed_reads_familiar_and_the_verdict_is_final_at_final_samples():
    rng = np.random.default_rng(0)
    wobble = rng.normal(0.0, 0.01, 2000)  # 1 % per half-second window
    check = _check_over(lambda t: 1.3 * (1 + np.interp(t, np.arange(2000) * 0.5, wobble)), 90.0)
    assert check.smooth and check.final is True
    assert len(check.samples) == FamiliarVelocityConfig().final_samples  # no more taken after the verdict
    assert check.median_jitter < 0.05


def test_a_jittery_speed_is_not_familiar():
    rng = np.random.default_rng(1)
    jitter = rng.normal(0.0, 0.12, 2000)  # a phone's RoNIN new to the walker: about 10 % per window
    check = _check_over(lambda t: 1.3 * (1 + np.repeat(jitter, 10)[: len(t)]), 90.0)
    assert not check.smooth and check.final is False
    assert check.median_jitter > 0.05


def test_standing_gives_no_samples_and_too_few_samples_decide_nothing():
    standing = _check_over(lambda t: np.full(len(t), 0.1), 60.0)  # phantom motion under 0.6 m/s
    assert standing.samples == [] and not standing.smooth and standing.final is None
    short = _check_over(lambda t: np.full(len(t), 1.3), 15.0)  # 29 perfect samples, 40 needed
    assert 0 < len(short.samples) < FamiliarVelocityConfig().min_samples and not short.smooth


def test_the_first_window_after_a_start_or_a_stop_gives_no_sample():
    # the speed of the window before the first is unknown (NaN): it must not count as a sample
    check = _check_over(lambda t: np.full(len(t), 1.3), 2.0)
    assert len(check.samples) == 2 and all(math.isfinite(s) for s in check.samples)


@pytest.fixture(scope="module")
def raster():
    return rasterize_map(block_layers(), 0.5)


def _session(tmp_path, jitter: float, seed: int = 0):
    """The 80 s block walk, its velocity's speed changing by ``jitter`` from one half second to the next."""
    session = read_session(write_walk(tmp_path / "walk", duration_s=80.0))
    v = session.velocity
    factor = 1.0 + np.random.default_rng(seed).normal(0.0, jitter, len(v) // 10 + 1)
    v[["ve", "vn"]] = v[["ve", "vn"]].to_numpy() * np.repeat(factor, 10)[: len(v), None]
    return session


def _track(session, raster, mode: str) -> tuple[pd.DataFrame, object]:
    config = RunConfig.for_mode("fused", seed=2).with_overrides({"familiar_velocity.mode": mode})
    engine = _engine(session, raster, config)
    engine.push_velocity(session.velocity["t"].to_numpy(), session.velocity[["ve", "vn"]].to_numpy())
    engine.push_steps(session.steps["t"].to_numpy(), math.inf)
    engine.push_gnss(session.gnss)
    engine.finish()
    rows = pd.DataFrame([(r.t, r.x, r.y, r.motion) for r in engine.rows], columns=["t", "x", "y", "motion"])
    return rows, engine


def test_auto_follows_the_calm_filter_from_the_verdict_and_is_the_default_one_before(tmp_path, raster):
    session = _session(tmp_path, 0.0)
    auto, engine = _track(session, raster, "auto")
    on, _ = _track(session, raster, "on")
    off, _ = _track(session, raster, "off")
    familiar = auto["motion"] == "familiar"
    assert familiar.any() and not familiar.iloc[:20].any()  # 40 samples first: 20 s of walking
    assert (auto["motion"][~familiar] == "default").all() and (on["motion"] == "familiar").all()
    assert np.allclose(auto.loc[familiar, ["x", "y"]], on.loc[familiar, ["x", "y"]])
    assert np.allclose(auto.loc[~familiar, ["x", "y"]], off.loc[~familiar, ["x", "y"]])
    assert engine.familiar_velocity["verdict"] == "familiar" and engine.shadow is None  # final: 60 s walked
    calm = engine.tracker.predictor.config
    assert (calm.heading_noise_deg, calm.step_noise_fraction, calm.scale_noise_per_step) == (0.75, 0.15, 0.0)
    config = RunConfig.for_mode("fused", seed=2).with_overrides({"familiar_velocity.mode": "auto"})
    streamed = _stream(session, raster, config, [7.3, 21.0, 21.4, 40.05])
    pd.testing.assert_frame_equal(_stream(session, raster, config, []), streamed)


def test_auto_keeps_the_default_filter_for_a_jittery_velocity(tmp_path, raster):
    session = _session(tmp_path, 0.15)
    auto, engine = _track(session, raster, "auto")
    off, _ = _track(session, raster, "off")
    assert (auto["motion"] == "default").all()
    pd.testing.assert_frame_equal(auto, off.assign(motion="default"))
    assert engine.familiar_velocity["verdict"] == "not familiar" and engine.shadow is None


def test_a_model_caught_reading_motion_at_a_standstill_is_not_familiar(tmp_path, raster):
    session = _session(tmp_path, 0.0)
    steps = session.steps
    session = dataclasses.replace(session, steps=steps[(steps["t"] < 30) | (steps["t"] > 42)])
    v = session.velocity
    v.loc[(v["t"] > 30) & (v["t"] < 42), ["ve", "vn"]] = (0.25, -0.15)  # handled while standing
    config = RunConfig.for_mode("fused", seed=2).with_overrides({"familiar_velocity.mode": "auto"})
    engine = _engine(session, raster, config)
    engine.push_velocity(v["t"].to_numpy(), v[["ve", "vn"]].to_numpy())
    engine.push_steps(session.steps["t"].to_numpy(), math.inf)
    engine.push_gnss(session.gnss)
    rows = engine.finish()
    motions = [r.motion for r in engine.rows]
    assert "familiar" in motions  # smooth walking first ...
    assert engine.unseen_since_t is not None and engine.shadow is None  # ... then caught at a standstill
    after = [r.motion for r in rows if r.t > engine.unseen_since_t]
    assert after and set(after) == {"unseen"} and engine.familiar_velocity["verdict"] == "undecided"
    assert engine.tracker.predictor.config.step_noise_fraction == 0.55  # the default filter, unseen preset


def test_pdr_velocity_never_runs_the_test(tmp_path, raster):
    session = _session(tmp_path, 0.0)
    config = RunConfig.for_mode("fused").with_overrides({"familiar_velocity.mode": "auto"})
    start, t_begin = _start_of(session)
    engine = SessionEngine(config, _frame_for(session, block_layers()), raster, start=start, t_begin=t_begin,
                           step_means_velocity=True)
    assert engine.shadow is None and engine.familiar_velocity is None


def test_the_flag_the_record_and_replay(tmp_path, monkeypatch):
    monkeypatch.setattr(settings, "cache_dir", tmp_path / "cache")
    folder = write_walk(tmp_path / "walk", duration_s=40.0)

    def run(*options):
        out = tmp_path / f"run{len(list(tmp_path.glob('run*')))}"
        assert localize_main(["run", str(folder), *options, "-o", str(out)]) == 0
        return json.loads((out / "run.json").read_text()), pd.read_csv(out / "track.csv")

    plain_info, plain = run()
    assert RunConfig.from_dict(plain_info["config"]).familiar_velocity.mode == "off"  # opt-in
    assert plain_info["familiar_velocity"] is None and set(plain["motion"]) == {"default"}
    info, track = run("--familiar-velocity")  # the flag alone: auto
    assert RunConfig.from_dict(info["config"]).familiar_velocity.mode == "auto"
    assert info["familiar_velocity"]["verdict"] == "undecided"  # 40 s: familiar from 20 s, final at 60 s
    assert set(track["motion"]) == {"default", "familiar"}
    on_info, on_track = run("--familiar-velocity", "on")
    assert set(on_track["motion"]) == {"familiar"} and on_info["familiar_velocity"] is None
    _, replay = run("--config", str(tmp_path / "run1" / "run.json"))
    pd.testing.assert_frame_equal(replay, track)
    assert RunConfig.for_mode("paper").familiar_velocity.mode == "off"


@pytest.mark.parametrize("value", ["familiar_velocity.jitter_max=0", "familiar_velocity.mode=sometimes",
                                   "familiar_velocity.min_samples=0",
                                   "familiar_velocity.scale_correction_fraction=2"])
def test_bad_values_are_one_line_errors(tmp_path, monkeypatch, capsys, value):
    monkeypatch.setattr(settings, "cache_dir", tmp_path / "cache")
    folder = write_walk(tmp_path / "walk", duration_s=5.0)
    assert localize_main(["run", str(folder), "--set", value, "-o", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "familiar_velocity" in err
    assert not (tmp_path / "out").exists()
