"""The fixes' lag: estimated from a recording, compensated at each update, recorded in run.json."""

from __future__ import annotations

import json
import math

import numpy as np
import pandas as pd
import pytest
from test_run import write_walk

from curbside import settings
from curbside.cli.localize import main as localize_main
from curbside.localize.fix_lag import GRID_S, LagCompensator, estimate_fix_lag, lagged
from curbside.localize.pipeline import track_session
from curbside.localize.runconfig import FixLagConfig, RunConfig
from curbside.localize.session import read_session
from curbside.localize.streams import DisplacementIntegrator
from curbside.projection import LocalFrame

LON0, LAT0 = -122.40, 37.79
DT_S = 0.05


def _truth(duration_s: float = 300.0) -> tuple[np.ndarray, np.ndarray]:
    """A walk at 1.3 m/s turning by +-90 deg every 40 m, with a 10 s stop every third leg."""
    t = np.arange(0.0, duration_s, DT_S)
    speed = np.full(len(t), 1.3)
    leg_s = 40.0 / 1.3
    stop = (t % (3 * leg_s + 10.0)) > 3 * leg_s
    speed[stop] = 0.0
    distance = np.concatenate([[0.0], np.cumsum(speed[:-1] * DT_S)])
    heading = np.radians(90.0 * (np.floor(distance / 40.0) % 2))  # east, north, east, north, ...
    v = np.column_stack([speed * np.cos(heading), speed * np.sin(heading)])
    xy = np.vstack([[0.0, 0.0], np.cumsum(v[:-1] * DT_S, axis=0)])
    return t, xy, v


