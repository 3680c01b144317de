"""Stage 1: OpenStreetMap elements -> three GeoDataFrames in the local UTM CRS.

The derivation stages (:mod:`~curbside.osmseg.buildings`, :mod:`~curbside.osmseg.streets`,
:mod:`~curbside.osmseg.crosswalks`, :mod:`~curbside.osmseg.sidewalks`) all work on an
:class:`OsmData`: highway ways as LineStrings, building areas as (Multi)Polygons and tagged highway
nodes as Points, each with one column per tag of :data:`TAG_KEYS`. Files are read with pyosmium in
one streaming pass; :mod:`~curbside.osmseg.overpass` writes an Overpass answer to an OSM file and
reads it here too, so both sources share the reading and the derivation.
"""

from __future__ import annotations

import contextlib
import logging
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path

import geopandas as gpd
import numpy as np
import osmium
import pandas as pd
import shapely
from pyproj import CRS

from curbside.errors import CurbsideInputError
from curbside.osmseg.areas import (
    DroppedBuildings,
    Reason,
    Surroundings,
    multipolygon_areas,
    open_outer_closures,
    outside_buildings,
)
from curbside.osmseg.clipped import ADVICE, MissingNodes, agreed_area, closed_rings
from curbside.osmseg.config import LOCALISED_NAME
from curbside.osmseg.inputs import check_osm_file
from curbside.projection import LocalFrame

log = logging.getLogger(__name__)

BBox = tuple[float, float, float, float]

_FORMAT_NAMES = {"pbf": "PBF", "osm.bz2": "bzip2-compressed OSM XML", "osm.gz": "gzip-compressed OSM XML",
                 "osm": "OSM XML"}  # fmt: skip

#: What osmium says about a file that ends early (an interrupted download).
_CUT_SHORT = ("bzip2 error", "gzip error", "unexpected EOF", "unclosed token", "no element found")

#: Tags the derivation reads; every table has one column per key (None where absent).
TAG_KEYS: tuple[str, ...] = (
    "highway", "footway", "crossing", "crossing:markings", "name", "ref", "service", "area", "junction",
    "building", "building:part", "building:levels", "height", "location", "layer", "level",
    "tunnel", "bridge", "covered", "indoor",
    "width", "est_width", "lanes", "lanes:forward", "lanes:backward", "lanes:both_ways", "oneway",
    "parking:lane:both", "parking:lane:left", "parking:lane:right",
    "parking:both", "parking:left", "parking:right",
    "cycleway", "cycleway:both", "cycleway:left", "cycleway:right",
    "sidewalk", "sidewalk:both", "sidewalk:left", "sidewalk:right",
)  # fmt: skip

_NODE_HIGHWAY_VALUES = frozenset({"crossing"})


@dataclass
class OsmData:
    """The OSM elements the derivation uses, in a local metric CRS.

    Attributes
    ----------
    ways
        Highway ways: ``osm_id`` (int), LineString geometry, one column per tag key.
    areas
        Building areas from closed ways and multipolygon relations: ``osm_id`` (``"w<id>"`` or
        ``"r<id>"``), (Multi)Polygon geometry, tag columns.
    nodes
        Tagged highway nodes (crossings): ``osm_id`` (int), Point geometry, tag columns.
    source
        The file name, or ``"overpass"``.
    timestamp
        ISO 8601 time of the newest element, when the source records one.
    bounds
        (west, south, east, north) WGS84 degrees the source declares it covers (an OSM file's
        ``<bounds>`` or PBF header box, the bbox of an Overpass query); ``None`` when it declares none.
        Ways that leave the area run on past it with none of their surroundings, so maps are clipped
        to it.
    """

    ways: gpd.GeoDataFrame
    areas: gpd.GeoDataFrame
    nodes: gpd.GeoDataFrame
    source: str
    timestamp: str | None = None
    bounds: tuple[float, float, float, float] | None = None

    @property
    def crs(self) -> CRS:
        """The metric CRS of every table."""
        return self.ways.crs

    def __len__(self) -> int:
        return len(self.ways) + len(self.areas) + len(self.nodes)


def tag_table(records: list[dict[str, str]]) -> pd.DataFrame:
    """One column per :data:`TAG_KEYS` entry from tag dicts (missing tags are None), and one per
    other key the dicts hold (the :data:`~curbside.osmseg.config.LOCALISED_NAME` tags of highways)."""
    if not records:
        return pd.DataFrame({k: pd.Series([], dtype=object) for k in TAG_KEYS})
    others = sorted({k for record in records for k in record} - set(TAG_KEYS))
    df = pd.DataFrame.from_records(records, columns=[*TAG_KEYS, *others]).astype(object)
    return df.where(df.notna(), None)


