"""The reader's streaming pass: a ``--bbox`` checked against the file's header before any element is
read, and each way's nodes walked once."""

from __future__ import annotations

import logging
from collections import Counter
from pathlib import Path

import osmium
import pytest

from curbside import settings
from curbside.cli.osmseg import main as osmseg_main
from curbside.errors import CurbsideInputError
from curbside.osmseg import build, reader
from curbside.osmseg.reader import declared_bounds, read_osm_file

OSM_DATA = Path(__file__).parent / "data" / "osm"
PAST_BOUNDS = OSM_DATA / "past-bounds.osm"
SOMA_CUT = OSM_DATA / "corpus" / "sf-soma-cut.osm.pbf"


@pytest.fixture
def no_reading(monkeypatch) -> list[str]:
    """Make every read of a file's elements fail the test; returns what was asked to be read."""
    asked: list[str] = []

    def refuse(path, *args, **kwargs):
        asked.append(str(path))
        raise AssertionError(f"{path} was read")

    monkeypatch.setattr(build, "read_osm_file", refuse)
    monkeypatch.setattr(reader, "_read_elements", refuse)
    return asked


def test_declared_bounds_come_from_the_header():
    assert declared_bounds(SOMA_CUT) == pytest.approx((-122.3990, 37.7855, -122.3955, 37.7880))
    assert declared_bounds(settings.default_osm_file) == pytest.approx(settings.default_extract_bbox)
    assert declared_bounds(OSM_DATA / "corpus" / "sf-union-square-nobounds.osm.gz") is None
    assert declared_bounds(PAST_BOUNDS) == read_osm_file(PAST_BOUNDS).bounds


def test_declared_bounds_of_a_bad_file_is_a_one_line_error(tmp_path):
    with pytest.raises(CurbsideInputError, match="no such OSM file"):
        declared_bounds(tmp_path / "missing.osm")
    (tmp_path / "page.osm").write_text("<html><body>not osm</body></html>")
    with pytest.raises(CurbsideInputError, match="not a readable OSM file"):
        declared_bounds(tmp_path / "page.osm")


def test_bbox_outside_the_bounds_is_refused_before_reading(no_reading):
    west, south, east, north = settings.default_extract_bbox
    outside = (east + 0.001, south, east + 0.002, north)
    with pytest.raises(CurbsideInputError, match="lies outside the bounds the file declares"):
        build.build_map(outside, settings.default_osm_file)
    assert no_reading == []


def test_bbox_outside_the_bounds_cli_reads_nothing(no_reading, tmp_path, capsys):
    west, south, east, north = declared_bounds(PAST_BOUNDS)
    out = tmp_path / "map.geojson"
    bbox = [str(v) for v in (west - 0.002, south, west - 0.001, north)]
    assert osmseg_main(["build", "--osm", str(PAST_BOUNDS), "--bbox", *bbox, "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "lies outside the bounds the file declares" in err
    assert no_reading == [] and not out.exists()


def test_bbox_partly_outside_warns_before_reading(monkeypatch, caplog):
    west, south, east, north = declared_bounds(PAST_BOUNDS)
    asked = (west + 0.5 * (east - west), south, east + 0.5 * (east - west), north)
    warned_before_read: list[bool] = []

    def spy(path, *args, **kwargs):
        warned_before_read.append(any("reaches past the bounds" in r.getMessage() for r in caplog.records))
        return read_osm_file(path, *args, **kwargs)

    monkeypatch.setattr(build, "read_osm_file", spy)
    with caplog.at_level(logging.WARNING):
        layers = build.build_map(asked, PAST_BOUNDS)
    assert warned_before_read == [True]
    assert layers.meta["bbox"] == pytest.approx([asked[0], south, east, north], abs=1e-7)


class _CountingWay:
    """A way whose node list counts how often it is walked."""

    def __init__(self, way: osmium.osm.Way, walks: Counter) -> None:
        self._way, self._walks = way, walks

    def __getattr__(self, name: str):
        return getattr(self._way, name)

    @property
    def nodes(self):
        self._walks[self._way.id] += 1
        return self._way.nodes


class _CountingProcessor:
    """``osmium.FileProcessor`` handing out :class:`_CountingWay` in place of ways."""

    walks: Counter = Counter()

    def __init__(self, *args, **kwargs) -> None:
        self._processor = _REAL_PROCESSOR(*args, **kwargs)
        self.header = self._processor.header

    def with_locations(self, *args, **kwargs) -> _CountingProcessor:
        self._processor.with_locations(*args, **kwargs)
        return self

    def __iter__(self):
        for obj in self._processor:
            yield _CountingWay(obj, self.walks) if obj.is_way() else obj


_REAL_PROCESSOR = osmium.FileProcessor


def test_each_way_is_walked_once(monkeypatch):
    # A simple cut: highways and building rings with missing nodes, whose nodes were walked twice
    # (once to find the missing ones, once for their coordinates).
    _CountingProcessor.walks = Counter()
    monkeypatch.setattr(reader.osmium, "FileProcessor", _CountingProcessor)
    data = read_osm_file(SOMA_CUT)
    walks = _CountingProcessor.walks
    assert len(data.ways) > 0 and len(walks) > 0
    assert max(walks.values()) == 1, walks.most_common(3)
