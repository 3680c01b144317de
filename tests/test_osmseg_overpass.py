"""osmseg build through Overpass: a recorded response served on loopback, never the network."""

from __future__ import annotations

import http.server
import socket
import time
from collections.abc import Iterator
from pathlib import Path

import osmnx as ox
import pytest
import shapely
from loopback import loopback_server

from curbside import settings
from curbside.cli.osmseg import main as osmseg_main
from curbside.osmseg import overpass as overpass_module
from curbside.osmseg.build import build_map
from curbside.osmseg.mapio import CLASSES

RECORDED = Path(__file__).parent / "data" / "osm" / "overpass-sansome-pine.json"
#: The bbox the recording was made for (tests/data/osm/make_fixtures.py).
BBOX = (-122.4016, 37.7914, -122.4003, 37.7924)


class _Handler(http.server.BaseHTTPRequestHandler):
    body = b""
    status = 200
    requests = 0

    def do_POST(self) -> None:  # noqa: N802 - http.server's naming
        length = int(self.headers.get("Content-Length", 0))
        self.rfile.read(length)
        type(self).requests += 1
        self.send_response(self.status)
        self.send_header("Content-Type", "application/json")
        self.send_header("Content-Length", str(len(self.body)))
        self.end_headers()
        self.wfile.write(self.body)

    def log_message(self, *args) -> None:
        pass


@pytest.fixture
def overpass(tmp_path, monkeypatch) -> Iterator[type[_Handler]]:
    """A loopback Overpass serving the recording; osmnx and curbside caches in tmp_path."""
    handler = type("Recorded", (_Handler,), {"body": RECORDED.read_bytes(), "status": 200, "requests": 0})
    with loopback_server(handler) as base:
        monkeypatch.setattr(ox.settings, "overpass_url", f"{base}/api")
        monkeypatch.setattr(ox.settings, "overpass_rate_limit", False)
        monkeypatch.setattr(ox.settings, "cache_folder", ox.settings.cache_folder)
        monkeypatch.setattr(ox.settings, "use_cache", ox.settings.use_cache)
        monkeypatch.setattr(settings, "cache_dir", tmp_path / "cache")
        # Pretend the bundled extract does not cover this bbox, so the build must ask Overpass.
        monkeypatch.setattr(settings, "default_extract_bbox", (0.0, 0.0, 1.0, 1.0))
        yield handler


def test_overpass_build_matches_file_build(overpass):
    via_overpass = build_map(BBOX)
    assert overpass.requests == 1
    assert via_overpass.meta["source"] == "overpass"
    assert set(via_overpass.gdf["class"]) == set(CLASSES)
    # The same elements read from the bundled file give the same map.
    from_file = build_map(BBOX, settings.default_osm_file)
    for cls in CLASSES:
        a, b = via_overpass.union(cls), from_file.union(cls)
        assert shapely.symmetric_difference(a, b).area < 0.01 * max(a.area, 1.0), cls


def test_overpass_response_is_cached(overpass):
    build_map(BBOX)
    build_map(BBOX)
    assert overpass.requests == 1
    assert any((settings.cache_dir / "overpass").iterdir())


def test_overpass_cli(overpass, tmp_path, capsys):
    out = tmp_path / "map.geojson"
    bbox = [str(v) for v in BBOX]
    assert osmseg_main(["build", "--bbox", *bbox, "-o", str(out)]) == 0
    assert out.is_file()
    assert "overpass" in capsys.readouterr().out


def test_overpass_empty_area(overpass, tmp_path, capsys):
    overpass.body = b'{"version":0.6,"elements":[]}'
    out = tmp_path / "map.geojson"
    status = osmseg_main(["build", "--bbox", "-122.5", "37.70", "-122.499", "37.701", "-o", str(out)])
    err = capsys.readouterr().err
    assert status == 2
    assert "no OSM" in err and len(err.strip().splitlines()) == 1
    assert not out.exists()


def test_overpass_unreachable(overpass, tmp_path, capsys, monkeypatch):
    # A loopback port with no server behind it.
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        port = sock.getsockname()[1]
    monkeypatch.setattr(ox.settings, "overpass_url", f"http://127.0.0.1:{port}/api")
    out = tmp_path / "map.geojson"
    status = osmseg_main(["build", "--bbox", *(str(v) for v in BBOX), "-o", str(out)])
    err = capsys.readouterr().err
    assert status == 2
    assert "cannot reach the Overpass server" in err and len(err.strip().splitlines()) == 1
    assert not out.exists()


def test_overpass_server_error(overpass, tmp_path, capsys):
    overpass.status = 500
    overpass.body = b"<html>overloaded</html>"
    out = tmp_path / "map.geojson"
    status = osmseg_main(["build", "--bbox", *(str(v) for v in BBOX), "-o", str(out)])
    err = capsys.readouterr().err
    assert status == 2
    assert "Overpass request failed" in err
    assert not out.exists()


def test_no_network_fails_fast_with_one_line(overpass, tmp_path, capsys, monkeypatch):
    # osmnx's defaults: rate limiting on, so an unknown server status used to cost a 60 s pause.
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        port = sock.getsockname()[1]
    monkeypatch.setattr(ox.settings, "overpass_url", f"http://127.0.0.1:{port}/api")
    monkeypatch.setattr(ox.settings, "overpass_rate_limit", True)
    out = tmp_path / "map.geojson"
    start = time.perf_counter()
    status = osmseg_main(["build", "--bbox", *(str(v) for v in BBOX), "-o", str(out)])
    elapsed_s = time.perf_counter() - start
    err = capsys.readouterr().err
    assert status == 2
    assert "cannot reach the Overpass server" in err and len(err.strip().splitlines()) == 1
    assert elapsed_s < 10.0
    assert not out.exists()


def test_silent_server_times_out_quickly(overpass, tmp_path, capsys, monkeypatch):
    # A server that accepts connections and never answers (a black-holed network).
    silent = socket.socket()
    silent.bind(("127.0.0.1", 0))
    silent.listen(8)
    monkeypatch.setattr(ox.settings, "overpass_url", f"http://127.0.0.1:{silent.getsockname()[1]}/api")
    monkeypatch.setattr(ox.settings, "overpass_rate_limit", True)
    monkeypatch.setattr(settings, "overpass_connect_timeout_s", 0.5)
    out = tmp_path / "map.geojson"
    start = time.perf_counter()
    try:
        status = osmseg_main(["build", "--bbox", *(str(v) for v in BBOX), "-o", str(out)])
    finally:
        silent.close()
    assert status == 2
    assert time.perf_counter() - start < 5.0
    assert len(capsys.readouterr().err.strip().splitlines()) == 1


def test_cached_response_is_used_when_offline(overpass, monkeypatch):
    first = build_map(BBOX)
    # Offline, the query runs with the short timeout: the cache must still answer it.
    monkeypatch.setattr(overpass_module, "overpass_reachable", lambda url, timeout_s: False)
    again = build_map(BBOX)
    assert overpass.requests == 1
    assert len(again.gdf) == len(first.gdf)


def test_caches_go_to_the_cache_folder_not_the_working_directory(overpass, tmp_path, monkeypatch):
    work = tmp_path / "work"
    work.mkdir()
    monkeypatch.chdir(work)
    build_map(BBOX)
    assert not any(work.iterdir())
    assert any((settings.cache_dir / "overpass").iterdir())
