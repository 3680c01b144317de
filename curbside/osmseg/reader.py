"""Stage 1: OpenStreetMap elements -> three GeoDataFrames in the local UTM CRS.

The derivation stages (:mod:`~curbside.osmseg.buildings`, :mod:`~curbside.osmseg.streets`,
:mod:`~curbside.osmseg.crosswalks`, :mod:`~curbside.osmseg.sidewalks`) all work on an
:class:`OsmData`: highway ways as LineStrings, building areas as (Multi)Polygons and tagged highway
nodes as Points, each with one column per tag of :data:`TAG_KEYS`. Files are read with pyosmium in
one streaming pass; :mod:`~curbside.osmseg.overpass` converts an osmnx feature table into the same
representation, so both sources share the derivation.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path

import geopandas as gpd
import numpy as np
import osmium
import pandas as pd
import shapely
from pyproj import CRS

from curbside.errors import CurbsideInputError
from curbside.projection import LocalFrame

log = logging.getLogger(__name__)

#: File name endings ``--osm`` accepts (pyosmium reads compressed XML itself).
OSM_SUFFIXES: tuple[str, ...] = (".osm", ".osm.bz2", ".osm.gz", ".osm.pbf")

#: Tags the derivation reads; every table has one column per key (None where absent).
TAG_KEYS: tuple[str, ...] = (
    "highway", "footway", "crossing", "crossing:markings", "name", "service", "area",
    "building", "building:part", "building:levels", "height", "location", "layer", "level",
    "tunnel", "bridge", "covered", "indoor",
    "width", "est_width", "lanes", "lanes:forward", "lanes:backward", "lanes:both_ways", "oneway",
    "parking:lane:both", "parking:lane:left", "parking:lane:right",
    "parking:both", "parking:left", "parking:right",
    "cycleway", "cycleway:both", "cycleway:left", "cycleway:right",
    "sidewalk", "sidewalk:both", "sidewalk:left", "sidewalk:right",
)  # fmt: skip

_WAY_KEYS = ("highway",)
_AREA_KEYS = ("building",)
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
    """

    ways: gpd.GeoDataFrame
    areas: gpd.GeoDataFrame
    nodes: gpd.GeoDataFrame
    source: str
    timestamp: str | None = None

    @property
    def crs(self) -> CRS:
        """The metric CRS of every table."""
        return self.ways.crs

    def __len__(self) -> int:
        return len(self.ways) + len(self.areas) + len(self.nodes)


def tag_table(records: list[dict[str, str]]) -> pd.DataFrame:
    """One column per :data:`TAG_KEYS` entry from tag dicts (missing tags are None)."""
    if not records:
        return pd.DataFrame({k: pd.Series([], dtype=object) for k in TAG_KEYS})
    df = pd.DataFrame.from_records(records, columns=list(TAG_KEYS)).astype(object)
    return df.where(df.notna(), None)


def make_table(ids, geoms, records: list[dict[str, str]], crs: CRS) -> gpd.GeoDataFrame:
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

    return OsmData(keep(data.ways), keep(data.areas), keep(data.nodes), data.source, data.timestamp)


def _check_path(path: Path) -> None:
    if not path.exists():
        raise CurbsideInputError(path, "no such OSM file")
    if not path.is_file():
        raise CurbsideInputError(path, "not a file")
    name = path.name.lower()
    if not name.endswith(OSM_SUFFIXES):
        raise CurbsideInputError(
            path, f"unsupported file type; expected one of {', '.join(OSM_SUFFIXES[:4])}"
        )


