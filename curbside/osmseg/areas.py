"""Building areas from multipolygon relations, and the buildings that give no area, counted by reason.

:func:`multipolygon_areas` polygonizes the member lines of building relations (outer rings minus
inner rings). :class:`DroppedBuildings` counts every building way or relation that gives no area (a
way that is not closed, one with fewer than three distinct nodes, a multipolygon whose outer ways close
no ring...) so that the build says so: one WARNING line per reason, with the count and a few OSM ids,
instead of a map short of buildings without a word. :func:`open_outer_closures` gives back the part
inside the file's bounds of a building relation that crosses them in a complete-ways export.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from enum import Enum

import numpy as np
import shapely
from shapely.ops import split

log = logging.getLogger(__name__)


class Reason(str, Enum):
    """Why a building gives no area (the WARNING lines say it)."""

    NOT_CLOSED = "way not closed: its last node is not its first"
    FEW_NODES = "way with fewer than three distinct nodes: no area"
    OPEN_OUTER = "multipolygon whose outer ways close no ring"
    NO_MEMBERS = "multipolygon with none of its member ways in the file"
    INNER_COVERS = "multipolygon whose inner rings cover its outer ones"


#: OSM ids a WARNING line names per reason.
EXAMPLE_IDS = 4

#: A side of an open outer chain is taken for building when what it would cover that cannot be
#: building is at most this share of what the other side would cover (:func:`open_outer_closures`).
SIDE_CONFLICT_RATIO = 0.5
#: m^2 counted per metre of street centreline a side would cover (about a lane).
STREET_CONFLICT_M = 3.0
#: Roads a building never stands on (:func:`outside_buildings`).
OUTSIDE_ROADS = frozenset(
    {"motorway", "trunk", "primary", "secondary", "tertiary", "unclassified", "residential",
     "living_street", "busway"}
)  # fmt: skip
#: m: a chain's end this close to the bounds, or inside them, is not taken for one outside them.
BOUNDS_CLEARANCE_M = 0.01


@dataclass
class DroppedBuildings:
    """Building ways and relations of one file that give no area, by reason.

    Rings cut by the file's bounds are counted by :class:`~curbside.osmseg.clipped.MissingNodes`
    instead.

    Attributes
    ----------
    ids
        Reason -> the OSM ids (``"w<id>"``, ``"r<id>"``) dropped for it, in file order.
    """

    ids: dict[Reason, list[str]] = field(default_factory=dict)

    def add(self, reason: Reason, osm_ids: list[str]) -> None:
        """Count ``osm_ids`` as dropped for ``reason``."""
        if osm_ids:
            self.ids.setdefault(reason, []).extend(osm_ids)

    def warn(self, source: str) -> None:
        """Log one WARNING per reason: how many buildings, and the first few ids (nothing if none)."""
        for reason, ids in self.ids.items():
            shown = ", ".join(ids[:EXAMPLE_IDS]) + (", ..." if len(ids) > EXAMPLE_IDS else "")
            log.warning(
                "%s: %d building%s dropped (%s): %s; the map has no building there",
                source, len(ids), "" if len(ids) == 1 else "s", reason.value, shown,
            )  # fmt: skip


def multipolygon_areas(
    lines: np.ndarray,
    relation: np.ndarray,
    inner: np.ndarray,
    n_relations: int,
    extra_outer: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Areas of multipolygon relations: the rings their outer lines close, minus their inner rings.

    Parameters
    ----------
    lines
        Member LineStrings, one row per use of a line by a relation.
    relation
        Row's relation, ``0 .. n_relations - 1``.
    inner
        Row's role is ``inner`` (any other role counts as outer).
    n_relations
        How many relations.
    extra_outer
        Per relation, area to add to what its outer lines close (:func:`open_outer_closures`).

    Returns
    -------
    (outer, areas)
        Per relation, the union of the polygons its outer lines close, and that minus its inner
        rings (valid); either is empty where there is none.
    """

    def rings(mask: np.ndarray) -> np.ndarray:
        """Per relation, the union of the polygons its member lines of one role close."""
        table = _padded_rows(relation[mask], lines[mask], n_relations)
        faces = shapely.polygonize(table, axis=1)
        parts, owner = shapely.get_parts(faces, return_index=True)
        return shapely.union_all(_padded_rows(owner, parts, n_relations), axis=1)

    outer = rings(~inner)
    if extra_outer is not None:
        outer = shapely.union(outer, extra_outer)
    return outer, shapely.make_valid(shapely.difference(outer, rings(inner)))


@dataclass(frozen=True)
class Surroundings:
    """What a building crossing the file's bounds is weighed against (all in the map's metric CRS).

    Attributes
    ----------
    bounds
        The bounds the file declares, as a polygon.
    taken
        The other buildings (polygons).
    streets
        Centrelines of highways no building stands on (:func:`outside_buildings`).
    """

    bounds: shapely.Polygon
    taken: np.ndarray
    streets: np.ndarray


