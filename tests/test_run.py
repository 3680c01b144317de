"""End-to-end tests of ``localize run`` and the pipeline on synthetic walks along a synthetic block.

The block (local metres around a point of downtown San Francisco, UTM 10N): a street along x
(|y| < 6 m) with a crosswalk at |x| < 3 m, sidewalks north (6..10 m, ``N``) and south (-10..-6 m,
``S``), buildings beyond both. The walker goes east along the north sidewalk; GNSS snaps to the
opposite sidewalk, as it often does in urban canyons.
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import geopandas as gpd
import numpy as np
import pandas as pd
import pytest
import shapely

from curbside import settings
from curbside.cli.localize import main as localize_main
from curbside.errors import CurbsideInputError
from curbside.localize import engine as engine_module
from curbside.localize.particle_recorder import CloudRecorder
from curbside.localize.particle_store import unpack_particles
from curbside.localize.pipeline import track_session
from curbside.localize.raster import BUILDING, rasterize_map
from curbside.localize.runconfig import RunConfig
from curbside.localize.session import read_session
from curbside.osmseg.mapio import MapLayers, read_map, write_map
from curbside.projection import LocalFrame

X0, Y0 = 551000.0, 4182000.0
FRAME = LocalFrame(gpd.GeoSeries([], crs=32610).crs)


@pytest.fixture(autouse=True)
def _cache_in_tmp(tmp_path, monkeypatch):
    monkeypatch.setattr(settings, "cache_dir", tmp_path / "cache")


def block_layers() -> MapLayers:
    def box(x0, y0, x1, y1):
        return shapely.box(X0 + x0, Y0 + y0, X0 + x1, Y0 + y1)

    rows = [
        ("street", box(-150, -6, 150, 6), None),
        ("crosswalk", box(-3, -6, 3, 6), None),
        ("sidewalk", box(-150, 6, 150, 10), "N"),
        ("sidewalk", box(-150, -10, 150, -6), "S"),
        ("building", box(-150, 10, 150, 60), None),
        ("building", box(-150, -60, 150, -10), None),
    ]
    gdf = gpd.GeoDataFrame(
        {"class": [r[0] for r in rows], "segment_id": [r[2] for r in rows], "street": "Test St",
         "side": None},
        geometry=[r[1] for r in rows], crs=32610,
    )
    return MapLayers(gdf, {"source": "synthetic"})


@pytest.fixture
def map_file(tmp_path) -> Path:
    return write_map(block_layers(), tmp_path / "block.geojson")


def lonlat(x, y):
    lon, lat = FRAME.to_lonlat(X0 + np.asarray(x, float), Y0 + np.asarray(y, float))
    return lon, lat


def truth_xy(t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The walker: east along the north sidewalk (y = 8 m) at 1.3 m/s from x = -100 m at t = 0."""
    return -100.0 + 1.3 * t, np.full_like(t, 8.0)


def write_walk(
    folder: Path,
    seed: int = 0,
    duration_s: float = 120.0,
    gnss_gap: tuple[float, float] | None = None,
    start_xy: tuple[float, float] | None = (-100.0, 8.0),
    gnss_offset_m: tuple[float, float] = (0.0, -16.0),
) -> Path:
    """A SPEC session: steps.csv, velocity.csv (biased, scaled, noisy), gnss.csv (biased), meta.json."""
    rng = np.random.default_rng(seed)
    folder.mkdir(parents=True)
    steps = np.arange(0.0, duration_s, 0.55)
    pd.DataFrame({"t": steps}).to_csv(folder / "steps.csv", index=False)
    tv = np.arange(0.0, duration_s, 0.05)
    bias = math.radians(6.0)  # inertial heading error, which the drift state has to learn
    ve = 1.05 * 1.3 * math.cos(bias) + rng.normal(0, 0.05, len(tv))
    vn = 1.05 * 1.3 * math.sin(bias) + rng.normal(0, 0.05, len(tv))
    pd.DataFrame({"t": tv, "ve": ve, "vn": vn}).to_csv(folder / "velocity.csv", index=False)
    tg = np.arange(0.0, duration_s, 1.0)
    if gnss_gap is not None:
        tg = tg[(tg < gnss_gap[0]) | (tg > gnss_gap[1])]
    gx, gy = truth_xy(tg)
    lon, lat = lonlat(gx + gnss_offset_m[0] + rng.normal(0, 3, len(tg)),
                      gy + gnss_offset_m[1] + rng.normal(0, 3, len(tg)))
    acc = np.full(len(tg), 10.0)
    acc[::10] = -1.0  # invalid fixes: no update
    gnss = pd.DataFrame({"t": tg, "lat": lat, "lon": lon, "accuracy_m": acc})
    gnss.to_csv(folder / "gnss.csv", index=False)
    if start_xy is not None:
        slon, slat = lonlat(*start_xy)
        meta = {"start": {"lat": float(slat), "lon": float(slon), "heading_deg": 90.0, "t": 0.0}}
        (folder / "meta.json").write_text(json.dumps(meta))
    return folder