def read_osm_file(
    path: str | Path,
    bbox: tuple[float, float, float, float] | None = None,
    *,
    margin_m: float = 60.0,
) -> OsmData:
    """Read highway ways, buildings and crossing nodes from an OSM file with pyosmium.

    One streaming pass with node locations (plus osmium's relation pass for multipolygons).

    Parameters
    ----------
    path
        ``.osm``, ``.osm.bz2``, ``.osm.gz`` or ``.osm.pbf``.
    bbox
        (west, south, east, north) degrees: keep only elements within ``margin_m`` of it and take
        the UTM zone of its centre. ``None``: everything, UTM zone of the data's centre.
    margin_m
        Elements this close to the bbox are kept so that sidewalks at its edge are complete.

    Returns
    -------
    OsmData

    Raises
    ------
    CurbsideInputError
        Missing file, unsupported extension, or a file osmium cannot parse.
    """
    path = Path(path)
    _check_path(path)
    members, rel_tags = _building_relation_members(path)
    way_ids: list[int] = []
    way_tags: list[dict[str, str]] = []
    way_lens: list[int] = []
    way_coords: list[tuple[float, float]] = []
    area_ids: list[str] = []
    area_tags: list[dict[str, str]] = []
    area_lens: list[int] = []
    area_coords: list[tuple[float, float]] = []
    member_coords: dict[int, list[tuple[float, float]]] = {}
    node_ids: list[int] = []
    node_tags: list[dict[str, str]] = []
    node_coords: list[tuple[float, float]] = []
    # osmium's location index holds only positive ids; extracts and editors use negative ones too.
    negative_nodes: dict[int, tuple[float, float]] = {}
    newest = 0.0
    keys = frozenset(TAG_KEYS)
    processor = osmium.FileProcessor(str(path)).with_locations()
    try:
        for obj in processor:
            if obj.is_node() and obj.id < 0:
                negative_nodes[obj.id] = (obj.location.lon, obj.location.lat)
            elif obj.is_way() and obj.id in members:
                member_coords[obj.id] = _way_coords(obj, negative_nodes)
            if not obj.tags:
                continue
            stamp = obj.timestamp.timestamp()
            if stamp > newest:
                newest = stamp
            if obj.is_node():
                if obj.tags.get("highway") in _NODE_HIGHWAY_VALUES:
                    node_ids.append(obj.id)
                    node_tags.append({t.k: t.v for t in obj.tags if t.k in keys})
                    node_coords.append((obj.location.lon, obj.location.lat))
            elif obj.is_way():
                if "highway" in obj.tags:
                    coords = _way_coords(obj, negative_nodes)
                    if len(coords) >= 2:
                        way_ids.append(obj.id)
                        way_tags.append({t.k: t.v for t in obj.tags if t.k in keys})
                        way_lens.append(len(coords))
                        way_coords.extend(coords)
                elif "building" in obj.tags and obj.is_closed():
                    coords = _way_coords(obj, negative_nodes)
                    if len(coords) >= 4:
                        area_ids.append(f"w{obj.id}")
                        area_tags.append({t.k: t.v for t in obj.tags if t.k in keys})
                        area_lens.append(len(coords))
                        area_coords.extend(coords)
    except RuntimeError as exc:
        raise CurbsideInputError(path, f"not a readable OSM file ({_first_line(exc)})") from None
    log.info("read %s: %d ways, %d areas, %d nodes", path.name, len(way_ids), len(area_ids), len(node_ids))

    way_xy = np.array(way_coords, dtype=float).reshape(-1, 2)
    area_xy = np.array(area_coords, dtype=float).reshape(-1, 2)
    node_xy = np.array(node_coords, dtype=float).reshape(-1, 2)
    every_xy = np.concatenate([way_xy, area_xy, node_xy])
    if len(every_xy) == 0:
        raise CurbsideInputError(path, "no highways, buildings or crossings in this file")
    frame = LocalFrame.around(*((every_xy.min(0) + every_xy.max(0)) / 2)) if bbox is None else frame_for(bbox)
    rel_ids, rel_tags, rel_polys = _assemble_relations(members, rel_tags, member_coords, frame, keys)
    data = OsmData(
        ways=make_table(way_ids, _rings_or_lines(way_xy, way_lens, frame, closed=False), way_tags, frame.crs),
        areas=make_table(
            area_ids + rel_ids,
            np.concatenate([_rings_or_lines(area_xy, area_lens, frame, closed=True), rel_polys]),
            area_tags + rel_tags,
            frame.crs,
        ),
        nodes=make_table(
            node_ids, shapely.points(np.column_stack(frame.to_xy(*node_xy.T))), node_tags, frame.crs
        ),
        source=path.name,
        timestamp=_iso(newest),
    )
    return data if bbox is None else clip_to_bbox(data, bbox, margin_m)