def make_table(
    ids: Iterable[int], geoms: Iterable[shapely.Geometry], records: list[dict[str, str]], crs: CRS
) -> gpd.GeoDataFrame:
    """An OsmData table from ids, geometries and tag dicts."""
    tags = tag_table(records)
    tags.insert(0, "osm_id", list(ids))
    return gpd.GeoDataFrame(tags, geometry=np.asarray(geoms, dtype=object), crs=crs)


def frame_for(bbox: tuple[float, float, float, float]) -> LocalFrame:
    """The UTM frame of a (west, south, east, north) bbox's centre."""
    west, south, east, north = bbox
    return LocalFrame.around((west + east) / 2, (south + north) / 2)


def bbox_polygon(bbox: tuple[float, float, float, float], crs: CRS) -> shapely.Polygon:
    """A WGS84 (west, south, east, north) bbox as a polygon in a metric CRS (its four corners)."""
    west, south, east, north = bbox
    x, y = LocalFrame(crs).to_xy(np.array([west, east, east, west]), np.array([south, south, north, north]))
    return shapely.Polygon(np.column_stack([x, y]))


def clip_to_bbox(data: OsmData, bbox: tuple[float, float, float, float], margin_m: float) -> OsmData:
    """Keep the elements whose geometry comes within ``margin_m`` of the bbox."""
    window = bbox_polygon(bbox, data.crs).buffer(margin_m, join_style="mitre")

    def keep(gdf: gpd.GeoDataFrame) -> gpd.GeoDataFrame:
        return gdf[shapely.intersects(gdf.geometry.values, window)].reset_index(drop=True)

    return OsmData(
        keep(data.ways), keep(data.areas), keep(data.nodes), data.source, data.timestamp, data.bounds
    )


def _osm_input(path: Path, *, warn: bool = True) -> str | osmium.io.File:
    """What osmium should open for ``path``: its name, or, when its content is another OSM format than
    its name says (XML named ``.pbf``), the file with the format its first bytes show (a WARNING says so).

    Raises
    ------
    CurbsideInputError
        Missing, a folder, empty, or a name without one of
        :data:`~curbside.osmseg.inputs.OSM_SUFFIXES` (:func:`~curbside.osmseg.inputs.check_osm_file`).
    """
    named = check_osm_file(path)
    found = _sniffed_format(path)
    if found is None or found == named:
        return str(path)
    if warn:
        log.warning(
            "%s holds %s, not the %s its name says; reading it as %s",
            path.name, _FORMAT_NAMES[found], _FORMAT_NAMES[named], _FORMAT_NAMES[found],
        )  # fmt: skip
    return osmium.io.File(str(path), found)


def _sniffed_format(path: Path) -> str | None:
    """osmium's name of the format that the first bytes of ``path`` show, ``None`` for none of them."""
    with open(path, "rb") as fh:
        head = fh.read(64)
    if head.startswith(b"\x1f\x8b"):
        return "osm.gz"
    if head.startswith(b"BZh"):
        return "osm.bz2"
    if head[4:].startswith(b"\n\tOSMHeader"):  # a PBF's first blob header: length, then type "OSMHeader"
        return "pbf"
    if head.lstrip(b"\xef\xbb\xbf \t\r\n").startswith(b"<"):
        return "osm"
    return None


def declared_bounds(path: str | Path) -> BBox | None:
    """The bounds an OSM file declares, from its header alone (no element is read).

    Parameters
    ----------
    path
        ``.osm``, ``.osm.bz2``, ``.osm.gz`` or ``.osm.pbf``.

    Returns
    -------
    tuple or None
        (west, south, east, north) degrees of the ``<bounds>`` element or PBF header box; ``None``
        when the file declares none.

    Raises
    ------
    CurbsideInputError
        Missing file, unsupported extension, or a header osmium cannot parse.
    """
    path = Path(path)
    source = _osm_input(path, warn=False)
    with _osmium_errors(path):
        reader = osmium.io.Reader(source, osmium.osm.osm_entity_bits.NOTHING)
        try:
            return _header_bounds(reader.header())
        finally:
            reader.close()