def errors_m(track: pd.DataFrame) -> np.ndarray:
    tx, ty = truth_xy(track["t"].to_numpy())
    return np.hypot(track["x_m"].to_numpy() - X0 - tx, track["y_m"].to_numpy() - Y0 - ty)


# -- the three modes on the map -------------------------------------------------------------------------


class KeepsTheFloats(CloudRecorder):
    """A particle recorder that also keeps each footstep's cloud as the engine gave it, in floats."""

    def __init__(self, crs: str, **kwargs) -> None:
        super().__init__(crs, **kwargs)
        #: One ``(5, N)`` array a footstep: x, y, theta (rad), scale, weight.
        self.floats: list[np.ndarray] = []

    def add(self, t, ref_x_m, ref_y_m, x, y, theta_rad, scale, weight) -> None:
        self.floats.append(np.vstack([x, y, theta_rad, scale, weight]))
        super().add(t, ref_x_m, ref_y_m, x, y, theta_rad, scale, weight)


@contextmanager
def keeping_the_floats() -> Iterator[list[KeepsTheFloats]]:
    """While open, each run's particle recorder is a :class:`KeepsTheFloats`; the list gets them in turn."""
    made: list[KeepsTheFloats] = []

    def recorder(crs: str, **kwargs) -> KeepsTheFloats:
        made.append(KeepsTheFloats(crs, **kwargs))
        return made[-1]

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(engine_module, "CloudRecorder", recorder)
        yield made


def tracked_keeping_the_floats(session, layers, mode: str, seed: int):
    """``track_session`` with the particles saved, and its clouds as floats, ``(K, 5, N)`` (see
    :class:`KeepsTheFloats`)."""
    with keeping_the_floats() as made:
        result = track_session(session, layers, mode, seed=seed, save_particles=True)
    (recorder,) = made
    return result, np.stack(recorder.floats)


@pytest.fixture(scope="module")
def walk_results(tmp_path_factory):
    """``{seed: {mode: TrackResult, "floats": {mode: (K, 5, N) clouds}}}``."""
    tmp = tmp_path_factory.mktemp("walks")
    settings_cache = settings.cache_dir
    settings.cache_dir = tmp / "cache"
    try:
        layers = block_layers()
        out = {}
        for seed in (0, 1):
            session = read_session(write_walk(tmp / f"walk{seed}", seed=seed))
            out[seed] = {"gnss": track_session(session, layers, "gnss", seed=seed), "floats": {}}
            for mode in ("inertial", "fused"):
                result, out[seed]["floats"][mode] = tracked_keeping_the_floats(session, layers, mode, seed)
                out[seed][mode] = result
        return out
    finally:
        settings.cache_dir = settings_cache


@pytest.mark.parametrize("seed", [0, 1])
def test_fused_beats_gnss_and_stays_on_the_right_sidewalk(walk_results, seed):
    res = walk_results[seed]
    gnss, fused, inertial = (errors_m(res[m].track) for m in ("gnss", "fused", "inertial"))
    assert np.median(fused) < 0.5 * np.median(gnss)
    assert np.percentile(fused, 90) < np.percentile(gnss, 90)
    assert np.median(inertial) < np.median(gnss)
    on_north = (res["fused"].track["sidewalk_segment_id"] == "N").mean()
    assert on_north > 0.9
    assert (res["gnss"].track["sidewalk_segment_id"] == "N").mean() < 0.2
    # No particles in gnss mode: no posterior, and the mode estimate is the track itself.
    assert res["gnss"].track["segment_prob"].isna().all()
    gnss_track = res["gnss"].track
    np.testing.assert_array_equal(gnss_track[["mode_lat", "mode_lon"]], gnss_track[["lat", "lon"]])