def _way_coords(way: osmium.osm.Way, negative_nodes: dict[int, tuple[float, float]]) -> list:
    """(lon, lat) of a way's nodes whose location is known."""
    coords = []
    for n in way.nodes:
        if n.location.valid():
            coords.append((n.lon, n.lat))
        elif n.ref in negative_nodes:
            coords.append(negative_nodes[n.ref])
    return coords


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


def _building_relation_members(
    path: Path,
) -> tuple[dict[int, list[tuple[int, str]]], dict[int, dict[str, str]]]:
    """Building multipolygon relations: way id -> [(relation id, role)], and relation tags.

    A first pass over relations only, so that the main pass can keep the member ways' coordinates.
    """
    members: dict[int, list[tuple[int, str]]] = {}
    rel_tags: dict[int, dict[str, str]] = {}
    try:
        for rel in osmium.FileProcessor(str(path), osmium.osm.RELATION):
            if rel.tags.get("type") != "multipolygon" or "building" not in rel.tags:
                continue
            for m in rel.members:
                if m.type == "w":
                    members.setdefault(m.ref, []).append((rel.id, m.role))
            rel_tags[rel.id] = dict(rel.tags)
    except RuntimeError as exc:
        raise CurbsideInputError(path, f"not a readable OSM file ({_first_line(exc)})") from None
    return members, rel_tags


def _assemble_relations(
    members: dict[int, list[tuple[int, str]]],
    rel_tags: dict[int, dict[str, str]],
    member_coords: dict[int, list[tuple[float, float]]],
    frame: LocalFrame,
    keys: frozenset[str],
) -> tuple[list[str], list[dict[str, str]], np.ndarray]:
    """Polygons of building multipolygon relations: polygonized outer ways minus inner ways."""
    way_ids = [w for w in members if len(member_coords.get(w, ())) >= 2]
    if not way_ids:
        return [], [], np.array([], dtype=object)
    lengths = [len(member_coords[w]) for w in way_ids]
    lonlat = np.array([c for w in way_ids for c in member_coords[w]], dtype=float)
    lines = _rings_or_lines(lonlat, lengths, frame, closed=False)
    uses = [(i, rel_id, role == "inner") for i, w in enumerate(way_ids) for rel_id, role in members[w]]
    line_i, rel_of, inner = (np.array(v) for v in zip(*uses, strict=True))
    rel_ids, rel_row = np.unique(rel_of, return_inverse=True)

    def rings(mask: np.ndarray) -> np.ndarray:
        """Per relation, the union of the polygons its member lines of one role close."""
        table = _padded_rows(rel_row[mask], lines[line_i[mask]], len(rel_ids))
        faces = shapely.polygonize(table, axis=1)
        parts, owner = shapely.get_parts(faces, return_index=True)
        return shapely.union_all(_padded_rows(owner, parts, len(rel_ids)), axis=1)

    polys = shapely.difference(rings(~inner), rings(inner))
    keep = ~shapely.is_empty(polys)
    ids = [f"r{r}" for r in rel_ids[keep]]
    tags = [{k: v for k, v in rel_tags[int(r)].items() if k in keys} for r in rel_ids[keep]]
    return ids, tags, polys[keep]


def _padded_rows(row: np.ndarray, values: np.ndarray, n_rows: int) -> np.ndarray:
    """A (n_rows, widest) object array holding each row's values, padded with None."""
    order = np.argsort(row, kind="stable")
    row, values = row[order], values[order]
    rank = np.arange(len(row)) - np.searchsorted(row, row)
    table = np.full((n_rows, int(rank.max()) + 1 if len(rank) else 1), None, dtype=object)
    table[row, rank] = values
    return table


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return text[0] if text else type(exc).__name__


