"""Building areas from multipolygon relations, and the buildings that give no area, counted by reason.

:func:`multipolygon_areas` polygonizes the member lines of building relations (outer rings minus
inner rings). :class:`DroppedBuildings` counts every building way or relation that gives no area (a
way that is not closed, one with fewer than three distinct nodes, a multipolygon whose outer ways close
no ring...) so that the build says so: one WARNING line per reason, with the count and a few OSM ids,
instead of a map short of buildings without a word.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from enum import Enum

import numpy as np
import shapely

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
    lines: np.ndarray, relation: np.ndarray, inner: np.ndarray, n_relations: int
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
    return outer, shapely.make_valid(shapely.difference(outer, rings(inner)))


def _padded_rows(row: np.ndarray, values: np.ndarray, n_rows: int) -> np.ndarray:
    """A (n_rows, widest) object array holding each row's values, padded with None."""
    order = np.argsort(row, kind="stable")
    row, values = row[order], values[order]
    rank = np.arange(len(row)) - np.searchsorted(row, row)
    table = np.full((n_rows, int(rank.max()) + 1 if len(rank) else 1), None, dtype=object)
    table[row, rank] = values
    return table