def test_particles_never_stay_in_buildings(walk_results):
    raster = rasterize_map(block_layers(), 0.5)
    for mode in ("inertial", "fused"):
        floats = walk_results[0]["floats"][mode]  # as the filter held them
        x, y, alive = floats[:, 0], floats[:, 1], floats[:, 4] > 0
        in_building = (raster.codes_at(x, y) >= BUILDING) & alive
        assert in_building.mean(axis=1).max() == 0.0 and alive.mean(axis=1).min() > 0.3
        assert x.shape == (len(walk_results[0][mode].track), 2000)  # the default N


def test_the_stored_clouds_are_the_filters_rounded(walk_results):
    for mode in ("inertial", "fused"):
        floats, result = walk_results[0]["floats"][mode], walk_results[0][mode]
        clouds = unpack_particles(result.snapshots)
        assert clouds.x.shape == floats[:, 0].shape == (len(result.track), 2000)
        np.testing.assert_array_equal(clouds.t, result.track["t"].to_numpy())
        for stored, given in ((clouds.x, floats[:, 0]), (clouds.y, floats[:, 1])):
            assert np.abs(stored - given).max() <= 0.05 + 1e-4  # decimetres, through float32 offsets
        # map-killed particles keep their place with no weight, and are stored with none
        assert clouds.weight is not None and (floats[:, 4] == 0).any()
        assert (clouds.weight[floats[:, 4] == 0] == 0).all()


def test_drift_state_learns_the_inertial_heading_error(walk_results):
    # The first motion is aligned with the start heading (drift about -6 deg from the start).
    theta = walk_results[0]["inertial"].track["theta_drift_deg"].to_numpy()
    assert abs(theta[0] + 6.0) < 3.0
    assert abs(np.median(theta[-50:]) + 6.0) < 5.0


def test_speed_scale_is_off_in_the_papers_filter_and_learned_in_curbsides(walk_results, tmp_path):
    assert RunConfig.for_mode("paper").filter.motion.scale_init_sigma == 0.0
    assert RunConfig.for_mode("fused").filter.motion.scale_init_sigma > 0.0
    # The velocity is 5 % fast; along a straight street only GNSS can tell.
    session = read_session(write_walk(tmp_path / "walk", seed=1))
    scale = track_session(session, block_layers(), "fused", seed=1).track["speed_scale"]
    assert abs(scale.iat[0] - 1.0) < 0.03
    assert abs(np.median(scale.iloc[-50:]) - 1 / 1.05) < 0.03


# -- the command ----------------------------------------------------------------------------------------


def run_cli(*args) -> int:
    return localize_main(["run", *map(str, args)])


def test_cli_softens_the_walls_of_a_map_whose_buildings_cover_its_sidewalks(tmp_path, map_file, capsys):
    session = write_walk(tmp_path / "walk", duration_s=30.0)
    layers = block_layers()
    north = layers.gdf["geometry"].bounds["miny"] == Y0 + 10
    layers.gdf.loc[north & (layers.gdf["class"] == "building"), "geometry"] = shapely.box(
        X0 - 150, Y0 + 8, X0 + 150, Y0 + 60
    )  # drawn 2 m south, over the north sidewalk the walker is on (y = 8 m)
    shifted = write_map(layers, tmp_path / "shifted.geojson")
    assert run_cli(session, "--map", map_file, "-o", tmp_path / "clean") == 0
    assert "walls are soft" not in capsys.readouterr().out
    assert run_cli(session, "--map", shifted, "-o", tmp_path / "shifted") == 0
    said = capsys.readouterr().out
    assert "sidewalks and crosswalks count where they overlap, and walls are soft by 1.5 m" in said
    info = {name: json.loads((tmp_path / name / "run.json").read_text()) for name in ("clean", "shifted")}
    assert info["clean"]["wall_tolerance_m"] == 0.0 and info["shifted"]["wall_tolerance_m"] == 1.5
    assert info["clean"]["walkable_first"] is False and info["shifted"]["walkable_first"] is True
    track = pd.read_csv(tmp_path / "shifted" / "track.csv")
    # Median offset from the walker's line: hard walls at 8 m 1.1 m, soft walls alone 0.75 m; with the
    # sidewalk over the building as close as on the right map (0.29 and 0.44 m at this seed).
    clean = pd.read_csv(tmp_path / "clean" / "track.csv")
    offset_clean, offset = (np.median(np.abs(t["y_m"] - (Y0 + 8.0))) for t in (clean, track))
    assert offset < max(0.5, offset_clean + 0.1)


