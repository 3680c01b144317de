"""osmseg build on a corpus of real OSM extracts: every file format, cut every usual way.

The corpus (``tests/data/osm/corpus``, made by ``make_corpus.py``) holds pieces of downtown San
Francisco, central Helsinki and Kotka in ``.osm``, ``.osm.gz``, ``.osm.bz2`` and ``.osm.pbf``, cut with
complete ways (ways run on past the bounds) or simply (ways refer to nodes the file lacks), with and
without ``<bounds>``, with building relations whose members are partly missing.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import shapely

from curbside.cli.osmseg import main as osmseg_main
from curbside.osmseg.build import build_map
from curbside.osmseg.mapio import CLASSES, read_map
from curbside.osmseg.reader import read_osm_file

CORPUS = Path(__file__).parent / "data" / "osm" / "corpus"
FILES = sorted(p for p in CORPUS.iterdir() if p.name.endswith((".osm", ".osm.gz", ".osm.bz2", ".osm.pbf")))


def test_corpus_covers_every_format_and_cut():
    suffixes = {p.name.split(".", 1)[1] for p in FILES}
    assert suffixes == {"osm", "osm.gz", "osm.bz2", "osm.pbf"}
    bounds = [read_osm_file(p).bounds for p in FILES]
    assert any(b is None for b in bounds) and any(b is not None for b in bounds)


@pytest.mark.parametrize("path", FILES, ids=lambda p: p.name)
def test_corpus_file_builds_a_clean_map(path: Path):
    declared = read_osm_file(path).bounds
    layers = build_map(osm_file=path)
    gdf = layers.gdf
    geoms = gdf.geometry.values
    assert {"building", "street", "sidewalk"} <= set(gdf["class"])
    assert shapely.is_valid(geoms).all() and (shapely.get_type_id(geoms) == 3).all()
    # No two buildings overlap; the classes are disjoint.
    buildings = layers.layer("building").geometry.values
    assert shapely.area(buildings).sum() == pytest.approx(shapely.union_all(buildings).area, rel=1e-6)
    unions = {cls: layers.union(cls) for cls in CLASSES}
    total = sum(u.area for u in unions.values())
    assert shapely.union_all(list(unions.values())).area == pytest.approx(total, rel=1e-4)
    segment_ids = gdf.loc[gdf["class"] == "sidewalk", "segment_id"]
    assert segment_ids.notna().all() and segment_ids.is_unique
    if declared is not None:
        west, south, east, north = gdf.to_crs(4326).total_bounds
        assert np.all(np.array([west, south]) >= np.array(declared[:2]) - 1e-6)
        assert np.all(np.array([east, north]) <= np.array(declared[2:]) + 1e-6)


def test_corpus_file_through_the_cli(tmp_path, capsys):
    path = CORPUS / "helsinki-centre.osm.pbf"
    out = tmp_path / "helsinki.geojson"
    assert osmseg_main(["build", "--osm", str(path), "-o", str(out)]) == 0
    assert "building" in capsys.readouterr().out
    layers = read_map(out)
    assert layers.meta["bbox"] == pytest.approx(read_osm_file(path).bounds, abs=1e-7)