def read_osm_file(
    path: str | Path,
    bbox: tuple[float, float, float, float] | None = None,
    *,
    margin_m: float = 60.0,
) -> OsmData:
    """Read highway ways, buildings and crossing nodes from an OSM file with pyosmium.

    A pass over relations (building multipolygons) and one streaming pass with node locations.
    Highway ways are cut where they refer to nodes the file lacks (an extract cut at its bounds):
    each run of two or more known nodes becomes its own line, so a road that leaves the extract and
    comes back is not joined across the gap. A building ring with missing nodes is closed along the
    bounds the file declares, keeping what two guesses at its missing walls agree on
    (:func:`~curbside.osmseg.clipped.closed_rings`), or dropped; a WARNING says how many ways lack
    nodes. Buildings that give no area for another reason (a way that is not closed, a multipolygon
    whose outer ways close no ring...) are dropped with one WARNING per reason
    (:class:`~curbside.osmseg.areas.DroppedBuildings`).

    Parameters
    ----------
    path
        ``.osm``, ``.osm.bz2``, ``.osm.gz`` or ``.osm.pbf``; read as the format its first bytes show
        when that is another of the four (a WARNING says so).
    bbox
        (west, south, east, north) degrees: keep only elements within ``margin_m`` of it and take
        the UTM zone of its centre. ``None``: everything, UTM zone of the data's centre.
    margin_m
        Elements this close to the bbox are kept so that sidewalks at its edge are complete.

    Returns
    -------
    OsmData
        With ``bounds`` from the file's header (``<bounds>`` or the PBF header box), if it has any.

    Raises
    ------
    CurbsideInputError
        Missing or empty file, a folder, unsupported extension, a file osmium cannot parse (not OSM,
        truncated, corrupt), one without highways, buildings or crossings, or one whose ways refer
        only to nodes it lacks.
    """
    path = Path(path)
    source = _osm_input(path)
    with _osmium_errors(path):
        members, rel_tags, bounds = _building_relations(source)
        elements = _read_elements(source, members, bounds)
    log.info(
        "read %s: %d ways, %d areas, %d nodes",
        path.name, len(elements.way_ids), len(elements.area_ids), len(elements.node_ids),
    )  # fmt: skip
    every_xy = np.reshape(np.array(elements.coords(), dtype=float), (-1, 2))
    if len(every_xy) == 0:
        raise _nothing_read(path, elements.missing)
    frame = LocalFrame.around(*((every_xy.min(0) + every_xy.max(0)) / 2)) if bbox is None else frame_for(bbox)
    way_xy = np.array(elements.way_coords, dtype=float).reshape(-1, 2)
    node_xy = np.array(elements.node_coords, dtype=float).reshape(-1, 2)
    way_lines = _rings_or_lines(way_xy, elements.way_lens, frame, closed=False)
    data = OsmData(
        ways=make_table(elements.way_ids, way_lines, elements.way_tags, frame.crs),
        areas=_area_table(elements, (members, rel_tags), frame, way_lines, bounds),
        nodes=make_table(
            elements.node_ids,
            shapely.points(np.column_stack(frame.to_xy(*node_xy.T))),
            elements.node_tags,
            frame.crs,
        ),
        source=path.name,
        timestamp=_iso(elements.newest),
        bounds=bounds,
    )
    elements.missing.warn(path.name)
    elements.dropped.warn(path.name)
    return data if bbox is None else clip_to_bbox(data, bbox, margin_m)


def _area_table(
    elements: _Elements,
    relations: tuple[dict[int, list[tuple[int, str]]], dict[int, dict[str, str]]],
    frame: LocalFrame,
    way_lines: np.ndarray,
    bounds: BBox | None,
) -> gpd.GeoDataFrame:
    """Building areas: whole rings, then rings cut by the bounds, then multipolygon relations
    (``relations``: member ways' uses and relations' tags, from :func:`_building_relations`)."""
    area_xy = np.array(elements.area_coords, dtype=float).reshape(-1, 2)
    whole = _rings_or_lines(area_xy, elements.area_lens, frame, closed=True)
    closures = []
    for k in (0, 1):
        rings = [pair[k] for pair in elements.cut_rings]
        xy = np.array([c for ring in rings for c in ring], dtype=float).reshape(-1, 2)
        closures.append(_rings_or_lines(xy, [len(ring) for ring in rings], frame, closed=True))
    cut_polys = agreed_area(*closures) if elements.cut_rings else np.array([], dtype=object)
    kept = ~shapely.is_empty(cut_polys)
    if not kept.all():
        elements.missing.drop("no area that both guesses agree on", int((~kept).sum()))
    around = None
    if bounds is not None:
        taken = np.concatenate([whole, cut_polys[kept]])
        streets = way_lines[outside_buildings(elements.way_tags)]
        around = Surroundings(bbox_polygon(bounds, frame.crs), taken, streets)
    rel_ids, rel_tags, rel_polys = _assemble_relations(*relations, elements, frame, around)
    return make_table(
        elements.area_ids + [i for i, k in zip(elements.cut_ids, kept, strict=True) if k] + rel_ids,
        np.concatenate([whole, cut_polys[kept], rel_polys]),
        elements.area_tags + [t for t, k in zip(elements.cut_tags, kept, strict=True) if k] + rel_tags,
        frame.crs,
    )


