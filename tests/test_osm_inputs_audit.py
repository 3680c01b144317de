"""Audit of ``osmseg build``'s other OSM sources: Overpass, Nominatim (``--place``) and user files.

Overpass and Nominatim are a scripted server on loopback (never the network), answering with the
recorded response of ``tests/data/osm/overpass-sansome-pine.json`` or with what a failing server
sends. Files are cut from the bundled extract with pyosmium into ``tmp_path``. Each test failed
before the audit's fixes: osmnx retried a busy server forever, built a map without buildings from an
answer Overpass had stopped, called an empty or cut-short answer "no data", crashed on a damaged
cache entry and could leave one half-written; ``--place`` did not exist; a wrong bbox order got no
hint; XML named ``.pbf`` was refused; a file without nodes was "without highways".
"""

from __future__ import annotations

import bz2
import http.server
import json
import pathlib
import socket
import time
from collections.abc import Iterator
from pathlib import Path

import osmium
import osmnx as ox
import pytest
from loopback import loopback_server

from curbside import settings
from curbside.cli.osmseg import main as osmseg_main
from curbside.osmseg.mapio import read_map

RECORDED = Path(__file__).parent / "data" / "osm" / "overpass-sansome-pine.json"
#: The bbox of the recording, and of the files cut here: the Sansome / Pine crossroads.
BBOX = (-122.4016, 37.7914, -122.4003, 37.7924)
BBOX_ARGS = [str(v) for v in BBOX]


class _Scripted(http.server.BaseHTTPRequestHandler):
    """Overpass (POST .../interpreter, GET .../status) and Nominatim (GET /search) on loopback."""

    answers: list[tuple[int, bytes]] = []  # Overpass's answers in turn; the last one repeats
    places: bytes = b"[]"  # Nominatim's answer
    posts = 0
    status_queries = 0
    searches = 0

    def do_POST(self) -> None:  # noqa: N802 - http.server's naming
        self.rfile.read(int(self.headers.get("Content-Length", 0)))
        cls = type(self)
        status, body = cls.answers[min(cls.posts, len(cls.answers) - 1)]
        cls.posts += 1
        self._send(status, body)

    def do_GET(self) -> None:  # noqa: N802 - http.server's naming
        cls = type(self)
        if self.path.startswith("/search"):
            cls.searches += 1
            self._send(200, cls.places)
        else:
            cls.status_queries += 1
            self._send(200, b"Connected as: 1\nRate limit: 2\n2 slots available now.\n")

    def _send(self, status: int, body: bytes) -> None:
        self.send_response(status)
        self.send_header("Content-Type", "application/json")
        self.send_header("Content-Length", str(len(body)))
        self.end_headers()
        self.wfile.write(body)

    def log_message(self, *args) -> None:
        pass


@pytest.fixture
def server(tmp_path, monkeypatch) -> Iterator[type[_Scripted]]:
    """The scripted server, answering with the recording; caches in tmp_path; no bundled extract."""
    handler = type("Server", (_Scripted,), {"answers": [(200, RECORDED.read_bytes())]})
    with loopback_server(handler) as base:
        monkeypatch.setattr(ox.settings, "overpass_url", f"{base}/api")
        monkeypatch.setattr(ox.settings, "nominatim_url", f"{base}/")
        monkeypatch.setattr(settings, "cache_dir", tmp_path / "cache")
        monkeypatch.setattr(settings, "overpass_busy_waits_s", (0.0, 0.0))
        monkeypatch.setattr(settings, "default_extract_bbox", (0.0, 0.0, 1.0, 1.0))
        yield handler


def _build(tmp_path: Path, *args: str) -> tuple[int, Path]:
    out = tmp_path / "map.geojson"
    return osmseg_main(["build", *args, "-o", str(out)]), out


def _one_error(err: str) -> str:
    """The one error line of a failed command (after any WARNING lines)."""
    errors = [line for line in err.splitlines() if line.startswith("osmseg: error: ")]
    assert len(errors) == 1 and "Traceback" not in err and "internal error" not in err, err
    return errors[0]


def _cache_files() -> list[Path]:
    return [p for p in Path(settings.cache_dir).rglob("*") if p.is_file()]


# --- Overpass ---------------------------------------------------------------------------------------


