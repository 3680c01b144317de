"""An Overpass answer is read by the reader of ``--osm`` files, through public APIs only.

Before, osmnx's private ``features._create_gdf`` turned the answer into a feature table that
``features_to_osmdata`` converted: a second reading of OSM with its own rules (a closed footway tagged
``building=roof`` became a building and no footway, the reverse of the file reader), and a node
without coordinates crashed the build with a ``KeyError``.
"""

from __future__ import annotations

import json
import tempfile
from collections.abc import Iterator
from pathlib import Path
from xml.sax.saxutils import quoteattr

import osmnx as ox
import pytest
import shapely
from loopback import loopback_server
from test_osm_inputs_audit import _build, _cache_files, _one_error, _Scripted

from curbside import settings
from curbside.osmseg import overpass
from curbside.osmseg.reader import OsmData, read_osm_file

#: (west, south, east, north) around the scene.
BBOX = (-122.4012, 37.7896, -122.3988, 37.7908)

_NODES = {
    1: (-122.4006840, 37.7900000), 2: (-122.3993160, 37.7900000),
    3: (-122.4002280, 37.7900901), 4: (-122.3997720, 37.7900901), 5: (-122.3997720, 37.7903604),
    6: (-122.4002280, 37.7903604), 7: (-122.4000570, 37.7901802), 8: (-122.3999430, 37.7901802),
    9: (-122.3999430, 37.7902703), 10: (-122.4000570, 37.7902703), 11: (-122.4008000, 37.7904500),
    12: (-122.4006000, 37.7904500), 13: (-122.4006000, 37.7905500), 14: (-122.4008000, 37.7905500),
    16: (-122.3996000, 37.7905000), 17: (-122.3994000, 37.7905000), 18: (-122.3994000, 37.7906000),
}  # fmt: skip


def _way(way_id: int, nodes: list[int], **tags: str) -> dict:
    return {"type": "way", "id": way_id, "nodes": nodes, **({"tags": tags} if tags else {})}


#: A street with a crossing node, a building relation with a courtyard, a covered walkway (a closed
#: footway that is also a roof), a pedestrian square (closed, area=yes), in Overpass's order.
ELEMENTS: list[dict] = [
    *({"type": "node", "id": i, "lat": lat, "lon": lon} for i, (lon, lat) in sorted(_NODES.items())),
    {"type": "node", "id": 15, "lat": 37.79, "lon": -122.4, "tags": {"highway": "crossing"}},
    _way(1000, [1, 15, 2], highway="residential", name="Court St"),
    _way(1001, [3, 4, 5, 6, 3]),
    _way(1002, [7, 8, 9, 10, 7]),
    _way(1003, [11, 12, 13, 14, 11], highway="footway", building="roof"),
    _way(1004, [16, 17, 18, 16], highway="pedestrian", area="yes"),
    {"type": "relation", "id": 5000, "tags": {"type": "multipolygon", "building": "yes"}, "members": [
        {"type": "way", "ref": 1001, "role": "outer"}, {"type": "way", "ref": 1002, "role": "inner"}]},
]  # fmt: skip


def _answer(elements: list[dict]) -> bytes:
    return json.dumps({"version": 0.6, "generator": "Overpass API", "elements": elements}).encode()


def _osm_xml(elements: list[dict], path: Path) -> Path:
    """The same elements as an OSM XML file (no ``<bounds>``, as an Overpass answer declares none)."""

    def tags(e: dict) -> str:
        return "".join(f"<tag k={quoteattr(k)} v={quoteattr(v)}/>" for k, v in e.get("tags", {}).items())

    lines = ['<?xml version="1.0" encoding="UTF-8"?>', '<osm version="0.6">']
    for e in elements:
        if e["type"] == "node":
            lines.append(f'<node id="{e["id"]}" lat="{e["lat"]}" lon="{e["lon"]}">{tags(e)}</node>')
        elif e["type"] == "way":
            refs = "".join(f'<nd ref="{r}"/>' for r in e["nodes"])
            lines.append(f'<way id="{e["id"]}">{refs}{tags(e)}</way>')
        else:
            members = "".join(
                f'<member type="way" ref="{m["ref"]}" role="{m["role"]}"/>' for m in e["members"]
            )
            lines.append(f'<relation id="{e["id"]}">{members}{tags(e)}</relation>')
    path.write_text("\n".join([*lines, "</osm>"]), encoding="utf-8")
    return path


@pytest.fixture
def server(tmp_path, monkeypatch) -> Iterator[type[_Scripted]]:
    """A loopback Overpass answering with :data:`ELEMENTS`; caches in tmp_path; no bundled extract."""
    handler = type("Server", (_Scripted,), {"answers": [(200, _answer(ELEMENTS))]})
    with loopback_server(handler) as base:
        monkeypatch.setattr(ox.settings, "overpass_url", f"{base}/api")
        monkeypatch.setattr(settings, "cache_dir", tmp_path / "cache")
        monkeypatch.setattr(settings, "default_extract_bbox", (0.0, 0.0, 1.0, 1.0))
        yield handler


def _rows(data: OsmData, table: str) -> list[tuple[str, dict, shapely.Geometry]]:
    gdf = getattr(data, table)
    tags = gdf.drop(columns=["osm_id", "geometry"]).to_dict("records")
    rows = zip(gdf["osm_id"].astype(str), tags, gdf.geometry.values, strict=True)
    return sorted([(i, {k: v for k, v in t.items() if v is not None}, g) for i, t, g in rows], key=str)