def test_cli_writes_track_files_and_same_seed_same_track(tmp_path, map_file, capsys):
    session = write_walk(tmp_path / "walk", duration_s=40.0)
    assert run_cli(session, "--map", map_file, "--seed", 3, "--save-particles", "-o", tmp_path / "a") == 0
    assert run_cli(session, "--map", map_file, "--seed", 3, "-o", tmp_path / "b") == 0
    assert run_cli(session, "--map", map_file, "--seed", 4, "-o", tmp_path / "c") == 0
    a = (tmp_path / "a" / "track.csv").read_bytes()
    assert a == (tmp_path / "b" / "track.csv").read_bytes()
    assert a != (tmp_path / "c" / "track.csv").read_bytes()
    track = pd.read_csv(tmp_path / "a" / "track.csv")
    assert list(track.columns) == ["t", "lat", "lon", "x_m", "y_m", "accuracy_m", "update", "gnss_used",
                                   "theta_drift_deg", "speed_scale", "n_eff", "recovered", "injected",
                                   "motion", "sidewalk_segment_id", "segment_prob", "mode_lat", "mode_lon",
                                   "segment_distance_m"]
    assert (np.diff(track["t"]) > 0).all() and len(track) == len(np.arange(0, 40, 0.55))
    # the MAP segment and its posterior probability; the mode estimate lies on that sidewalk
    assert track["segment_prob"].between(0.0, 1.0 + 1e-9).all()
    assert (track["sidewalk_segment_id"] == "N").mean() > 0.9
    _, mode_y = FRAME.to_xy(track["mode_lon"].to_numpy(), track["mode_lat"].to_numpy())
    assert np.median(np.abs(mode_y - Y0 - 8.0)) < 1.5
    doc = json.loads((tmp_path / "a" / "track.geojson").read_text())
    kinds = [f["geometry"]["type"] for f in doc["features"]]
    assert kinds[0] == "LineString" and kinds.count("Point") == len(track)
    with np.load(tmp_path / "a" / "particles.npz") as npz:
        clouds = unpack_particles(npz)
    assert clouds.x.shape == (len(track), 2000)  # curbside fused's default N
    weight = np.ones(clouds.y.shape) if clouds.weight is None else clouds.weight
    mean_y = (weight * clouds.y).sum(axis=1) / weight.sum(axis=1)
    assert np.abs(mean_y - track["y_m"]).max() < 0.06  # decimetre positions, weights in 1/255
    info = json.loads((tmp_path / "a" / "run.json").read_text())
    assert info["velocity_source"] == "file" and info["step_source"] == "file" and info["config"]["seed"] == 3
    assert info["config"]["filter"]["n_particles"] == 2000
    assert info["config"]["filter"]["map"]["jaywalk_weight"] == 0.4
    assert info["heading_corrections"] == 0  # good fixes and a right velocity: never needed
    assert info["config"]["filter"]["heading_correction"]["fraction"] == 0.1
    calibration = info["calibration"]  # segment_prob tempered by the fixes' persistence
    assert calibration["fix_pairs"] > 0 and 0.0 <= calibration["fix_persistence"] <= 1.0
    assert calibration["temperature"] == pytest.approx(1.5 + 2.0 * calibration["fix_persistence"])
    assert not (tmp_path / "b" / "particles.npz").exists()
    assert "updates" in capsys.readouterr().out