def outside_buildings(tags: list[dict[str, str]]) -> np.ndarray:
    """Which highways (tag dicts) no building stands on: open-air roads (:data:`OUTSIDE_ROADS` and
    their links) and mapped sidewalks and crossings. Service roads are not counted: courtyards have
    them."""

    def outside(t: dict[str, str]) -> bool:
        covered = t.get("tunnel", "no") != "no" or t.get("covered", "no") != "no" or "indoor" in t
        road = t.get("highway", "").removesuffix("_link") in OUTSIDE_ROADS
        return not covered and (road or t.get("footway") in ("sidewalk", "crossing"))

    return np.array([outside(t) for t in tags], dtype=bool)


def open_outer_closures(
    lines: np.ndarray, relation: np.ndarray, inner: np.ndarray, n_relations: int, around: Surroundings
) -> np.ndarray:
    """Per relation whose outer lines close no ring, the building inside the bounds, if the file shows it.

    A complete-ways export (openstreetmap.org's Export, ``osmium extract --strategy complete_ways``)
    holds every way with a node inside its bounds, whole, and no other: of a building relation that
    crosses the bounds it keeps the outer ways that enter them, which merge into one open chain with
    both ends outside the bounds. Inside the bounds that chain is the whole ring, so the building there
    is the part of the bounds on one side of it. The side is the one that would cover less of what
    cannot be building -- other buildings (m^2) and the centrelines of open-air roads other than
    service roads, mapped sidewalks and crossings (:data:`STREET_CONFLICT_M` m^2 a metre) -- when that
    is at most :data:`SIDE_CONFLICT_RATIO` of what the other side would cover. Otherwise (no evidence
    either way), or for several open chains, an end inside the bounds (a file cut through its ways) or
    a chain that misses them, the relation gets nothing.

    Parameters
    ----------
    lines, relation, inner, n_relations
        As for :func:`multipolygon_areas`.
    around
        The file's bounds and what the building must not cover.

    Returns
    -------
    numpy.ndarray
        Per relation, a polygon (empty where none).
    """
    out = np.array([shapely.Polygon()] * n_relations, dtype=object)
    for rel in np.unique(relation[~inner]):
        merged = shapely.line_merge(shapely.multilinestrings(lines[~inner & (relation == rel)]))
        chains = shapely.get_parts(merged)
        if len(chains) != 1 or shapely.is_closed(chains[0]):
            continue
        ends = shapely.points(shapely.get_coordinates(chains[0])[[0, -1]])
        if (shapely.distance(around.bounds, ends) > BOUNDS_CLEARANCE_M).all():
            out[rel] = _building_side(chains[0], around)
    return out


def _building_side(chain: shapely.LineString, around: Surroundings) -> shapely.Geometry:
    """The part of the bounds on the side of ``chain`` that covers clearly less non-building, or empty."""
    pieces = shapely.get_parts(split(around.bounds, chain))
    inside = shapely.get_parts(shapely.intersection(chain, around.bounds))
    inside = inside[shapely.length(inside) > 0]
    if len(pieces) < 2 or not len(inside):
        return shapely.Polygon()
    middle = shapely.line_interpolate_point(inside, 0.5, normalized=True)
    ahead = shapely.line_interpolate_point(inside, shapely.line_locate_point(inside, middle) + 0.01)
    behind = shapely.line_interpolate_point(inside, shapely.line_locate_point(inside, middle) - 0.01)
    tangent = shapely.get_coordinates(ahead) - shapely.get_coordinates(behind)
    normal = np.column_stack([-tangent[:, 1], tangent[:, 0]])
    normal /= np.maximum(np.hypot(*normal.T), 1e-12)[:, None]
    at = shapely.get_coordinates(middle)
    sides = []
    for sign in (1.0, -1.0):
        probes = shapely.points(at + sign * BOUNDS_CLEARANCE_M * normal)
        touched = shapely.contains(pieces[:, None], probes[None, :]).any(axis=1)
        sides.append(shapely.union_all(pieces[touched]))
    conflict = [
        shapely.area(shapely.intersection(around.taken, side)).sum()
        + STREET_CONFLICT_M * shapely.length(shapely.intersection(around.streets, side)).sum()
        for side in sides
    ]
    for this, other in ((0, 1), (1, 0)):
        if conflict[this] <= SIDE_CONFLICT_RATIO * conflict[other] and conflict[other] > 0:
            return sides[this]
    return shapely.Polygon()


def _padded_rows(row: np.ndarray, values: np.ndarray, n_rows: int) -> np.ndarray:
    """A (n_rows, widest) object array holding each row's values, padded with None."""
    order = np.argsort(row, kind="stable")
    row, values = row[order], values[order]
    rank = np.arange(len(row)) - np.searchsorted(row, row)
    table = np.full((n_rows, int(rank.max()) + 1 if len(rank) else 1), None, dtype=object)
    table[row, rank] = values
    return table
