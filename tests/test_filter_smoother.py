"""The fixed-lag smoother: genealogy bookkeeping, its place in the tracker, and its output."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from test_run_sf import MAP_FILE, phone_heading_error_deg, write_sf_walk

from curbside import settings
from curbside.cli.localize import main as localize_main
from curbside.evaluate.runner import SMOOTHED_METHOD, smoothed_results
from curbside.localize.filter import ParticleSet
from curbside.localize.filter.config import SmootherConfig
from curbside.localize.filter.smoother import FixedLagSmoother
from curbside.localize.pipeline import track_session
from curbside.localize.session import read_session
from curbside.osmseg.mapio import read_map
from curbside.projection import LocalFrame


def test_a_past_position_follows_the_particles_that_survive():
    p = ParticleSet(4)
    p.x[:] = [0.0, 1.0, 2.0, 3.0]
    smoother = FixedLagSmoother(SmootherConfig(lag_s=0.5), 4)
    assert smoother.record(0.0, p, resampled=False).shape == (0, 3)
    # Particles 1 and 3 survive the next update, twice each; all move 10 m.
    p.ancestors[:] = [3, 3, 1, 1]
    p.x[:] = [13.0, 13.0, 11.0, 11.0]
    smoothed = smoother.record(1.0, p, resampled=True)
    np.testing.assert_allclose(smoothed, [[0.0, 2.0, 0.0]])  # the filter said 1.5 at t = 0
    np.testing.assert_allclose(smoother.flush(p), [[1.0, 12.0, 0.0]])
    assert len(smoother) == 0


def test_the_buffer_matches_whole_paths_kept_naively():
    n, lag_s = 6, 2.5
    rng = np.random.default_rng(3)
    p = ParticleSet(n)
    smoother = FixedLagSmoother(SmootherConfig(lag_s=lag_s), n, capacity=2)  # grows and compacts
    paths_x, paths_y, times, got = [], [], [], []
    for k in range(40):
        t = 0.5 * k
        resampled = k > 0 and rng.random() < 0.6
        if resampled:
            p.ancestors[:] = rng.integers(0, n, n)
            paths_x = [x[p.ancestors] for x in paths_x]
            paths_y = [y[p.ancestors] for y in paths_y]
        p.state[0] = rng.normal(size=n)
        p.state[1] = rng.normal(size=n)
        w = rng.random(n)
        p.weights[:] = w / w.sum()
        paths_x.append(p.x.copy())
        paths_y.append(p.y.copy())
        times.append(t)
        got.append(smoother.record(t, p, resampled))
        for j, tj in enumerate(times):  # the naive answer for the update that became lag_s old now
            if t - lag_s < tj <= t - lag_s + 0.25:
                np.testing.assert_allclose(got[-1], [[tj, paths_x[j] @ p.weights, paths_y[j] @ p.weights]])
    got.append(smoother.flush(p))
    rows = np.concatenate(got)
    np.testing.assert_allclose(rows[:, 0], times)
    np.testing.assert_allclose(rows[-1, 1:], [p.x @ p.weights, p.y @ p.weights])


def test_a_negative_or_infinite_lag_is_refused():
    for lag in (-1.0, float("inf")):
        with pytest.raises(ValueError, match="lag_s"):
            SmootherConfig(lag_s=lag)


@pytest.fixture
def sf_walk(tmp_path, monkeypatch):
    monkeypatch.setattr(settings, "cache_dir", tmp_path / "cache")
    layers = read_map(MAP_FILE)
    folder, a, u, speed = write_sf_walk(
        tmp_path / "walk", layers, 0, heading_error_deg=phone_heading_error_deg, speed_factor=1.15
    )
    return layers, folder, a, u, speed


def test_smoothing_leaves_the_filter_alone_and_uses_what_came_later(sf_walk):
    layers, folder, a, u, speed = sf_walk
    session = read_session(folder)
    plain = track_session(session, layers, "fused", seed=0)
    config = plain.config.with_overrides({"filter.smoother.lag_s": 20})
    plain, smoothed = plain.track, track_session(session, layers, config=config).track
    pd.testing.assert_frame_equal(smoothed[plain.columns], plain)  # same seed, same filter track
    assert smoothed[["smooth_lat", "smooth_lon"]].notna().all().all()
    truth = a + np.outer(speed * smoothed["t"].to_numpy(), u)

    def median_error(x_col: str, y_col: str) -> float:
        return float(np.median(np.hypot(smoothed[x_col] - truth[:, 0], smoothed[y_col] - truth[:, 1])))

    lonlat = smoothed["smooth_lon"].to_numpy(), smoothed["smooth_lat"].to_numpy()
    smoothed["smooth_x"], smoothed["smooth_y"] = LocalFrame(layers.crs).to_xy(*lonlat)
    assert median_error("smooth_x", "smooth_y") < median_error("x_m", "y_m")


def test_localize_run_lag_s_writes_smoothed_columns_and_refuses_a_negative_lag(sf_walk, tmp_path, capsys):
    _, folder, *_ = sf_walk
    out = tmp_path / "out"
    assert localize_main(["run", str(folder), "--map", str(MAP_FILE), "--lag-s", "15", "-o", str(out)]) == 0
    track = pd.read_csv(out / "track.csv")
    assert {"smooth_lat", "smooth_lon"} <= set(track.columns)
    assert '"lag_s": 15.0' in (out / "run.json").read_text()
    with pytest.raises(SystemExit) as exc:
        localize_main(["run", str(folder), "--lag-s", "-2", "-o", str(tmp_path / "bad")])
    assert exc.value.code == 2
    assert "--lag-s: must be 0 or more" in capsys.readouterr().err
    assert not (tmp_path / "bad").exists()


def test_smoothed_runs_pool_as_their_own_method():
    errors = pd.DataFrame({"euclid_m": [1.0]})

    def run(method: str, smoothed: pd.DataFrame | None) -> dict:
        summary = None if smoothed is None else {"a": 1}
        return {"spec": {"method": method}, "errors": None, "errors_smoothed": smoothed,
                "metrics_smoothed": summary}

    fused, paper, plain = run("fused", errors), run("paper", errors), run("fused", None)
    (copy,) = smoothed_results([fused, paper, plain])
    assert copy["spec"]["method"] == SMOOTHED_METHOD and copy["errors"] is errors
    assert copy["metrics"] == {"a": 1} and fused["spec"]["method"] == "fused"
