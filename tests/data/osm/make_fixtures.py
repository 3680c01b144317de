"""Regenerate the osmseg test fixtures: the recorded Overpass response and the hand-written scenes.

``python tests/data/osm/make_fixtures.py`` writes ``overpass-sansome-pine.json``: every building and
highway way with a node inside :data:`BBOX` (complete, with all their nodes) and the crossing nodes
inside it, in Overpass JSON, as ``osmnx.features_from_bbox`` would receive it from a server; and the
scenes of :func:`write_scenes`, each in metres around :data:`ORIGIN`.
"""

from __future__ import annotations

import json
from pathlib import Path

import osmium

from curbside import settings

#: (west, south, east, north): the Sansome / Pine Street crossroads, downtown San Francisco.
BBOX = (-122.4016, 37.7914, -122.4003, 37.7924)
OUT = Path(__file__).with_name("overpass-sansome-pine.json")


def main() -> None:
    west, south, east, north = BBOX
    nodes: dict[int, dict] = {}
    ways = []
    for obj in osmium.FileProcessor(str(settings.default_osm_file)):
        if obj.is_node():
            nodes[obj.id] = {"type": "node", "id": obj.id, "lat": round(obj.location.lat, 7),
                             "lon": round(obj.location.lon, 7), "tags": dict(obj.tags)}
        elif obj.is_way() and ("highway" in obj.tags or "building" in obj.tags):
            refs = [n.ref for n in obj.nodes]
            inside = any(
                r in nodes and west <= nodes[r]["lon"] <= east and south <= nodes[r]["lat"] <= north
                for r in refs
            )
            if inside:
                ways.append({"type": "way", "id": obj.id, "nodes": refs, "tags": dict(obj.tags)})
    used = {r for w in ways for r in w["nodes"]}
    crossing = {
        i for i, n in nodes.items()
        if n["tags"].get("highway") == "crossing" and west <= n["lon"] <= east and south <= n["lat"] <= north
    }
    elements = []
    for i in sorted(used | crossing):
        node = dict(nodes[i])
        if not node["tags"]:
            del node["tags"]
        elements.append(node)
    elements += ways
    doc = {"version": 0.6, "generator": "curbside tests (recorded from the bundled extract)",
           "osm3s": {"timestamp_osm_base": "2026-02-21T00:00:00Z",
                     "copyright": "The data included in this document is from www.openstreetmap.org. "
                                  "The data is made available under ODbL."},
           "elements": elements}
    OUT.write_text(json.dumps(doc, separators=(",", ":")), encoding="utf-8")
    print(f"{OUT.name}: {len(elements)} elements, {OUT.stat().st_size} bytes")




# --- Hand-written scenes in metres around one origin, written as OSM XML -----------------------------

ORIGIN = (-122.4000, 37.7900)
M_PER_DEG_LAT = 111_000.0


def _lonlat(x: float, y: float) -> tuple[float, float]:
    import math

    lon0, lat0 = ORIGIN
    return lon0 + x / (M_PER_DEG_LAT * math.cos(math.radians(lat0))), lat0 + y / M_PER_DEG_LAT