def _nothing_read(path: Path, missing: MissingNodes) -> CurbsideInputError:
    """The error for a file that gave no coordinates: no elements used, or ways without their nodes."""
    if missing.ways:
        return CurbsideInputError(
            path, f"its {missing.ways} highway and building ways refer to nodes the file lacks, which "
            f"leaves nothing to build. {ADVICE}",
        )  # fmt: skip
    return CurbsideInputError(path, "no highways, buildings or crossings in this file")


@contextlib.contextmanager
def _osmium_errors(path: Path) -> Iterator[None]:
    """Turn what osmium raises on a file it cannot parse into a one-line :class:`CurbsideInputError`."""
    try:
        yield
    except (RuntimeError, osmium.InvalidLocationError) as exc:
        reason = _first_line(exc)
        cut = "; it ends early: an interrupted download?" if any(m in reason for m in _CUT_SHORT) else ""
        raise CurbsideInputError(path, f"not a readable OSM file ({reason}){cut}") from None


@dataclass
class _Elements:
    """What the streaming pass collects: concatenated (lon, lat) per kind, with ids and tags."""

    way_ids: list[int] = field(default_factory=list)
    way_tags: list[dict[str, str]] = field(default_factory=list)
    way_lens: list[int] = field(default_factory=list)
    way_coords: list[tuple[float, float]] = field(default_factory=list)
    area_ids: list[str] = field(default_factory=list)
    area_tags: list[dict[str, str]] = field(default_factory=list)
    area_lens: list[int] = field(default_factory=list)
    area_coords: list[tuple[float, float]] = field(default_factory=list)
    node_ids: list[int] = field(default_factory=list)
    node_tags: list[dict[str, str]] = field(default_factory=list)
    node_coords: list[tuple[float, float]] = field(default_factory=list)
    #: Relation member way id -> its runs of known (lon, lat).
    member_runs: dict[int, list[list[tuple[float, float]]]] = field(default_factory=dict)
    newest: float = 0.0
    #: Ways with missing nodes, counted.
    missing: MissingNodes = field(default_factory=MissingNodes)
    #: Buildings that give no area for another reason.
    dropped: DroppedBuildings = field(default_factory=DroppedBuildings)
    #: Building rings with missing nodes: id, tags, two closures along the bounds.
    cut_ids: list[str] = field(default_factory=list)
    cut_tags: list[dict[str, str]] = field(default_factory=list)
    cut_rings: list[tuple[list[tuple[float, float]], list[tuple[float, float]]]] = field(default_factory=list)

    def coords(self) -> list[tuple[float, float]]:
        """Every (lon, lat) read, building relations' member ways included."""
        cut = [c for pair in self.cut_rings for c in pair[0]]
        members = [c for runs in self.member_runs.values() for run in runs for c in run]
        return self.way_coords + self.area_coords + self.node_coords + cut + members


def _read_elements(
    source: str | osmium.io.File, members: dict[int, list[tuple[int, str]]], bounds: BBox | None
) -> _Elements:
    """The streaming pass: highway ways, building ways, crossing nodes, member ways' coordinates."""
    out = _Elements()
    keys = frozenset(TAG_KEYS)
    # osmium's location index holds only positive ids; extracts and editors use negative ones too.
    negative_nodes: dict[int, tuple[float, float]] = {}
    for obj in osmium.FileProcessor(source).with_locations():
        if obj.tags:
            out.newest = max(out.newest, obj.timestamp.timestamp())
        if obj.is_node():
            if obj.id < 0 and obj.location.valid():
                negative_nodes[obj.id] = (obj.location.lon, obj.location.lat)
            if obj.tags.get("highway") in _NODE_HIGHWAY_VALUES and obj.location.valid():
                out.node_ids.append(obj.id)
                out.node_tags.append({t.k: t.v for t in obj.tags if t.k in keys})
                out.node_coords.append((obj.location.lon, obj.location.lat))
        elif obj.is_way():
            _add_way(obj, negative_nodes, obj.id in members, bounds, out)
    return out