@pytest.mark.parametrize("mode", ["gnss", "inertial", "fused"])
def test_cli_modes_without_map(tmp_path, mode):
    session = write_walk(tmp_path / "walk", duration_s=20.0)
    assert run_cli(session, "--mode", mode, "--particles", 100, "-o", tmp_path / "out") == 0
    track = pd.read_csv(tmp_path / "out" / "track.csv")
    assert len(track) > 30 and track[["lat", "lon"]].notna().all().all()
    assert "sidewalk_segment_id" not in track


def test_gnss_gap_of_minutes_runs_on_inertial_data(tmp_path, map_file):
    session = read_session(write_walk(tmp_path / "walk", duration_s=220.0, gnss_gap=(20.0, 200.0)))
    track = track_session(session, read_map(map_file), "fused", seed=0).track
    in_gap = (track["t"] > 25) & (track["t"] < 195)
    assert in_gap.sum() > 250
    # Without fixes the map holds the walker on the sidewalk, and the along-street error grows only
    # as the 5 % scale error of the velocity (234 m walked in the gap).
    across = np.abs(track["y_m"].to_numpy() - Y0 - 8.0)
    assert np.median(across[in_gap]) < 1.5
    along = track["x_m"].to_numpy() - X0 - truth_xy(track["t"].to_numpy())[0]
    assert np.abs(along[in_gap]).max() < 0.06 * 1.3 * 180 + 3.0
    assert track["recovered"].sum() == 0


def test_start_pose_in_building_recovers_with_a_warning(tmp_path, map_file, caplog):
    session = read_session(write_walk(tmp_path / "walk", duration_s=20.0, start_xy=(-100.0, 14.0)))
    track = track_session(session, read_map(map_file), "inertial", seed=0).track
    assert "inside a building" in caplog.text
    assert track["y_m"].iat[0] - Y0 < 10.0
    assert (track["sidewalk_segment_id"] == "N").mean() > 0.9


def test_fixes_that_all_report_no_usable_accuracy_are_named_in_a_warning(tmp_path, map_file, caplog):
    folder = write_walk(tmp_path / "walk", duration_s=20.0)
    track_session(read_session(folder), read_map(map_file), "fused", seed=0)
    assert "usable accuracy" not in caplog.text  # some fixes are invalid, most are not
    gnss = pd.read_csv(folder / "gnss.csv").assign(accuracy_m=0.0)
    gnss.to_csv(folder / "gnss.csv", index=False)
    with caplog.at_level("WARNING", logger="curbside.localize.pipeline"):
        result = track_session(read_session(folder), read_map(map_file), "fused", seed=0)
    assert "walk/gnss.csv: none of its 20 fixes reports a usable accuracy" in caplog.text
    assert not result.track["gnss_used"].any()


def test_a_truncated_velocity_file_is_named_in_a_warning(tmp_path, map_file, caplog):
    folder = write_walk(tmp_path / "walk", duration_s=60.0)
    with caplog.at_level("WARNING", logger="curbside.localize.input_warnings"):
        track_session(read_session(folder), read_map(map_file), "fused", seed=0)
    assert "velocity covers" not in caplog.text
    velocity = pd.read_csv(folder / "velocity.csv")
    velocity[velocity["t"] < 1.0].to_csv(folder / "velocity.csv", index=False)
    with caplog.at_level("WARNING", logger="curbside.localize.input_warnings"):
        track_session(read_session(folder), read_map(map_file), "fused", seed=0)
    assert "walk/velocity.csv: the velocity covers t=0.0-1.0 s of the walk's 0.0-" in caplog.text
    # standing for 15 s at each end (a `convert --pdr` session): the footsteps say where the walk is
    caplog.clear()
    for name in ("steps.csv", "velocity.csv"):
        table = pd.read_csv(folder / name) if name == "steps.csv" else velocity
        table[(table["t"] > 15) & (table["t"] < 45)].to_csv(folder / name, index=False)
    with caplog.at_level("WARNING", logger="curbside.localize.input_warnings"):
        track_session(read_session(folder), read_map(map_file), "fused", seed=0)
    assert "velocity covers" not in caplog.text


