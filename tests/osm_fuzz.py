"""Hypothesis strategies that write odd but legal OpenStreetMap XML, for the osmseg fuzz tests.

A scene is a handful of nodes around a fixed point and ways, relations and tags drawn from the
shapes real extracts contain: missing and odd tag values, unclosed and self-touching rings,
duplicate and missing nodes, one-node ways, negative ids, relations whose members are absent, of the
wrong type or other relations. Every document is well-formed OSM 0.6 that osmium reads.
"""

from __future__ import annotations

from xml.sax.saxutils import quoteattr

import numpy as np
from hypothesis import strategies as st

#: The scene's centre (lon, lat) and the metres per degree there.
CENTRE = (-122.4000, 37.7900)
_M_PER_DEG_LAT = 111_320.0
_M_PER_DEG_LON = 111_320.0 * 0.79

#: Tag values as mappers write them, the odd ones included.
_NUMBERS = ["3", "7.5", "7,5", "12 m", "40'", "24 ft", "6'6\"", "-1", "0", "1;2", "-1;0", "x", "", " ",
            "99999999999999999999", "1e3", "inf", "nan", "2.5.1", "١٢"]  # fmt: skip
TAG_VALUES: dict[str, list[str]] = {
    "highway": ["residential", "primary", "service", "footway", "crossing", "steps", "pedestrian",
                "platform", "busway", "construction", "corridor", "unclassified", "motorway", "yes", ""],
    "building": ["yes", "house", "roof", "no", "transportation", "construction", ""],
    "footway": ["sidewalk", "crossing", "yes", ""],
    "crossing": ["marked", "unmarked", "traffic_signals", "uncontrolled", ""],
    "crossing:markings": ["yes", "no", "zebra"],
    "service": ["driveway", "parking_aisle", "alley"],
    "area": ["yes", "no"],
    "tunnel": ["yes", "building_passage", "no"],
    "bridge": ["yes", "no"],
    "covered": ["yes", "arcade"],
    "location": ["underground", "overground"],
    "oneway": ["yes", "-1", "no"],
    "sidewalk": ["both", "left", "right", "no", "separate", "none"],
    "sidewalk:left": ["no", "yes"],
    "parking:lane:both": ["parallel", "diagonal", "no"],
    "parking:right": ["lane", "half_on_kerb"],
    "cycleway": ["lane", "track"],
    "cycleway:both": ["lane"],
    "name": ["Market Street", "", "Ünïcødé ;&<> \"'"],
    **{key: _NUMBERS for key in ("width", "est_width", "lanes", "lanes:forward", "layer", "level",
                                 "height", "building:levels")},
}  # fmt: skip


@st.composite
def tags(draw, keys: tuple[str, ...] | None = None) -> dict[str, str]:
    """A tag dict: a few keys of :data:`TAG_VALUES`, each with one of its values."""
    pool = sorted(TAG_VALUES) if keys is None else list(keys)
    chosen = draw(st.lists(st.sampled_from(pool), max_size=4, unique=True))
    return {k: draw(st.sampled_from(TAG_VALUES[k])) for k in chosen}


def _tag_xml(tag_dict: dict[str, str]) -> str:
    return "".join(f"<tag k={quoteattr(k)} v={quoteattr(v)}/>" for k, v in tag_dict.items())


@st.composite
def osm_scene(draw) -> str:
    """One OSM XML document of a small odd scene (a string)."""
    n_nodes = draw(st.integers(1, 14))
    # A coarse grid so that ways share, repeat and cross nodes; ids may be negative or out of order.
    sign = draw(st.sampled_from([1, -1]))
    node_ids = [sign * (i + 1) for i in range(n_nodes)]
    cells = draw(st.lists(st.tuples(st.integers(-4, 4), st.integers(-4, 4)), min_size=n_nodes,
                          max_size=n_nodes))  # fmt: skip
    step_m = draw(st.sampled_from([0.0, 0.01, 4.0, 25.0]))
    lon0, lat0 = CENTRE
    nodes = []
    for nid, (i, j) in zip(node_ids, cells, strict=True):
        lon = lon0 + i * step_m / _M_PER_DEG_LON
        lat = lat0 + j * step_m / _M_PER_DEG_LAT
        node_tags = draw(st.one_of(st.just({}), tags(("highway", "crossing", "crossing:markings"))))
        attrs = f'id="{nid}" version="1" lat="{lat:.7f}" lon="{lon:.7f}"'
        nodes.append(f"<node {attrs}>{_tag_xml(node_tags)}</node>")
    # Way node lists: any ids, repeats allowed, sometimes closed, sometimes referring to absent nodes.
    ref = st.one_of(st.sampled_from(node_ids), st.just(9_999_999))
    ways = []
    way_ids = list(range(1, draw(st.integers(0, 6)) + 1))
    for wid in way_ids:
        refs = draw(st.lists(ref, min_size=1, max_size=8))
        if draw(st.booleans()) and len(refs) > 1:
            refs.append(refs[0])
        nds = "".join(f'<nd ref="{r}"/>' for r in refs)
        ways.append(f'<way id="{wid}" version="1">{nds}{_tag_xml(draw(tags()))}</way>')
    relations = []
    for rid in range(1, draw(st.integers(0, 2)) + 1):
        member = st.one_of(
            st.tuples(st.just("way"), st.one_of(st.sampled_from(way_ids or [1]), st.just(8_888_888))),
            st.tuples(st.just("node"), st.sampled_from(node_ids)),
            st.tuples(st.just("relation"), st.integers(1, 3)),
        )
        role = st.sampled_from(["outer", "inner", "", "part"])
        members = draw(st.lists(st.tuples(member, role), max_size=5))
        mxml = "".join(f'<member type="{t}" ref="{r}" role="{role}"/>' for (t, r), role in members)
        rel_type = draw(st.sampled_from(["multipolygon", "building", "route"]))
        rel_tags = {"type": rel_type, **draw(tags(("building",)))}
        relations.append(f'<relation id="{rid}" version="1">{mxml}{_tag_xml(rel_tags)}</relation>')
    bounds = ""
    if draw(st.booleans()):
        half_lat, half_lon = draw(st.sampled_from([10.0, 60.0])) / np.array([_M_PER_DEG_LAT, _M_PER_DEG_LON])
        bounds = (
            f'<bounds minlat="{lat0 - half_lat:.7f}" minlon="{lon0 - half_lon:.7f}" '
            f'maxlat="{lat0 + half_lat:.7f}" maxlon="{lon0 + half_lon:.7f}"/>'
        )
    body = "\n".join([bounds, *nodes, *ways, *relations])
    return f'<?xml version="1.0" encoding="UTF-8"?>\n<osm version="0.6" generator="fuzz">\n{body}\n</osm>\n'