@pytest.mark.parametrize("status", [429, 504])
def test_busy_overpass_is_asked_again_then_given_up_on(server, tmp_path, capsys, monkeypatch, status):
    # osmnx slept 55 s and asked again without end; here it would have got the map on the 6th try.
    monkeypatch.setattr(time, "sleep", lambda s: None)
    server.answers = [(status, b"<html>busy</html>")] * 5 + [(200, RECORDED.read_bytes())]
    code, out = _build(tmp_path, "--bbox", *BBOX_ARGS)
    line = _one_error(capsys.readouterr().err)
    assert code == 2
    assert f"server is busy (HTTP {status}" in line and "3 tries" in line and "--osm FILE" in line
    assert server.posts == 1 + len(settings.overpass_busy_waits_s)
    assert not out.exists() and not _cache_files()


def test_busy_overpass_that_recovers_builds(server, tmp_path, monkeypatch):
    monkeypatch.setattr(settings, "overpass_busy_waits_s", (0.01,))
    server.answers = [(429, b"busy"), (200, RECORDED.read_bytes())]
    code, out = _build(tmp_path, "--bbox", *BBOX_ARGS)
    assert code == 0 and out.is_file() and server.posts == 2


def test_answer_stopped_by_a_runtime_error_is_refused(server, tmp_path, capsys):
    # Overpass stopped the query: every node, half the ways. The old build wrote a map without a
    # single building (all open walkable space) and exit status 0.
    answer = json.loads(RECORDED.read_bytes())
    ways = [e for e in answer["elements"] if e["type"] == "way"]
    answer["elements"] = [e for e in answer["elements"] if e["type"] == "node"] + ways[: len(ways) // 2]
    answer["remark"] = 'runtime error: Query timed out in "query" at line 1 after 181 seconds.'
    server.answers = [(200, json.dumps(answer).encode())]
    code, out = _build(tmp_path, "--bbox", *BBOX_ARGS)
    line = _one_error(capsys.readouterr().err)
    assert code == 2
    assert "Overpass stopped the query (runtime error: Query timed out" in line and "incomplete" in line
    assert not out.exists() and not _cache_files()


@pytest.mark.parametrize(
    ("body", "problem"),
    [
        (b"", "Overpass sent an empty answer"),
        (RECORDED.read_bytes()[:5000], "Overpass sent JSON cut short or malformed"),
        (b'<?xml version="1.0"?>\n<osm version="0.6" generator="Overpass API">\n<node id="1" la',
         "Overpass sent XML or HTML"),
        (b'{"version": 0.6}', "Overpass sent JSON without a list of elements"),
    ],
    ids=["empty", "truncated-json", "truncated-xml", "no-elements"],
)  # fmt: skip
def test_broken_answer_says_what_is_wrong_with_it(server, tmp_path, capsys, body, problem):
    # Before: "no OSM buildings or highways in bbox" for the first three, an internal error (and a
    # cache entry that failed every later build) for the last.
    server.answers = [(200, body)]
    code, out = _build(tmp_path, "--bbox", *BBOX_ARGS)
    line = _one_error(capsys.readouterr().err)
    assert code == 2 and problem in line and ox.settings.overpass_url in line
    assert not out.exists() and not _cache_files()


def test_damaged_cache_entry_is_downloaded_again(server, tmp_path, caplog):
    assert _build(tmp_path, "--bbox", *BBOX_ARGS)[0] == 0
    (entry,) = _cache_files()
    entry.write_bytes(entry.read_bytes()[:500])
    # Before: "internal error: JSONDecodeError", exit 1, on every build until the file was deleted.
    code, out = _build(tmp_path, "--bbox", *BBOX_ARGS, "--overwrite")
    assert code == 0 and server.posts == 2
    assert "unreadable cache entry" in caplog.text and entry.name in caplog.text
    assert json.loads(entry.read_bytes()) == json.loads(RECORDED.read_bytes())


def test_cached_answer_asks_no_server(server, tmp_path):
    _build(tmp_path, "--bbox", *BBOX_ARGS)
    queries = server.status_queries
    # Before, a cached build still asked for the server's status: up to 5 s lost on a dead network.
    assert _build(tmp_path, "--bbox", *BBOX_ARGS, "--overwrite")[0] == 0
    assert server.status_queries == queries and server.posts == 1


def test_ctrl_c_while_the_answer_is_cached_leaves_no_entry(server, tmp_path, capsys):
    cache_root = Path(settings.cache_dir)
    write_bytes = pathlib.Path.write_bytes

    def interrupting(original):
        def write(self: Path, data, *args, **kwargs):
            if cache_root in self.parents:
                data = data.encode() if isinstance(data, str) else data
                write_bytes(self, data[: len(data) // 2])
                raise KeyboardInterrupt
            return original(self, data, *args, **kwargs)

        return write

    with pytest.MonkeyPatch.context() as patch:
        for name in ("write_bytes", "write_text"):
            patch.setattr(pathlib.Path, name, interrupting(getattr(pathlib.Path, name)))
        code, out = _build(tmp_path, "--bbox", *BBOX_ARGS)
    assert code == 130 and "interrupted" in capsys.readouterr().err
    # osmnx wrote its cache file in place: half of it stayed, and every later build crashed on it.
    assert not out.exists() and not _cache_files()
    assert _build(tmp_path, "--bbox", *BBOX_ARGS)[0] == 0 and server.posts == 2


# --- Nominatim: --place -----------------------------------------------------------------------------


def _place(osm_type: str, bbox: tuple[float, float, float, float], name: str) -> bytes:
    west, south, east, north = bbox
    return json.dumps([{
        "osm_type": osm_type, "display_name": name, "lat": str((south + north) / 2),
        "lon": str((west + east) / 2), "boundingbox": [str(south), str(north), str(west), str(east)],
    }]).encode()  # fmt: skip


def test_place_name_builds_its_bounding_box(server, tmp_path, capsys):
    server.places = _place("relation", BBOX, "Sansome and Pine, San Francisco")
    code, out = _build(tmp_path, "--place", "Sansome and Pine")
    assert code == 0, capsys.readouterr().err
    assert "--place 'Sansome and Pine' is Sansome and Pine, San Francisco: --bbox -122.4016000" in (
        capsys.readouterr().out
    )
    assert read_map(out).meta["bbox"] == pytest.approx(BBOX)
    assert server.searches == 1 and server.posts == 1
    # Looked up once: the answer is cached like Overpass's.
    assert _build(tmp_path, "--place", "Sansome and Pine", "--overwrite")[0] == 0
    assert server.searches == 1


@pytest.mark.parametrize(
    ("answer", "problem"),
    [
        (b"[]", "Nominatim knows no place of that name"),
        (_place("node", (-122.3937, 37.7955, -122.3937, 37.7955), "Ferry Building"),
         "is a point, not an area (Ferry Building, at -122.39370 37.79550); give the area around it, e.g. "
         "--bbox -122.39654 37.79325 -122.39086 37.79775"),
        (_place("relation", (-124.48, 32.53, -114.13, 42.01), "California"),
         "--place 'Somewhere': area 964,324.4 km^2 is over the 25 km^2 limit"),
        (b"<html>502</html>", "Nominatim sent XML or HTML"),
    ],
    ids=["nothing", "point", "too-large", "not-json"],
)  # fmt: skip
def test_place_that_is_no_usable_area_is_one_line(server, tmp_path, capsys, answer, problem):
    server.places = answer
    code, out = _build(tmp_path, "--place", "Somewhere")
    line = _one_error(capsys.readouterr().err)
    assert code == 2 and problem in line, line
    assert not out.exists() and server.posts == 0


def test_place_without_network_is_one_line(server, tmp_path, capsys, monkeypatch):
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        port = sock.getsockname()[1]
    monkeypatch.setattr(ox.settings, "nominatim_url", f"http://127.0.0.1:{port}/")
    code, out = _build(tmp_path, "--place", "Union Square, San Francisco")
    line = _one_error(capsys.readouterr().err)
    assert code == 2 and "cannot reach the geocoder Nominatim" in line and "--osm FILE" in line
    assert not out.exists()


# --- --bbox -----------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("given", "kind"),
    [
        ("37.79 -122.40 37.80 -122.39", "latitude first"),
        ("-122.40 -122.39 37.79 37.80", "W E S N"),
        ("37.79 37.80 -122.40 -122.39", "Nominatim's order"),
        ("-122.39 37.80 -122.40 37.79", "west < east"),
    ],
)
def test_bbox_in_a_wrong_order_gets_the_right_one(tmp_path, capsys, given, kind):
    code, out = _build(tmp_path, "--bbox", *given.split())
    line = _one_error(capsys.readouterr().err)
    assert code == 2 and kind in line and line.endswith("--bbox -122.4 37.79 -122.39 37.8"), line
    assert not out.exists()


def test_too_large_bbox_says_the_limit_and_why(tmp_path, capsys):
    code, _ = _build(tmp_path, "--bbox", "-122.55", "37.70", "-122.35", "37.83")
    line = _one_error(capsys.readouterr().err)
    assert code == 2 and "over the 25 km^2 limit (settings.max_bbox_area_km2)" in line
    assert "Overpass" in line and "split it" in line


# --- files ------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def sansome(tmp_path_factory) -> Path:
    """The Sansome / Pine crossroads cut from the bundled extract (complete ways, with <bounds>)."""
    west, south, east, north = BBOX
    inside: set[int] = set()
    ways: set[int] = set()
    for obj in osmium.FileProcessor(str(settings.default_osm_file), osmium.osm.NODE | osmium.osm.WAY):
        if obj.is_node() and west <= obj.location.lon <= east and south <= obj.location.lat <= north:
            inside.add(obj.id)
        elif obj.is_way() and any(n.ref in inside for n in obj.nodes):
            ways.add(obj.id)
            inside.update(n.ref for n in obj.nodes)
    path = tmp_path_factory.mktemp("osm") / "sansome.osm"
    header = osmium.io.Header()
    header.add_box(osmium.osm.Box(osmium.osm.Location(west, south), osmium.osm.Location(east, north)))
    with osmium.SimpleWriter(str(path), header=header) as writer:
        for obj in osmium.FileProcessor(str(settings.default_osm_file), osmium.osm.NODE | osmium.osm.WAY):
            if (obj.is_node() and obj.id in inside) or (obj.is_way() and obj.id in ways):
                writer.add(obj)
    assert path.stat().st_size < 100_000
    return path


def _rewrite(src: Path, dst: Path, *, nodes: bool = True) -> Path:
    """``src`` written again by osmium (the format from ``dst``'s name), optionally without nodes."""
    reader = osmium.io.Reader(str(src))
    header = reader.header()
    reader.close()
    with osmium.SimpleWriter(str(dst), header=header) as writer:
        for obj in osmium.FileProcessor(str(src)):
            if nodes or not obj.is_node():
                writer.add(obj)
    return dst


@pytest.mark.parametrize("disguise", ["xml-named.osm.pbf", "pbf-named.osm", "gzip-named.osm.bz2"])
def test_file_whose_name_misleads_is_read_by_its_content(sansome, tmp_path, caplog, disguise):
    real = {"xml-named.osm.pbf": "osm", "pbf-named.osm": "osm.pbf", "gzip-named.osm.bz2": "osm.gz"}[disguise]
    path = tmp_path / disguise
    path.write_bytes(_rewrite(sansome, tmp_path / f"real.{real}").read_bytes())
    code, out = _build(tmp_path, "--osm", str(path))
    assert code == 0  # before: "not a readable OSM file (PBF error: invalid BlobHeader size ...)"
    assert "not the" in caplog.text and "its name says" in caplog.text
    reference = osmseg_main(["build", "--osm", str(sansome), "-o", str(tmp_path / "reference.geojson")])
    assert reference == 0
    assert len(read_map(out).gdf) == len(read_map(tmp_path / "reference.geojson").gdf)


@pytest.mark.parametrize(
    ("name", "problem"),
    [
        ("no-nodes.osm", "its 94 highway and building ways refer to nodes the file lacks"),
        ("truncated.osm.bz2", "it ends early: an interrupted download?"),
        ("empty.osm.pbf", "is empty (0 bytes)"),
        ("folder.osm.pbf", "is a folder, not an OSM file"),
    ],
)
def test_bad_file_says_what_is_wrong_with_it(sansome, tmp_path, capsys, name, problem):
    path = tmp_path / name
    if name == "no-nodes.osm":  # a simple-strategy extract at its worst: every way, none of its nodes
        _rewrite(sansome, path, nodes=False)
    elif name == "truncated.osm.bz2":
        data = bz2.compress(sansome.read_bytes())
        path.write_bytes(data[: len(data) // 2])
    elif name == "empty.osm.pbf":
        path.touch()
    else:
        path.mkdir()
    code, out = _build(tmp_path, "--osm", str(path))
    line = _one_error(capsys.readouterr().err)
    assert code == 2 and line.startswith(f"osmseg: error: {path}: ") and problem in line, line
    assert not out.exists() and path.exists()


# --- --help -----------------------------------------------------------------------------------------


def test_help_says_where_the_data_comes_from(capsys):
    with pytest.raises(SystemExit):
        osmseg_main(["build", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    for needed in ("--place NAME", "nothing is downloaded", "Overpass API", "Nominatim",
                   f"{settings.cache_dir}/overpass", "CURBSIDE_CACHE_DIR", "longitude first",
                   settings.osm_attribution, "credit it"):  # fmt: skip
        assert needed in text, needed