def test_gnss_start_without_start_pose(tmp_path, map_file):
    folder = write_walk(tmp_path / "walk", duration_s=60.0, start_xy=None, gnss_offset_m=(0, 0))
    session = read_session(folder)
    result = track_session(session, read_map(map_file), "fused", seed=0)
    assert np.median(errors_m(result.track)[-40:]) < 5.0


def test_inertial_without_start_pose_says_what_anchors_it(tmp_path, map_file, caplog):
    folder = write_walk(tmp_path / "walk", duration_s=20.0, start_xy=None, gnss_offset_m=(0, 0))
    with caplog.at_level("WARNING", logger="curbside.localize.pipeline"):
        track_session(read_session(folder), read_map(map_file), "fused", seed=0)
        assert "no start pose" not in caplog.text
        track_session(read_session(folder), read_map(map_file), "inertial", seed=0)
    assert "no start pose: the inertial track starts at the first usable GNSS fix" in caplog.text


def test_fixed_cadence_without_steps_or_imu(tmp_path):
    folder = write_walk(tmp_path / "walk", duration_s=10.0)
    (folder / "steps.csv").unlink()
    result = track_session(read_session(folder), None, "inertial", seed=0)
    assert result.step_source == "cadence"
    np.testing.assert_allclose(np.diff(result.track["t"]), 0.5)


# -- bad input --------------------------------------------------------------------------------------------


def assert_exit_2(capsys, args, *words):
    out = args[args.index("-o") + 1]
    assert run_cli(*args) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err
    for word in words:
        assert word in err
    assert not Path(out).exists()


def test_missing_session_exits_2(tmp_path, capsys):
    assert_exit_2(capsys, [tmp_path / "nope", "-o", tmp_path / "out"], "nope")


def test_nan_in_velocity_exits_2(tmp_path, capsys):
    folder = write_walk(tmp_path / "walk", duration_s=10.0)
    v = pd.read_csv(folder / "velocity.csv")
    v.loc[5, "ve"] = np.nan
    v.to_csv(folder / "velocity.csv", index=False)
    assert_exit_2(capsys, [folder, "-o", tmp_path / "out"], "velocity.csv", "row")


def test_out_of_order_gnss_timestamps_exit_2(tmp_path, capsys):
    folder = write_walk(tmp_path / "walk", duration_s=10.0)
    g = pd.read_csv(folder / "gnss.csv")
    g.loc[[3, 4], "t"] = g.loc[[4, 3], "t"].to_numpy()
    g.to_csv(folder / "gnss.csv", index=False)
    assert_exit_2(capsys, [folder, "-o", tmp_path / "out"], "gnss.csv", "out-of-order")


def test_start_pose_outside_the_map_exits_2(tmp_path, map_file, capsys):
    folder = write_walk(tmp_path / "walk", duration_s=10.0, start_xy=(3000.0, 8.0))
    assert_exit_2(capsys, [folder, "--map", map_file, "-o", tmp_path / "out"], "meta.json", "outside")


def test_session_outside_the_map_exits_2(tmp_path, map_file, capsys):
    folder = write_walk(tmp_path / "walk", duration_s=10.0, start_xy=None, gnss_offset_m=(5000.0, 0.0))
    assert_exit_2(capsys, [folder, "--map", map_file, "-o", tmp_path / "out"], "gnss.csv", "outside")


@pytest.mark.parametrize("option", [("--jaywalk-weight", "1.5"), ("--particles", "0"), ("--mode", "best")])
def test_bad_options_exit_2(tmp_path, capsys, option):
    folder = write_walk(tmp_path / "walk", duration_s=5.0)
    with pytest.raises(SystemExit) as exit_info:  # argparse usage errors exit directly
        run_cli(folder, *option, "-o", tmp_path / "out")
    assert exit_info.value.code == 2
    assert option[0] in capsys.readouterr().err


def test_missing_velocity_for_file_source_exits_2(tmp_path, capsys):
    folder = write_walk(tmp_path / "walk", duration_s=5.0)
    (folder / "velocity.csv").unlink()
    assert_exit_2(capsys, [folder, "--velocity-source", "file", "-o", tmp_path / "out"], "velocity.csv")


