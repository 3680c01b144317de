"""Which side of which street, in words: "Market Street, north side" for a map's sidewalk segments.

A map's ``sidewalk`` features carry ``segment_id``, ``street`` and ``side``, the side being ``left`` or
``right`` of the OSM way's drawing direction: exact, but no use to a walker, who needs the compass
side. A map that ``osmseg build`` wrote also carries ``facing_deg``, the bearing from the street's
centreline to the segment (:func:`curbside.osmseg.sidewalks.facing_bearings_deg`), and
:func:`sidewalk_places` names its eighth of the compass: north (bearing 337.5°-22.5°), northeast
(22.5°-67.5°) and so on. Four points are not enough: San Francisco's Market Street runs at a bearing
of 45-47°, right between "north" and "west", and a four-point side would flip from one block to the
next; its sides are the northwest and southeast sides.

A map without ``facing_deg`` (drawn by hand, or built before it existed) has no centrelines, so the side
is read from the polygons (:func:`compass_sides`):

1. the street's direction along the segment is the long axis of the segment's minimum rotated
   rectangle (a sidewalk segment is a band along one side of one block);
2. the carriageway (the map's ``street`` polygons) point nearest to the segment's centroid gives the
   way from the street to the sidewalk; its component across the street's direction, turned into a
   bearing, names the side.

That reading is wrong for short pieces at corners, whose long axis or nearest carriageway may be the
cross street's: on the bundled map built from the extract, 107 of its 2,735 segments (3.9 %) got a
side a quarter turn or more from their centreline's, 28 of them the opposite side.

A segment with no carriageway within ``reach_m`` (a hand-drawn map without ``street`` polygons, a
footway) gets no side; its label is the street name alone.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import shapely

from curbside.osmseg.mapio import MapLayers

#: Compass sides by eighth of the bearing from the street to the sidewalk (0 = north, clockwise).
COMPASS_SIDES = ("north", "northeast", "east", "southeast", "south", "southwest", "west", "northwest")


@dataclass(frozen=True)
class SidewalkPlace:
    """One sidewalk segment in words.

    Attributes
    ----------
    segment_id
        The map's ``segment_id``.
    street
        Street name (``None`` when the map has none).
    side
        One of :data:`COMPASS_SIDES` (``None`` with no carriageway nearby).
    label
        ``"Market Street, north side"``; ``"unnamed street, east side"``; the name alone without a side.
    """

    segment_id: str
    street: str | None
    side: str | None
    label: str


def _long_axes(polygons: np.ndarray) -> np.ndarray:
    """Unit vectors ``(K, 2)`` along the long side of each polygon's minimum rotated rectangle."""
    rect = shapely.get_coordinates(shapely.oriented_envelope(polygons), return_index=False)
    corners = rect.reshape(len(polygons), -1, 2)[:, :3]  # a closed 5-point ring: corners 0, 1, 2
    a, b = corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 1]
    longer = np.where((np.hypot(*a.T) >= np.hypot(*b.T))[:, None], a, b)
    norm = np.hypot(*longer.T)[:, None]
    return np.divide(longer, norm, out=np.zeros_like(longer), where=norm > 0)


def compass_sides(sidewalks: np.ndarray, streets: np.ndarray, reach_m: float = 25.0) -> list[str | None]:
    """The compass side of each sidewalk polygon relative to the nearest carriageway polygon.

    Parameters
    ----------
    sidewalks, streets
        Shapely polygons in a metric CRS.
    reach_m
        Carriageway further than this from a segment's centroid does not count.

    Returns
    -------
    list
        One of :data:`COMPASS_SIDES` or ``None`` per sidewalk.
    """
    out: list[str | None] = [None] * len(sidewalks)
    if len(sidewalks) == 0 or len(streets) == 0:
        return out
    centroids = shapely.centroid(sidewalks)
    tree = shapely.STRtree(streets)
    which, nearest = tree.query_nearest(centroids, max_distance=reach_m, all_matches=False)
    if len(which) == 0:
        return out
    lines = shapely.shortest_line(streets[nearest], centroids[which])
    ends = shapely.get_coordinates(lines).reshape(-1, 2, 2)
    away = ends[:, 1] - ends[:, 0]  # from the carriageway to the sidewalk
    along = _long_axes(sidewalks[which])
    across = away - (away * along).sum(axis=1, keepdims=True) * along
    bearing = np.degrees(np.arctan2(across[:, 0], across[:, 1])) % 360.0
    usable = np.hypot(*across.T) > 1e-6  # a centroid on the carriageway has no side
    for i, side in zip(which[usable], compass_names(bearing[usable]), strict=True):
        out[int(i)] = side
    return out


def compass_names(bearing_deg: np.ndarray) -> list[str]:
    """The eighth of the compass (:data:`COMPASS_SIDES`) each bearing falls in."""
    sector = (((np.asarray(bearing_deg, dtype=float) + 22.5) % 360.0) // 45.0).astype(int)
    return [COMPASS_SIDES[q] for q in sector]


def sidewalk_places(map_layers: MapLayers, reach_m: float = 25.0) -> dict[str, SidewalkPlace]:
    """Every sidewalk segment of a map in words, by ``segment_id`` (see the module docstring).

    Parameters
    ----------
    map_layers
        A map with ``sidewalk`` features (with ``facing_deg``, or ``street`` polygons, for the sides).
    reach_m
        See :func:`compass_sides`.

    Returns
    -------
    dict
        ``segment_id`` -> :class:`SidewalkPlace` (empty for a map without sidewalk segments).
    """
    sidewalks = map_layers.layer("sidewalk")
    if len(sidewalks) == 0 or "segment_id" not in sidewalks:
        return {}
    streets = map_layers.layer("street").geometry.to_numpy()
    sides = compass_sides(sidewalks.geometry.to_numpy(), streets, reach_m)
    facing = sidewalks["facing_deg"].to_numpy(dtype=float) if "facing_deg" in sidewalks else np.array([])
    known = np.flatnonzero(np.isfinite(facing))
    for i, side in zip(known, compass_names(facing[known]), strict=True):
        sides[i] = side
    names = sidewalks["street"] if "street" in sidewalks else [None] * len(sidewalks)
    places = {}
    for segment_id, name, side in zip(sidewalks["segment_id"], names, sides, strict=True):
        street = name if isinstance(name, str) and name else None
        label = street or "unnamed street"
        if side is not None:
            label = f"{label}, {side} side"
        places[str(segment_id)] = SidewalkPlace(str(segment_id), street, side, label)
    return places