def _add_way(
    way: osmium.osm.Way,
    negative_nodes: dict[int, tuple[float, float]],
    is_member: bool,
    bounds: BBox | None,
    out: _Elements,
) -> None:
    """Collect a way the derivation uses (highway, building ring, relation member), walking its nodes once."""
    highway = "highway" in way.tags
    building = not highway and "building" in way.tags
    if building and not way.is_closed():
        if not is_member:  # a member is a part of its relation's ring
            few = len({n.ref for n in way.nodes}) < 3
            out.dropped.add(Reason.FEW_NODES if few else Reason.NOT_CLOSED, [f"w{way.id}"])
        building = False
    if not (is_member or highway or building):
        return
    locations = _locations(way, negative_nodes)
    lacks_nodes = None in locations
    if is_member:
        out.member_runs[way.id] = _known_runs(locations)
        if "building" not in way.tags and not highway:  # else counted below
            out.missing.members += lacks_nodes
    if highway:
        way_tags = {t.k: t.v for t in way.tags if t.k in TAG_KEYS or LOCALISED_NAME.fullmatch(t.k)}
        out.missing.highways += lacks_nodes
        for run in _known_runs(locations):
            out.way_ids.append(way.id)
            out.way_tags.append(way_tags)
            out.way_lens.append(len(run))
            out.way_coords.extend(run)
    elif building:
        ring = _building_ring(way, locations, bounds, out)
        if ring is not None:
            out.area_ids.append(f"w{way.id}")
            out.area_tags.append({t.k: t.v for t in way.tags if t.k in TAG_KEYS})
            out.area_lens.append(len(ring))
            out.area_coords.extend(ring)


def _building_ring(
    way: osmium.osm.Way, locations: list, bounds: BBox | None, out: _Elements
) -> list[tuple[float, float]] | None:
    """The closed (lon, lat) ring of a building way, ``None`` when it has none to give.

    A ring with missing nodes gives none here: its two closures along the file's bounds
    (:func:`~curbside.osmseg.clipped.closed_rings`) go to ``out.cut_rings``, or it is dropped.
    """
    if None not in locations:
        if len(set(locations)) < 3:
            out.dropped.add(Reason.FEW_NODES, [f"w{way.id}"])
            return None
        # The first node is repeated once more (as it always was): maps stay byte for byte the same.
        return locations + [locations[0]]
    out.missing.buildings.append(f"w{way.id}")
    closures = closed_rings(locations, bounds, out.missing)
    if closures is not None:
        out.cut_ids.append(f"w{way.id}")
        out.cut_tags.append({t.k: t.v for t in way.tags if t.k in TAG_KEYS})
        out.cut_rings.append(closures)
    return None


def _locations(way: osmium.osm.Way, negative_nodes: dict[int, tuple[float, float]]) -> list:
    """(lon, lat) of each of the way's nodes, ``None`` where the file lacks the node."""
    out: list[tuple[float, float] | None] = []
    for n in way.nodes:
        if n.location.valid():
            out.append((n.lon, n.lat))
        else:
            out.append(negative_nodes.get(n.ref))
    return out


def _known_runs(locations: list) -> list:
    """A way's (lon, lat) (:func:`_locations`) split where a node is missing: runs of two or more."""
    runs: list[list[tuple[float, float]]] = [[]]
    for loc in locations:
        if loc is not None:
            runs[-1].append(loc)
        elif runs[-1]:
            runs.append([])
    return [run for run in runs if len(run) >= 2]


def _iso(epoch_s: float) -> str | None:
    if epoch_s <= 0:
        return None
    return datetime.fromtimestamp(epoch_s, timezone.utc).isoformat().replace("+00:00", "Z")


def _rings_or_lines(lonlat: np.ndarray, lengths: list[int], frame: LocalFrame, *, closed: bool) -> np.ndarray:
    """LineStrings (or valid Polygons from closed rings) from concatenated coordinates."""
    if not lengths:
        return np.array([], dtype=object)
    xy = np.column_stack(frame.to_xy(lonlat[:, 0], lonlat[:, 1]))
    index = np.repeat(np.arange(len(lengths)), lengths)
    if not closed:
        return shapely.linestrings(xy, indices=index)
    polys = shapely.polygons(shapely.linearrings(xy, indices=index))
    return shapely.make_valid(polys)