class Scene:
    """Nodes at metric positions (shared when equal) and ways over them."""

    def __init__(self) -> None:
        self.nodes: dict[tuple[float, float], int] = {}
        self.node_tags: dict[int, dict[str, str]] = {}
        self.ways: list[tuple[int, list[int], dict[str, str]]] = []
        self.relations: list[tuple[int, list[tuple[int, str]], dict[str, str]]] = []
        #: (x0, y0, x1, y1) metres of the ``<bounds>`` element, if any.
        self.bounds: tuple[float, float, float, float] | None = None
        #: Nodes ways refer to but the file leaves out (as an extract cut at its bounds does).
        self.left_out: set[int] = set()

    def node(self, x: float, y: float, **tags: str) -> int:
        key = (round(x, 3), round(y, 3))
        if key not in self.nodes:
            self.nodes[key] = len(self.nodes) + 1
        nid = self.nodes[key]
        if tags:
            self.node_tags[nid] = {k.replace("__", ":"): v for k, v in tags.items()}
        return nid

    def way(self, points: list[tuple[float, float]], **tags: str) -> int:
        refs = [self.node(x, y) for x, y in points]
        wid = 1000 + len(self.ways)
        self.ways.append((wid, refs, {k.replace("__", ":"): v for k, v in tags.items()}))
        return wid

    def box(self, x0: float, y0: float, x1: float, y1: float, **tags: str) -> int:
        return self.way([(x0, y0), (x1, y0), (x1, y1), (x0, y1), (x0, y0)], **tags)

    def relation(self, members: list[tuple[int, str]], **tags: str) -> None:
        self.relations.append((5000 + len(self.relations), members, tags))

    def write(self, name: str) -> None:
        from xml.sax.saxutils import quoteattr

        lines = ['<?xml version="1.0" encoding="UTF-8"?>', '<osm version="0.6" generator="curbside tests">']
        if self.bounds is not None:
            (w, s), (e, n) = _lonlat(*self.bounds[:2]), _lonlat(*self.bounds[2:])
            lines.append(f'  <bounds minlat="{s:.7f}" minlon="{w:.7f}" maxlat="{n:.7f}" maxlon="{e:.7f}"/>')
        for (x, y), nid in sorted(self.nodes.items(), key=lambda kv: kv[1]):
            if nid in self.left_out:
                continue
            lon, lat = _lonlat(x, y)
            tags = self.node_tags.get(nid, {})
            attrs = f'id="{nid}" version="1" timestamp="2026-01-02T03:04:05Z" lat="{lat:.7f}" lon="{lon:.7f}"'
            if tags:
                lines.append(f"  <node {attrs}>")
                lines += [f"    <tag k={quoteattr(k)} v={quoteattr(v)}/>" for k, v in tags.items()]
                lines.append("  </node>")
            else:
                lines.append(f"  <node {attrs}/>")
        for wid, refs, tags in self.ways:
            lines.append(f'  <way id="{wid}" version="1" timestamp="2026-01-02T03:04:05Z">')
            lines += [f'    <nd ref="{r}"/>' for r in refs]
            lines += [f"    <tag k={quoteattr(k)} v={quoteattr(v)}/>" for k, v in tags.items()]
            lines.append("  </way>")
        for rid, members, tags in self.relations:
            lines.append(f'  <relation id="{rid}" version="1" timestamp="2026-01-02T03:04:05Z">')
            lines += [f'    <member type="way" ref="{ref}" role="{role}"/>' for ref, role in members]
            lines += [f"    <tag k={quoteattr(k)} v={quoteattr(v)}/>" for k, v in tags.items()]
            lines.append("  </relation>")
        lines.append("</osm>")
        Path(__file__).with_name(name).write_text("\n".join(lines) + "\n", encoding="utf-8")


def crossroads(mapped_sidewalks: bool) -> Scene:
    """Two residential streets crossing at the origin, a building on each corner.

    With ``mapped_sidewalks``: footway=sidewalk lines 6 m off each centreline and footway=crossing
    ways 12 m from the centre on every arm; without: highway=crossing nodes there instead.
    """
    s = Scene()
    arm, cross_at = 100.0, 12.0
    for sx in (-1, 1):
        for sy in (-1, 1):
            s.box(sx * 9, sy * 9, sx * 60, sy * 60, building="yes")
    if mapped_sidewalks:
        s.way([(-arm, 0), (0, 0), (arm, 0)], highway="residential", name="East Street")
        s.way([(0, -arm), (0, 0), (0, arm)], highway="residential", name="North Street")
        for sign in (-1, 1):
            # Sidewalks along each street, passing through the crossing ends.
            s.way([(-arm, sign * 6), (-cross_at, sign * 6), (-6, sign * 6)], highway="footway",
                  footway="sidewalk")
            s.way([(6, sign * 6), (cross_at, sign * 6), (arm, sign * 6)], highway="footway",
                  footway="sidewalk")
            s.way([(sign * 6, -arm), (sign * 6, -cross_at), (sign * 6, -6)], highway="footway",
                  footway="sidewalk")
            s.way([(sign * 6, 6), (sign * 6, cross_at), (sign * 6, arm)], highway="footway",
                  footway="sidewalk")
            s.way([(sign * cross_at, -6), (sign * cross_at, 0), (sign * cross_at, 6)], highway="footway",
                  footway="crossing", crossing="marked")
            s.way([(-6, sign * cross_at), (0, sign * cross_at), (6, sign * cross_at)], highway="footway",
                  footway="crossing", crossing="unmarked")
    else:
        for sign in (-1, 1):
            s.node(sign * cross_at, 0, highway="crossing", crossing="traffic_signals")
            s.node(0, sign * cross_at, highway="crossing", crossing="unmarked")
        s.way([(-arm, 0), (-cross_at, 0), (0, 0), (cross_at, 0), (arm, 0)], highway="residential",
              name="East Street")
        s.way([(0, -arm), (0, -cross_at), (0, 0), (0, cross_at), (0, arm)], highway="residential",
              name="North Street")
    return s


def wide_road() -> Scene:
    """One 20 m wide primary road, 120 m long, with a building 20 m off its centreline."""
    s = Scene()
    s.way([(-60, 0), (60, 0)], highway="primary", width="20", name="Wide Avenue", sidewalk="both")
    s.box(-40, 20, 40, 50, building="office")
    return s


