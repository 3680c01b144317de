"""curbside.cache: content keys, npz and GeoParquet entries, atomic writes, corrupt entries rebuilt."""

from __future__ import annotations

import logging
import os
import subprocess
import sys
from pathlib import Path

import geopandas as gpd
import numpy as np
import pytest
import shapely

from curbside import cache, settings
from curbside.evaluate import osmsource

OSM_DATA = Path(__file__).parent / "data" / "osm"
REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(autouse=True)
def _cache_in_tmp(tmp_path, monkeypatch):
    monkeypatch.setattr(settings, "cache_dir", tmp_path / "cache")


def test_content_key_covers_content_and_order(tmp_path):
    a, b = tmp_path / "a.osm", tmp_path / "b.osm"
    a.write_text("same")
    b.write_text("same")
    assert cache.content_key(a) == cache.content_key(b)  # a file counts by content, not name
    b.write_text("other")
    assert cache.content_key(a) != cache.content_key(b)
    assert cache.content_key("ab", "c") != cache.content_key("a", "bc")
    assert cache.content_key(np.arange(3)) != cache.content_key(np.arange(3.0))
    assert len(cache.content_key(1.5)) == 64


def test_arrays_are_built_once_then_read():
    builds = []

    def build():
        builds.append(1)
        return {"codes": np.arange(6, dtype=np.uint8).reshape(2, 3), "ids": np.array(["w1-0-L", "w2-1-R"])}

    first = cache.cached_arrays("rasters", "k1", build, required=("codes",))
    second = cache.cached_arrays("rasters", "k1", build, required=("codes",))
    assert len(builds) == 1
    np.testing.assert_array_equal(first["codes"], second["codes"])
    assert second["ids"].tolist() == ["w1-0-L", "w2-1-R"]
    assert cache.entry_path("rasters", "k1", ".npz").parent == settings.cache_dir / "rasters"


@pytest.mark.parametrize("damage", ["garbage", "truncated", "missing-array"])
def test_corrupt_array_entry_is_rebuilt_with_a_warning(damage, caplog):
    cache.save_arrays("rasters", "k", {"codes": np.ones((50, 50), np.uint8), "x0": np.float64(3.0)})
    path = cache.entry_path("rasters", "k", ".npz")
    if damage == "garbage":
        path.write_bytes(b"not a zip file")
    elif damage == "truncated":
        path.write_bytes(path.read_bytes()[:40])
    else:
        cache.save_arrays("rasters", "k", {"x0": np.float64(3.0)})
    with caplog.at_level(logging.WARNING, logger="curbside.cache"):
        arrays = cache.cached_arrays(
            "rasters", "k", lambda: {"codes": np.zeros(2, np.uint8)}, required=("codes",)
        )
    assert arrays["codes"].tolist() == [0, 0]
    assert "rebuilding unreadable cache entry" in caplog.text
    assert cache.load_arrays("rasters", "k", required=("codes",))["codes"].tolist() == [0, 0]


def test_object_arrays_are_refused():
    with pytest.raises(TypeError, match="pickle"):
        cache.save_arrays("rasters", "k", {"bad": np.array([{"a": 1}], dtype=object)})


def test_pickled_npz_is_never_loaded(caplog):
    path = cache.entry_path("rasters", "k", ".npz")
    path.parent.mkdir(parents=True)
    np.savez(path, evil=np.array([object()], dtype=object))
    with caplog.at_level(logging.WARNING, logger="curbside.cache"):
        assert cache.load_arrays("rasters", "k") is None
    assert "pickled" in caplog.text


def test_frames_round_trip_as_geoparquet():
    frame = gpd.GeoDataFrame(
        {"height_m": [12.0, 30.5], "osm_id": ["w1", "r2"]},
        geometry=[shapely.box(0, 0, 1, 1), shapely.box(2, 2, 3, 4)],
        crs="EPSG:32610",
    )
    cache.save_frames("osmsource", "k", {"buildings": frame, "empty": frame.iloc[:0]})
    folder = cache.entry_path("osmsource", "k", "")
    assert sorted(p.name for p in folder.iterdir()) == ["buildings.parquet", "empty.parquet"]
    back = cache.load_frames("osmsource", "k", ("buildings", "empty"))
    assert back["buildings"].crs == frame.crs
    assert back["buildings"]["height_m"].tolist() == [12.0, 30.5]
    assert shapely.equals(back["buildings"].geometry.values, frame.geometry.values).all()
    assert len(back["empty"]) == 0


