"""A synthetic walk on a real map: Mission Street between 1st and Fremont, San Francisco.

``tests/data/filter/sf-mission-1st.geojson`` was cut from the bundled OSM extract with
``build_map(bbox=(-122.3985, 37.7882, -122.3958, 37.7902))`` (© OpenStreetMap contributors, ODbL).
The walker follows the south-east sidewalk of Mission Street (segment ``w417101712-0-R``) from end
to end; GNSS is pulled onto the opposite sidewalk (the urban-canyon failure the paper targets).
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import shapely
from test_run import tracked_keeping_the_floats

from curbside import settings
from curbside.localize.particle_store import unpack_particles
from curbside.localize.pipeline import track_session
from curbside.localize.raster import BUILDING, rasterize_map
from curbside.localize.runconfig import RunConfig
from curbside.localize.session import read_session
from curbside.osmseg.mapio import read_map
from curbside.projection import LocalFrame

WALKED = "w417101712-0-R"
OPPOSITE = "w417101712-0-L"


MAP_FILE = Path(__file__).parent / "data" / "filter" / "sf-mission-1st.geojson"


@pytest.fixture(scope="module")
def sf_map():
    return read_map(MAP_FILE)


def sidewalk_axis(layers, segment_id: str) -> tuple[np.ndarray, np.ndarray]:
    """End points of the long axis of a sidewalk's oriented bounding box, 3 m in from each end."""
    poly = layers.gdf.loc[layers.gdf["segment_id"] == segment_id, "geometry"].iloc[0]
    corners = np.asarray(shapely.oriented_envelope(poly).exterior.coords)[:4]
    edges = np.roll(corners, -1, axis=0) - corners
    k = int(np.argmin(np.hypot(*edges.T)))  # a short side
    a = corners[k] + edges[k] / 2
    b = corners[(k + 2) % 4] + edges[(k + 2) % 4] / 2
    u = (b - a) / np.hypot(*(b - a))
    return a + 3 * u, b - 3 * u


def write_sf_walk(folder, layers, seed: int = 0, gnss_on_opposite: bool = True, gnss_sigma_m: float = 3.0,
                  accuracy_m: float = 10.0, heading_error_deg=5.0, speed_factor: float = 1.05):
    """A walk along WALKED: GNSS pulled onto the opposite sidewalk (or not); the velocity rotated by
    ``heading_error_deg`` (degrees, or a function of time) and scaled by ``speed_factor``."""
    rng = np.random.default_rng(seed)
    a, b = sidewalk_axis(layers, WALKED)
    length = float(np.hypot(*(b - a)))
    u = (b - a) / length
    speed = 1.3
    duration = length / speed
    centroids = layers.layer("sidewalk").set_index("segment_id").geometry.centroid
    across = np.array(centroids[OPPOSITE].coords[0]) - np.array(centroids[WALKED].coords[0])
    frame = LocalFrame(layers.crs)
    folder.mkdir()
    pd.DataFrame({"t": np.arange(0.0, duration, 0.55)}).to_csv(folder / "steps.csv", index=False)
    tv = np.arange(0.0, duration, 0.05)
    err = heading_error_deg(tv) if callable(heading_error_deg) else np.full(len(tv), heading_error_deg)
    err = np.radians(err)
    c, s = np.cos(err), np.sin(err)
    v = speed_factor * speed * np.array([c * u[0] - s * u[1], s * u[0] + c * u[1]])
    pd.DataFrame({"t": tv, "ve": v[0] + rng.normal(0, 0.05, len(tv)),
                  "vn": v[1] + rng.normal(0, 0.05, len(tv))}).to_csv(folder / "velocity.csv", index=False)
    tg = np.arange(0.0, duration, 1.0)
    truth = a + np.outer(speed * tg, u)
    noisy = truth + (across if gnss_on_opposite else 0.0) + rng.normal(0, gnss_sigma_m, truth.shape)
    lon, lat = frame.to_lonlat(noisy[:, 0], noisy[:, 1])
    gnss = pd.DataFrame({"t": tg, "lat": lat, "lon": lon, "accuracy_m": accuracy_m})
    gnss.to_csv(folder / "gnss.csv", index=False)
    slon, slat = frame.to_lonlat(a[0], a[1])
    heading = math.degrees(math.atan2(u[0], u[1])) % 360
    meta = {"start": {"lat": float(slat), "lon": float(slon), "heading_deg": heading, "t": 0.0}}
    (folder / "meta.json").write_text(json.dumps(meta))
    return folder, a, u, speed