def _fixes(t, xy, lag_s: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """1 Hz fixes of the path lagged by ``lag_s``, with 1.5 m white and 2 m (30 s) correlated error."""
    rng = np.random.default_rng(seed)
    seen = lagged(xy, lag_s, DT_S)
    k = np.arange(0, len(t), int(round(1.0 / DT_S)))
    a = math.exp(-1.0 / 30.0)
    slow = np.zeros((len(k), 2))
    for i in range(1, len(k)):
        slow[i] = a * slow[i - 1] + math.sqrt(1 - a * a) * rng.normal(0, 2.0, 2)
    return t[k], seen[k] + slow + rng.normal(0, 1.5, (len(k), 2))


def _inertial(v: np.ndarray, seed: int) -> np.ndarray:
    """The walk's velocity 8 % fast, turned by 5 deg, with 0.1 m/s noise: what the fit must absorb."""
    rng = np.random.default_rng(seed + 100)
    c, s = math.cos(math.radians(5.0)), math.sin(math.radians(5.0))
    return 1.08 * v @ np.array([[c, s], [-s, c]]) + rng.normal(0, 0.1, v.shape)


def _displacement(t: np.ndarray, velocity_en: np.ndarray) -> DisplacementIntegrator:
    d = DisplacementIntegrator(1.0)
    d.push(t, velocity_en)
    return d


def _estimate(lag_s: float, seed: int) -> float:
    t, xy, v = _truth()
    tf, fixes = _fixes(t, xy, lag_s, seed)
    velocity = _displacement(t, _inertial(v, seed))
    return estimate_fix_lag(tf, fixes, np.full(len(tf), 6.0), velocity, FixLagConfig()).lag_s


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_estimate_finds_the_lag_of_a_smoothing_receiver(seed):
    assert _estimate(2.0, seed) in (2.0, 3.0)
    assert _estimate(4.0, seed) in (3.0, 4.0)


@pytest.mark.parametrize("seed", range(6))
def test_fixes_that_do_not_lag_get_no_compensation(seed):
    assert _estimate(0.0, seed) == 0.0


def test_too_few_fixes_estimate_no_lag():
    t, xy, v = _truth(60.0)
    tf, fixes = _fixes(t, xy, 2.0, 0)
    est = estimate_fix_lag(tf[:10], fixes[:10], np.full(10, 5.0), _displacement(t, v), FixLagConfig())
    assert est.lag_s == 0.0 and est.blocks == 0 and est.to_dict()["residual_m"] == {}


@pytest.mark.parametrize("spacing_s", [0.1, 0.55, 1.3])
def test_the_compensator_is_the_walk_minus_its_lag_at_any_update_spacing(spacing_s):
    t, xy, _ = _truth(120.0)
    truth_lag = xy - lagged(xy, 2.0, DT_S)  # the EMA on the fine grid: what the fixes trail by
    comp = LagCompensator(2.0)
    for now in np.arange(0.0, 120.0 - DT_S, spacing_s):
        k = int(round(now / DT_S))
        d = xy[k]
        offset = comp.offset(float(t[k]), d)
    # the fine grid's explicit EMA and the exact linear one differ by under a grid step's motion
    assert np.allclose(offset, truth_lag[k], atol=1.3 * GRID_S)
    assert np.hypot(*offset) > 1.0  # walking: the fix trails by about lag * speed


def _session(folder, lag_s: float, seed: int = 0):
    """A session folder (no map) of :func:`_truth`'s walk with fixes lagging by ``lag_s``."""
    folder.mkdir(parents=True)
    t, xy, v = _truth()
    frame = LocalFrame.around(LON0, LAT0)
    vel = _inertial(v, seed)
    pd.DataFrame({"t": t, "ve": vel[:, 0], "vn": vel[:, 1]}).to_csv(folder / "velocity.csv", index=False)
    steps = t[(np.arange(len(t)) % 11 == 0) & (np.hypot(v[:, 0], v[:, 1]) > 0)]
    pd.DataFrame({"t": steps}).to_csv(folder / "steps.csv", index=False)
    tf, fixes = _fixes(t, xy, lag_s, seed)
    origin = np.array(frame.to_xy(LON0, LAT0), float)
    lon, lat = frame.to_lonlat(fixes[:, 0] + origin[0], fixes[:, 1] + origin[1])
    gnss = pd.DataFrame({"t": tf, "lat": lat, "lon": lon, "accuracy_m": 6.0})
    gnss.to_csv(folder / "gnss.csv", index=False)
    (folder / "meta.json").write_text(json.dumps({"start": {"lat": LAT0, "lon": LON0, "heading_deg": 90.0}}))
    return read_session(folder), frame, t, xy


def _median_error(result, frame, t, xy) -> float:
    track = result.track
    x0, y0 = frame.to_xy(LON0, LAT0)
    x, y = frame.to_xy(track["lon"].to_numpy(), track["lat"].to_numpy())
    x, y = x - x0, y - y0
    gx, gy = np.interp(track["t"], t, xy[:, 0]), np.interp(track["t"], t, xy[:, 1])
    return float(np.median(np.hypot(x - gx, y - gy)))


def test_a_batch_run_compensates_the_lag_it_estimates(tmp_path):
    session, frame, t, xy = _session(tmp_path / "walk", 3.0)
    config = RunConfig.for_mode("fused", seed=1)
    off = track_session(session, None, config=config)  # opt-in
    auto = track_session(session, None, config=config.with_overrides({"fix_lag.mode": "auto"}))
    assert auto.fix_lag["mode"] == "auto" and auto.fix_lag["lag_s"] == 3.0
    assert auto.fix_lag["block_share"] >= 0.7 and off.fix_lag is None
    assert _median_error(auto, frame, t, xy) < 0.8 * _median_error(off, frame, t, xy)
    fixed = track_session(session, None, config=config.with_overrides({"fix_lag.mode": "fixed",
                                                                       "fix_lag.lag_s": 3.0}))
    assert fixed.fix_lag == {"mode": "fixed", "lag_s": 3.0}
    pd.testing.assert_frame_equal(fixed.track, auto.track)  # the same lag, however it was set
    paper = track_session(session, None, config=RunConfig.for_mode("paper").with_overrides(
        {"fix_lag.mode": "auto"}))
    assert paper.fix_lag["lag_s"] == 3.0  # any method that takes fixes may compensate them


def test_run_json_records_the_estimate_and_replays(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(settings, "cache_dir", tmp_path / "cache")
    _session(tmp_path / "walk", 2.0)
    assert localize_main(["run", str(tmp_path / "walk"), "--fix-lag", "auto", "-o", str(tmp_path / "a")]) == 0
    assert "2 s lag (estimated from the recording)" in capsys.readouterr().out
    info = json.loads((tmp_path / "a" / "run.json").read_text())
    assert info["fix_lag"]["lag_s"] == 2.0 and set(info["fix_lag"]["residual_m"]) == {"0", "1", "2", "3", "4"}
    assert localize_main(["run", str(tmp_path / "walk"), "--config", str(tmp_path / "a" / "run.json"),
                          "-o", str(tmp_path / "b")]) == 0
    assert (tmp_path / "a" / "track.csv").read_bytes() == (tmp_path / "b" / "track.csv").read_bytes()
    older = dict(info["config"])
    del older["fix_lag"]  # written before the block existed: replays as it ran, without it
    assert RunConfig.from_dict(older).fix_lag.mode == "off"
    assert localize_main(["run", str(tmp_path / "walk"), "-o", str(tmp_path / "c")]) == 0
    assert json.loads((tmp_path / "c" / "run.json").read_text())["fix_lag"] is None  # opt-in
    assert localize_main(["run", str(tmp_path / "walk"), "--fix-lag", "1.5", "-o", str(tmp_path / "d")]) == 0
    assert json.loads((tmp_path / "d" / "run.json").read_text())["fix_lag"] == {"mode": "fixed", "lag_s": 1.5}
    assert "1.5 s lag (fix_lag.lag_s)" in capsys.readouterr().out
    _session(tmp_path / "prompt", 0.0)
    argv = ["run", str(tmp_path / "prompt"), "--fix-lag", "auto", "-o", str(tmp_path / "e")]
    assert localize_main(argv) == 0
    assert "do not trail the walker (lag estimated from the recording: 0 s)" in capsys.readouterr().out


@pytest.mark.parametrize("options", [["--set", "fix_lag.mode=always"], ["--set", "fix_lag.ratio_max=1.5"],
                                     ["--set", "fix_lag.lag_s=-1"], ["--set", "fix_lag.candidates_s=[0]"],
                                     ["--set", "fix_lag.min_block_share=2"], ["--fix-lag", "soon"],
                                     ["--fix-lag", "-2"], ["--fix-lag", "nan"]])
def test_bad_values_are_one_line_errors(tmp_path, monkeypatch, capsys, options):
    monkeypatch.setattr(settings, "cache_dir", tmp_path / "cache")
    folder = write_walk(tmp_path / "walk", duration_s=5.0)
    try:
        status = localize_main(["run", str(folder), *options, "-o", str(tmp_path / "out")])
    except SystemExit as exc:  # a flag's value: the argument parser's one-line usage error
        status = exc.code
    assert status == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and ("fix_lag" in err or "--fix-lag" in err)
    assert not (tmp_path / "out").exists()