def test_corrupt_frames_entry_is_rebuilt(caplog):
    frame = gpd.GeoDataFrame({"v": [1]}, geometry=[shapely.Point(0, 0)], crs="EPSG:32610")
    cache.save_frames("osmsource", "k", {"t": frame})
    (cache.entry_path("osmsource", "k", "") / "t.parquet").write_bytes(b"PAR1 broken")
    with caplog.at_level(logging.WARNING, logger="curbside.cache"):
        out = cache.cached_frames("osmsource", "k", lambda: {"t": frame.assign(v=[2])}, ("t",))
    assert out["t"]["v"].tolist() == [2]
    assert "rebuilding" in caplog.text


def test_unwritable_cache_costs_only_the_rebuild(tmp_path, monkeypatch, caplog):
    blocker = tmp_path / "not-a-folder"
    blocker.write_text("a file where the cache folder should be")
    monkeypatch.setattr(settings, "cache_dir", blocker)
    with caplog.at_level(logging.WARNING, logger="curbside.cache"):
        arrays = cache.cached_arrays("rasters", "k", lambda: {"a": np.arange(2)})
    assert arrays["a"].tolist() == [0, 1]
    assert "could not write cache entry" in caplog.text


def test_osmsource_uses_the_osmseg_reader_and_caches_geoparquet():
    source = osmsource.load_osm(OSM_DATA / "crossroads-mapped-sidewalks.osm")
    assert len(source.buildings) == 4 and len(source.roads) == 2
    assert set(source.footways["kind"]) == {"sidewalk", "crossing"}
    assert source.roads["name"].map(type).eq(str).all()
    entries = list((settings.cache_dir / "osmsource").iterdir())
    assert len(entries) == 1 and {p.suffix for p in entries[0].iterdir()} == {".parquet"}
    assert not list(settings.cache_dir.rglob("*.pkl"))
    again = osmsource.load_osm(OSM_DATA / "crossroads-mapped-sidewalks.osm")
    assert shapely.equals(again.footways.geometry.values, source.footways.geometry.values).all()
    assert again.buildings.crs == source.buildings.crs


def test_osmsource_cache_key_includes_its_config():
    path = OSM_DATA / "crossroads-mapped-sidewalks.osm"
    default = osmsource.load_osm(path)
    primary_only = osmsource.load_osm(path, osmsource.OsmSourceConfig(road_classes=("primary",)))
    assert len(list((settings.cache_dir / "osmsource").iterdir())) == 2
    assert len(primary_only.roads) < len(default.roads)
    with pytest.raises(ValueError, match="heights"):
        osmsource.OsmSourceConfig(level_height_m=0.0)


def test_osmsource_heights_use_the_shared_unit_parser():
    source = osmsource.load_osm(OSM_DATA / "feet-widths.osm")
    assert sorted(source.buildings["height_m"].round(4)) == [1.9812, 91.44]


def test_default_cache_folder_is_the_users_and_the_environment_overrides_it(tmp_path):
    code = "from curbside import settings; print(settings.cache_dir)"
    env = {k: v for k, v in os.environ.items() if k != "CURBSIDE_CACHE_DIR"}
    env["XDG_CACHE_HOME"] = str(tmp_path / "xdg")
    env["PYTHONPATH"] = str(REPO)
    run = [sys.executable, "-c", code]
    default = subprocess.run(run, env=env, capture_output=True, text=True, check=True)
    assert Path(default.stdout.strip()) == tmp_path / "xdg" / "curbside"
    env["CURBSIDE_CACHE_DIR"] = str(tmp_path / "mine")
    chosen = subprocess.run(run, env=env, capture_output=True, text=True, check=True)
    assert Path(chosen.stdout.strip()) == tmp_path / "mine"