@pytest.mark.parametrize("seed", [0, 1])
def test_fused_keeps_the_right_sidewalk_of_mission_street(tmp_path, monkeypatch, sf_map, seed):
    monkeypatch.setattr(settings, "cache_dir", tmp_path / "cache")
    folder, a, u, speed = write_sf_walk(tmp_path / "walk", sf_map, seed)
    session = read_session(folder)
    results = {"gnss": track_session(session, sf_map, "gnss", seed=seed)}
    results["fused"], floats = tracked_keeping_the_floats(session, sf_map, "fused", seed)

    def errors(track):
        truth = a + np.outer(speed * track["t"].to_numpy(), u)
        return np.hypot(track["x_m"] - truth[:, 0], track["y_m"] - truth[:, 1])

    gnss_err, fused_err = errors(results["gnss"].track), errors(results["fused"].track)
    assert np.median(fused_err) < 0.5 * np.median(gnss_err)
    assert (results["fused"].track["sidewalk_segment_id"] == WALKED).mean() > 0.8
    assert (results["gnss"].track["sidewalk_segment_id"] == WALKED).mean() < 0.3
    codes = rasterize_map(sf_map).codes_at(floats[:, 0], floats[:, 1])  # the clouds as the filter held them
    alive = floats[:, 4] > 0
    assert ((codes >= BUILDING) & alive).mean(axis=1).max() < 0.01
    clouds = unpack_particles(results["fused"].snapshots)  # and as stored
    assert clouds.x.shape == codes.shape == (len(results["fused"].track), 2000)
    assert np.abs(np.stack([clouds.x, clouds.y], axis=1) - floats[:, :2]).max() <= 0.05 + 1e-4  # decimetres


def phone_heading_error_deg(t: np.ndarray) -> np.ndarray:
    """A phone in a hand (docs/evaluate.md, ``phone`` profile): a 10 degree bias, a 1 deg/min drift, and a
    40 degree offset for 25 s when the phone changes hands mid-walk."""
    mid = t.max() / 2
    return 10.0 + t / 60.0 + np.where((t > mid) & (t < mid + 25.0), 40.0, 0.0)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_fused_is_not_worse_than_gnss_when_gnss_is_good(tmp_path, monkeypatch, sf_map, seed):
    # Issue 9: good fixes (2.5 m noise, 4 m reported accuracy, on the walked sidewalk) must not be
    # out-voted by a phone's biased, scaled, jumping inertial track.
    monkeypatch.setattr(settings, "cache_dir", tmp_path / "cache")
    folder, a, u, speed = write_sf_walk(
        tmp_path / "walk", sf_map, seed, gnss_on_opposite=False, gnss_sigma_m=2.5, accuracy_m=4.0,
        heading_error_deg=phone_heading_error_deg, speed_factor=1.15,
    )
    session = read_session(folder)
    results = {m: track_session(session, sf_map, m, seed=seed).track for m in ("gnss", "paper", "fused")}

    def median_error(track):
        truth = a + np.outer(speed * track["t"].to_numpy(), u)
        return float(np.median(np.hypot(track["x_m"] - truth[:, 0], track["y_m"] - truth[:, 1])))

    def on_walked(track):
        return float((track["sidewalk_segment_id"] == WALKED).mean())

    gnss, paper, fused = (results[m] for m in ("gnss", "paper", "fused"))
    assert on_walked(gnss) > 0.6  # GNSS is good here
    assert median_error(fused) <= 1.1 * median_error(gnss)  # within a walk's noise: equal or better
    assert on_walked(fused) >= on_walked(gnss)
    assert median_error(fused) <= median_error(paper)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_familiar_velocity_is_not_worse_than_gnss_when_gnss_is_good_and_the_speed_is_right(
    tmp_path, monkeypatch, sf_map, seed
):
    # The same walk with --familiar-velocity: its smooth speed reads familiar, and the track follows the
    # calm filter, which trusts the speed. 6 % fast: the bundled RoNIN's per-walk spread on the IPIN
    # trials it was trained on. (15 % fast, as above, it loses to these fixes: docs/filter.md, "A velocity
    # model fitted to the walker".)
    monkeypatch.setattr(settings, "cache_dir", tmp_path / "cache")
    folder, a, u, speed = write_sf_walk(
        tmp_path / "walk", sf_map, seed, gnss_on_opposite=False, gnss_sigma_m=2.5, accuracy_m=4.0,
        heading_error_deg=phone_heading_error_deg, speed_factor=1.06,
    )
    session = read_session(folder)
    config = RunConfig.for_mode("fused", seed=seed).with_overrides({"familiar_velocity.mode": "auto"})
    gnss = track_session(session, sf_map, "gnss", seed=seed).track
    fused = track_session(session, sf_map, config=config).track

    def median_error(track):
        truth = a + np.outer(speed * track["t"].to_numpy(), u)
        return float(np.median(np.hypot(track["x_m"] - truth[:, 0], track["y_m"] - truth[:, 1])))

    assert (fused["motion"] == "familiar").mean() > 0.5
    assert median_error(fused) <= 1.1 * median_error(gnss)
    assert (fused["sidewalk_segment_id"] == WALKED).mean() >= (gnss["sidewalk_segment_id"] == WALKED).mean()