def test_inertial_mode_without_inertial_data_raises(tmp_path):
    folder = write_walk(tmp_path / "walk", duration_s=5.0)
    (folder / "velocity.csv").unlink()
    (folder / "steps.csv").unlink()
    with pytest.raises(CurbsideInputError, match="inertial data"):
        track_session(read_session(folder), None, "inertial")
    assert len(track_session(read_session(folder), None, "gnss").track) > 5


# -- real data ------------------------------------------------------------------------------------------


@pytest.mark.slow
@pytest.mark.parametrize("trial", ["TrainingTrial23_repetition02", "TrainingTrial26_repetition02"])
def test_ipin_fused_beats_raw_gnss_in_the_basement(shared_data, trial):
    """Two basement trials of IPIN 2023 with poor GNSS (README: 9.2 m and 23.4 m median error)."""
    from curbside.localize.readers.ipin import read_trial

    session = read_trial(shared_data / "ipin2023" / "ipin2023-t3.h5", trial)
    start = session.meta["start"]
    frame = LocalFrame.around(start["lon"], start["lat"])
    wx, wy = frame.to_xy(session.waypoints["lon"].to_numpy(), session.waypoints["lat"].to_numpy())
    tw = session.waypoints["t"].to_numpy()
    medians = {}
    for mode in ("gnss", "fused"):
        track = track_session(session, None, mode, seed=0, velocity_source="pdr").track
        tx, ty = frame.to_xy(track["lon"].to_numpy(), track["lat"].to_numpy())
        t = track["t"].to_numpy()
        err = np.hypot(np.interp(tw, t, tx) - wx, np.interp(tw, t, ty) - wy)[1:]  # skip the start
        medians[mode] = np.median(err)
    assert medians["fused"] < 0.6 * medians["gnss"]


# -- IMU sessions: velocity source and footsteps -----------------------------------------------------------

IPIN_CUT = Path(__file__).parent / "data" / "sessions" / "ipin2023-cut.h5"


@pytest.fixture
def imu_session():
    from curbside.localize.readers import read_any

    return read_any(f"{IPIN_CUT}::TrainingTrial01_repetition01")


def _no_nan(constant: str):
    raise AssertionError(f"run.json holds {constant}: not strict JSON")


def test_real_imu_session_runs_with_pdr_and_detected_steps(tmp_path, capsys):
    src = f"{IPIN_CUT}::TrainingTrial01_repetition01"
    assert run_cli(src, "--velocity-source", "pdr", "-o", tmp_path / "out") == 0
    info = json.loads((tmp_path / "out" / "run.json").read_text(), parse_constant=_no_nan)  # strict JSON
    assert info["velocity_source"] == "pdr" and info["step_source"] == "detected"
    # the trial has surveyed waypoints: the track's error there, and how often its 68 % radius held
    scored = info["waypoint_error"]
    assert scored["n_waypoints"] >= 2 and 0.0 <= scored["waypoint_accuracy_held"] <= 1.0
    assert f"accuracy_m held {round(scored['waypoint_accuracy_held'] * scored['n_waypoints'])} of" in (
        capsys.readouterr().out
    )
    track = pd.read_csv(tmp_path / "out" / "track.csv")
    assert len(track) > 15 and track["recovered"].sum() == 0
    # 20 s of walking from the first POSI: the track moves, at walking pace.
    x, y, t = track["x_m"].to_numpy(), track["y_m"].to_numpy(), track["t"].to_numpy()
    assert 0.5 < np.hypot(x[-1] - x[0], y[-1] - y[0]) / (t[-1] - t[0]) < 2.0


def test_ronin_unavailable_falls_back_to_pdr(imu_session, monkeypatch, caplog):
    from curbside.localize.ronin import infer

    def missing(*args, **kwargs):
        raise CurbsideInputError("ronin_compact.pt", "no such RoNIN weights/config file")

    monkeypatch.setattr(infer, "ronin_velocity", missing)
    result = track_session(imu_session, None, "fused", seed=0)
    assert result.velocity_source == "pdr"
    assert "falling back to PDR" in caplog.text
    with pytest.raises(CurbsideInputError, match="RoNIN"):
        track_session(imu_session, None, "fused", seed=0, velocity_source="ronin")