def _building_relations(
    source: str | osmium.io.File,
) -> tuple[dict[int, list[tuple[int, str]]], dict[int, dict[str, str]], BBox | None]:
    """Building multipolygon relations and the header's bounds, from a pass over relations only.

    Returns
    -------
    members
        Way id -> [(relation id, role)], so that the main pass keeps the member ways' coordinates.
    rel_tags
        Relation id -> tags.
    bounds
        The header's (west, south, east, north), or ``None`` when it has no valid box.
    """
    members: dict[int, list[tuple[int, str]]] = {}
    rel_tags: dict[int, dict[str, str]] = {}
    processor = osmium.FileProcessor(source, osmium.osm.RELATION)
    bounds = _header_bounds(processor.header)
    for rel in processor:
        if rel.tags.get("type") != "multipolygon" or "building" not in rel.tags:
            continue
        for m in rel.members:
            if m.type == "w":
                members.setdefault(m.ref, []).append((rel.id, m.role))
        rel_tags[rel.id] = dict(rel.tags)
    return members, rel_tags, bounds


def _header_bounds(header: osmium.io.Header) -> BBox | None:
    """A file header's (west, south, east, north), ``None`` when it has no valid box."""
    box = header.box()
    if box.valid() and box.bottom_left.lon < box.top_right.lon and box.bottom_left.lat < box.top_right.lat:
        return box.bottom_left.lon, box.bottom_left.lat, box.top_right.lon, box.top_right.lat
    return None


def _assemble_relations(
    members: dict[int, list[tuple[int, str]]],
    rel_tags: dict[int, dict[str, str]],
    elements: _Elements,
    frame: LocalFrame,
    around: Surroundings | None,
) -> tuple[list[str], list[dict[str, str]], np.ndarray]:
    """Polygons of building multipolygon relations: polygonized outer ways minus inner ways.

    Members the file lacks are skipped. Where the outer ways close no ring and the file declares
    bounds (``around``), the part inside them that one open outer chain shows is the building
    (:func:`~curbside.osmseg.areas.open_outer_closures`). A relation that gives no polygon (no member
    in the file, outer ways that close no ring, inner rings that cover it all) is counted in
    ``elements.dropped``.
    """
    dropped = elements.dropped
    runs = [(w, run) for w in members for run in elements.member_runs.get(w, ())]
    uses = [(i, rel_id, role == "inner") for i, (w, _) in enumerate(runs) for rel_id, role in members[w]]
    used = {rel_id for _, rel_id, _ in uses}
    dropped.add(Reason.NO_MEMBERS, [f"r{r}" for r in rel_tags if r not in used])
    if not runs:
        return [], [], np.array([], dtype=object)
    lonlat = np.array([c for _, run in runs for c in run], dtype=float)
    lines = _rings_or_lines(lonlat, [len(run) for _, run in runs], frame, closed=False)
    line_i, rel_of, inner = (np.array(v) for v in zip(*uses, strict=True))
    rel_ids, rel_row = np.unique(rel_of, return_inverse=True)
    outer, polys = multipolygon_areas(lines[line_i], rel_row, inner, len(rel_ids))
    if around is not None and shapely.is_empty(outer).any():
        extra = open_outer_closures(lines[line_i], rel_row, inner, len(rel_ids), around)
        closed = ~shapely.is_empty(extra)
        if closed.any():
            log.info("%d building relations closed along the file's bounds", int(closed.sum()))
            outer, polys = multipolygon_areas(lines[line_i], rel_row, inner, len(rel_ids), extra)
    keep = ~shapely.is_empty(polys)
    open_outer = shapely.is_empty(outer)
    for reason, lost in ((Reason.OPEN_OUTER, ~keep & open_outer), (Reason.INNER_COVERS, ~keep & ~open_outer)):
        dropped.add(reason, [f"r{r}" for r in rel_ids[lost]])
    ids = [f"r{r}" for r in rel_ids[keep]]
    tags = [{k: v for k, v in rel_tags[int(r)].items() if k in TAG_KEYS} for r in rel_ids[keep]]
    return ids, tags, polys[keep]


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return text[0] if text else type(exc).__name__