def passage() -> Scene:
    """A station crossed by a footway through a passage, with a roof-garden path and a bus-deck
    platform, and an office with an upper-level platform."""
    s = Scene()
    s.way([(-80, -30), (80, -30)], highway="tertiary", name="Front Street")
    s.box(-40, -20, 40, 40, building="transportation", height="30")
    s.way([(0, -30), (0, -20), (0, 40), (0, 60)], highway="footway", tunnel="building_passage")
    s.way([(-30, 0), (30, 0)], highway="footway", layer="4", level="3")
    s.box(50, -20, 70, 10, building="roof")
    # Upper-level platforms: they open the station (a bus deck) but not an office building.
    s.way([(-30, 20), (30, 20)], highway="platform", layer="2", level="2")
    s.box(-40, 70, 40, 100, building="office")
    s.way([(-30, 85), (30, 85)], highway="platform", layer="2", level="2")
    return s


def relation_building() -> Scene:
    """A courtyard building mapped as a multipolygon relation (outer 40 x 30 m, inner 10 x 10 m)."""
    s = Scene()
    s.way([(-60, 0), (60, 0)], highway="residential", name="Court Street")
    outer = s.box(-20, 10, 20, 40)
    inner = s.box(-5, 20, 5, 30)
    s.relation([(outer, "outer"), (inner, "inner")], type="multipolygon", building="yes")
    return s


def feet_widths() -> Scene:
    """Whole-number tags and one in feet: ``width="40'"`` used to crash the build.

    Every ``width`` in the table is a whole number, so pandas parsed the column as integers, and the
    feet-to-metres product (12.192 m) could not be put back: a TypeError "cannot safely cast
    non-equivalent object to int64" (first seen on a US extract).
    """
    s = Scene()
    s.way([(-60, 0), (60, 0)], highway="residential", width="40'", name="Imperial Street")
    s.way([(0, -60), (0, 0)], highway="residential", width="12", lanes="2")
    s.box(10, 15, 40, 40, building="yes", height="300 ft")
    s.box(-40, 15, -10, 40, building="yes", height="6'6\"")
    return s


def past_bounds() -> Scene:
    """An extract whose ways leave its ``<bounds>``: a street runs 1.5 km east past them.

    Only the 160 x 120 m inside the bounds has buildings; past them the extract holds just the ways
    that leave it, and blocks without buildings would look like open walkable space.
    """
    s = Scene()
    s.bounds = (-80.0, -60.0, 80.0, 60.0)
    s.way([(-80, 0), (0, 0), (1500, 0)], highway="residential", name="Long Street")
    s.way([(0, -60), (0, 0), (0, 60)], highway="residential", name="Short Street")
    s.way([(40, 0), (40, -400)], highway="service")
    for sx in (-1, 1):
        for sy in (-1, 1):
            s.box(sx * 10, sy * 10, sx * 70, sy * 50, building="yes")
    return s


def overlapping_buildings() -> Scene:
    """Buildings drawn over each other: a tower inside its podium, neighbours whose walls cross."""
    s = Scene()
    s.way([(-80, 0), (80, 0)], highway="residential", name="Tower Street")
    s.box(-60, 10, 0, 50, building="commercial", height="12")
    s.box(-45, 20, -15, 40, building="office", height="150")
    s.box(-5, 10, 40, 45, building="yes")  # overlaps the podium by 5 m
    s.box(35, 15, 60, 45, building="yes")  # and its other neighbour by 5 m
    return s


def cut_at_bounds() -> Scene:
    """An extract cut like ``osmium extract -s simple``: ways refer to nodes the file lacks.

    The street leaves the bounds and comes back; joining its known nodes across the gap would draw a
    street straight through the building between. A building cut by the bounds keeps the part inside.
    """
    s = Scene()
    s.bounds = (-60.0, -20.0, 60.0, 60.0)
    street = [(-60, 0), (-30, 0), (-20, -40), (20, -40), (30, 0), (60, 0)]
    s.way(street, highway="residential", name="Loop Street")
    s.box(-25, 10, 25, 40, building="yes")
    s.way([(35, 10), (55, 10), (55, 80), (35, 80), (35, 10)], building="yes")
    s.left_out = {s.node(-20, -40), s.node(20, -40), s.node(55, 80)}
    return s


def write_scenes() -> None:
    crossroads(mapped_sidewalks=True).write("crossroads-mapped-sidewalks.osm")
    crossroads(mapped_sidewalks=False).write("crossroads-crossing-nodes.osm")
    wide_road().write("wide-road.osm")
    passage().write("building-passage.osm")
    relation_building().write("relation-building.osm")
    feet_widths().write("feet-widths.osm")
    past_bounds().write("past-bounds.osm")
    overlapping_buildings().write("overlapping-buildings.osm")
    cut_at_bounds().write("cut-at-bounds.osm")
    empty = Scene()
    empty.node(0, 0, amenity="bench")
    empty.way([(0, 0), (5, 5)], barrier="fence")
    empty.write("nothing-relevant.osm")


if __name__ == "__main__":
    main()
    write_scenes()