def test_answer_reads_like_the_same_elements_in_a_file(server, tmp_path, monkeypatch):
    def private(*args, **kwargs):
        raise AssertionError("osmnx's feature parser was used")

    monkeypatch.setattr(ox.features, "_create_gdf", private)
    monkeypatch.setattr(ox, "features_from_xml", private)
    via_overpass = overpass.fetch_overpass(BBOX)
    from_file = read_osm_file(_osm_xml(ELEMENTS, tmp_path / "scene.osm"), BBOX)
    assert (via_overpass.source, via_overpass.bounds, via_overpass.crs) == ("overpass", BBOX, from_file.crs)
    for table in ("ways", "areas", "nodes"):
        got, want = _rows(via_overpass, table), _rows(from_file, table)
        assert [r[:2] for r in got] == [r[:2] for r in want], table
        assert shapely.equals_exact([r[2] for r in got], [r[2] for r in want], tolerance=0.0).all(), table
    # The covered walkway is a footway (as from a file), the courtyard a hole in the relation's building.
    assert [r[0] for r in _rows(via_overpass, "ways")] == ["1000", "1003", "1004"]
    assert [r[0] for r in _rows(via_overpass, "areas")] == ["r5000"]
    assert len(via_overpass.areas.geometry.iloc[0].interiors) == 1


def test_cache_entry_of_an_earlier_version_is_read(server, monkeypatch):
    first = overpass.fetch_overpass(BBOX)
    (entry,) = _cache_files()
    assert json.loads(entry.read_bytes())["elements"] == ELEMENTS  # the answer as received
    monkeypatch.setattr(overpass, "overpass_reachable", lambda url, timeout_s: False)
    again = overpass.fetch_overpass(BBOX)
    assert server.posts == 1
    assert all(_rows(first, t)[:2] == _rows(again, t)[:2] for t in ("ways", "areas", "nodes"))


@pytest.mark.parametrize(
    ("element", "problem"),
    [
        ({"type": "node", "id": 1, "lon": -122.4}, "node 1 without its coordinates (lat, lon)"),
        ({"type": "way", "id": 2, "nodes": [1, "x"]}, "way 2 without its list of node ids"),
        ({"type": "relation", "id": 3, "members": [{"type": "way", "role": "outer"}]},
         "relation 3 without its list of members"),
        ({"type": "way", "id": "w4", "nodes": [1]}, "a way without a whole-number id"),
        ({"type": "node", "id": 5, "lat": 37.79, "lon": -122.4, "tags": {"name": "a\x00b"}},
         "node 5 with a tag or role that is not text"),
        ({"type": "node", "id": 6, "lat": 37.79, "lon": -122.4, "tags": {"name": "x" * 1025}},
         "node 6 with a tag or role that is not text of at most 1024 bytes"),
        ([1, 2], "an element that is not a JSON object"),
    ],
    ids=["node-without-lat", "way-with-text-ref", "member-without-ref", "text-id", "nul", "too-long", "list"],
)  # fmt: skip
def test_malformed_element_is_one_line_and_not_cached(server, tmp_path, capsys, element, problem):
    # Before: osmnx's parser raised KeyError (internal error, exit 1) or the map was built; a NUL in a
    # tag would now crash libosmium's writer (the process aborts), so it is refused before.
    server.answers = [(200, _answer([*ELEMENTS, element]))]
    code, out = _build(tmp_path, "--bbox", *(str(v) for v in BBOX))
    line = _one_error(capsys.readouterr().err)
    assert code == 2 and f"Overpass sent {problem}" in line and line.endswith("; try again")
    assert not out.exists() and not _cache_files()


def test_elements_of_other_types_are_skipped():
    assert overpass.element_problem({"type": "area", "id": 3600000001}) is None
    assert all(overpass.element_problem(e) is None for e in ELEMENTS)


def test_answer_without_anything_the_reader_uses(server, tmp_path, capsys):
    # Only a traffic-signals node: elements, but no highway way, building or crossing.
    signals = {"type": "node", "id": 1, "lat": 37.79, "lon": -122.4, "tags": {"highway": "traffic_signals"}}
    server.answers = [(200, _answer([signals]))]
    code, out = _build(tmp_path, "--bbox", *(str(v) for v in BBOX))
    line = _one_error(capsys.readouterr().err)
    assert code == 2 and "overpass: no OSM buildings or highways in bbox" in line
    assert "curbside-overpass-" not in line  # the temporary file is not named


def test_unwritable_temporary_folder_is_one_line(server, tmp_path, capsys, monkeypatch):
    # The answer is read through a temporary .osm.pbf; a TMPDIR that does not exist was a traceback.
    missing = tmp_path / "no-such-tmp"
    monkeypatch.setattr(tempfile, "tempdir", str(missing))
    code, out = _build(tmp_path, "--bbox", *(str(v) for v in BBOX))
    line = _one_error(capsys.readouterr().err)
    assert code == 2 and str(missing) in line and "TMPDIR" in line
    assert not out.exists()


def test_a_full_temporary_folder_is_one_line(server, tmp_path, capsys, monkeypatch):
    # libosmium's writer raises RuntimeError when the disk fills: it was an internal error.
    def full(elements, path):
        raise RuntimeError("Write failed: No space left on device")

    monkeypatch.setattr(overpass, "write_osm_file", full)
    code, out = _build(tmp_path, "--bbox", *(str(v) for v in BBOX))
    line = _one_error(capsys.readouterr().err)
    assert code == 2 and "No space left on device" in line and "TMPDIR" in line
    assert not out.exists()