def test_ronin_velocity_is_used_when_available(imu_session, monkeypatch):
    from curbside.localize.ronin import infer

    t = imu_session.imu["t"].to_numpy()[::10]
    monkeypatch.setattr(
        infer, "ronin_velocity", lambda imu, **kw: pd.DataFrame({"t": t, "ve": 1.0, "vn": 0.0})
    )
    result = track_session(imu_session, None, "inertial", seed=0)
    assert result.velocity_source == "ronin"
    track = result.track
    # One metre per second, turned onto the start heading: the estimate moves at ~1 m/s.
    speed = np.hypot(np.diff(track["x_m"]), np.diff(track["y_m"])) / np.diff(track["t"])
    assert 0.5 < np.median(speed) < 1.5


# -- the output folder ------------------------------------------------------------------------------------


def test_an_output_folder_holding_the_users_files_is_refused_and_kept(tmp_path, capsys):
    folder = write_walk(tmp_path / "walk", duration_s=10.0)
    user = tmp_path / "mine"
    user.mkdir()
    map_file = write_map(block_layers(), user / "block.geojson")
    assert run_cli(folder, "--map", map_file, "-o", user) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--overwrite" in err
    assert map_file.is_file() and sorted(p.name for p in user.iterdir()) == ["block.geojson"]
    assert run_cli(folder, "--map", map_file, "--overwrite", "-o", user) == 0
    assert map_file.is_file() and (user / "track.csv").is_file()
    assert run_cli(folder, "--map", map_file, "-o", user) == 0  # now a previous curbside output


def test_output_to_the_current_folder(tmp_path, monkeypatch):
    folder = write_walk(tmp_path / "walk", duration_s=10.0)
    out = tmp_path / "here"
    out.mkdir()
    monkeypatch.chdir(out)
    assert run_cli(folder, "-o", ".") == 0
    assert (out / "track.csv").is_file() and (out / "run.json").is_file()


# -- waypoints that cannot be scored, particle stores that cannot be read ----------------------------------


def _waypoints(folder: Path, xs: list[float], ts: list[float]) -> Path:
    lon, lat = lonlat(xs, [8.0] * len(xs))
    pd.DataFrame({"t": ts, "lat": lat, "lon": lon}).to_csv(folder / "waypoints.csv", index=False)
    return folder / "waypoints.csv"


@pytest.mark.parametrize(
    "duration_s, waypoints, why",
    [(0.5, ([-100.0, -99.0, -98.0], [0.0, 0.5, 1.0]), "at least two estimates"),
     (10.0, ([-99.0], [1.0]), "at least two of them")],
)
def test_a_waypoint_score_that_cannot_be_made_warns_and_the_track_is_written(
    tmp_path, map_file, capsys, caplog, duration_s, waypoints, why
):
    folder = write_walk(tmp_path / "walk", duration_s=duration_s)
    path = _waypoints(folder, *waypoints)
    assert run_cli(folder, "--map", map_file, "-o", tmp_path / "out") == 0
    assert (tmp_path / "out" / "track.csv").is_file()
    warned = [r.getMessage() for r in caplog.records if "at waypoints" in r.getMessage()]
    assert len(warned) == 1 and warned[0].startswith(f"{path}: error at waypoints not scored")
    assert why in warned[0]
    info = json.loads((tmp_path / "out" / "run.json").read_text())
    assert info["waypoint_error"]["n_waypoints"] == 0 and info["waypoint_error"]["waypoint_median_m"] is None
    assert "error at" not in capsys.readouterr().out


def test_view_names_a_corrupt_particle_store_in_one_line(tmp_path, capsys):
    folder = write_walk(tmp_path / "walk", duration_s=5.0)
    assert run_cli(folder, "--particles", 100, "--save-particles", "-o", tmp_path / "run") == 0
    store = tmp_path / "run" / "particles.npz"
    store.write_bytes(store.read_bytes()[:200])
    capsys.readouterr()
    assert localize_main(["view", str(tmp_path / "run"), "-o", str(tmp_path / "v.html")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"{store}: not a readable particle store" in err
    assert not (tmp_path / "v.html").exists()
