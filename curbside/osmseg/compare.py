"""Compare two maps class by class: areas, IoU, boundary distance and counts over their common extent.

Works on any two maps of the schema (the automatic OSM map, a hand-labelled map, the DataSF building
footprints...). Everything is measured in map A's local metric CRS and only inside the overlap of the
two maps' extents, so a map covering a larger area is not penalised for what the other one never
covered. A map's extent is its metadata ``bbox`` when it has a valid one, else its polygons' bounds.

For each class present in either map:

- ``area_a_m2``, ``area_b_m2``: area of the union of the class's polygons inside the extent;
- ``iou``: intersection over union of those two areas;
- ``boundary_mean_m`` / ``boundary_median_m``: the symmetric boundary distance. Points are sampled
  every ``boundary_step_m`` (1 m) along A's class outline and their distance to B's
  outline is measured, and vice versa; the mean (median) is over both sets of points together, so it
  is a length-weighted average. Outlines are those of the whole polygons, so the extent's edge is
  never taken for an outline, and targets are looked for a little beyond it
  (``edge_margin_m``, 25 m) so that points near the edge find their true nearest outline.
- ``boundary_a_to_b_m`` / ``boundary_b_to_a_m``: the two directed means (A's outline to B's, and back);
  a large ``b_to_a`` with a small ``a_to_b`` means B has outlines A lacks (e.g. missing buildings).
- ``count_a``, ``count_b``: polygons of the class that intersect the extent.

A class a map does not have at all gives ``n/a`` (NaN) for that map's figures.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import geopandas as gpd
import numpy as np
import pandas as pd
import shapely

from curbside import __version__
from curbside.errors import CurbsideInputError
from curbside.io import atomic_path
from curbside.osmseg.mapio import CLASSES, MapLayers
from curbside.osmseg.summary import dissolve, format_table
from curbside.projection import WGS84

COLUMNS: tuple[str, ...] = (
    "count_a", "count_b", "area_a_m2", "area_b_m2", "iou", "boundary_mean_m", "boundary_median_m",
    "boundary_a_to_b_m", "boundary_b_to_a_m",
)


@dataclass
class MapComparison:
    """The result of :func:`compare_maps`.

    Attributes
    ----------
    table
        One row per class present in either map, columns :data:`COLUMNS` (NaN: not applicable).
    extent_wgs84
        The common extent compared, ``(west, south, east, north)`` in degrees.
    extent_area_m2
        Its area.
    boundary_step_m
        Spacing of the points sampled along the outlines for the boundary distance.
    """

    table: pd.DataFrame
    extent_wgs84: tuple[float, float, float, float]
    extent_area_m2: float
    boundary_step_m: float

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready form: ``extent`` and ``classes`` (NaN written as null)."""
        classes = {
            cls: {
                col: None if pd.isna(v) else int(v) if col.startswith("count") else float(v)
                for col, v in row.items()
            }
            for cls, row in self.table.iterrows()
        }
        return {
            "extent": {"bbox_wgs84": list(self.extent_wgs84), "area_m2": self.extent_area_m2},
            "boundary_step_m": self.boundary_step_m,
            "classes": classes,
        }


def map_extent(layers: MapLayers) -> tuple[float, float, float, float]:
    """A map's extent in WGS84: its metadata ``bbox`` if valid, else the bounds of its polygons."""
    bbox = layers.meta.get("bbox")
    if isinstance(bbox, (list, tuple)) and len(bbox) == 4:
        try:
            west, south, east, north = (float(v) for v in bbox)
        except (TypeError, ValueError):
            pass
        else:
            if -180 <= west < east <= 180 and -90 <= south < north <= 90:
                return west, south, east, north
    return tuple(float(v) for v in layers.gdf.to_crs(WGS84).total_bounds)


def _segments(lines: np.ndarray) -> np.ndarray:
    """Every two-point segment of an array of (multi)linestrings, for a fine-grained STRtree."""
    coords, index = shapely.get_coordinates(lines, return_index=True)
    same = index[1:] == index[:-1]
    return shapely.linestrings(np.stack([coords[:-1][same], coords[1:][same]], axis=1))


def _sample(lines: np.ndarray, step_m: float) -> np.ndarray:
    """Points spaced about ``step_m`` apart (centred in equal intervals) along (multi)linestrings.

    Interpolates on the vertex arrays with numpy instead of ``shapely.line_interpolate_point``, which
    walks a whole line for every point.
    """
    parts = shapely.get_parts(shapely.get_parts(lines))
    parts = parts[shapely.get_type_id(parts) == shapely.GeometryType.LINESTRING]
    coords, index = shapely.get_coordinates(parts, return_index=True)
    if len(coords) < 2:
        return np.empty(0, dtype=object)
    step_len = np.hypot(*np.diff(coords, axis=0).T) * (index[1:] == index[:-1])
    arc = np.concatenate([[0.0], np.cumsum(step_len)])
    first = np.searchsorted(index, np.arange(len(parts)))
    start = arc[first]
    length = shapely.length(parts)
    n = np.where(length > 0, np.maximum(np.ceil(length / step_m), 1), 0).astype(int)
    owner = np.repeat(np.arange(len(parts)), n)
    k = np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n)
    at = start[owner] + (k + 0.5) * length[owner] / n[owner]
    seg = np.clip(np.searchsorted(arc, at, side="right") - 1, 0, len(coords) - 2)
    frac = (at - arc[seg]) / np.where(step_len[seg] > 0, step_len[seg], 1.0)
    xy = coords[seg] + frac[:, None] * (coords[seg + 1] - coords[seg])
    return shapely.points(xy)


def _outline(parts: np.ndarray, region: shapely.Geometry) -> np.ndarray:
    """The pieces of the outlines of (unclipped) polygons that lie inside ``region``."""
    lines = shapely.intersection(shapely.boundary(parts), region)
    return lines[~shapely.is_empty(lines)]


def _distances(points: np.ndarray, target_lines: np.ndarray) -> np.ndarray:
    segments = _segments(target_lines)
    if len(points) == 0 or len(segments) == 0:
        return np.empty(0)
    (_, _), dist = shapely.STRtree(segments).query_nearest(points, return_distance=True, all_matches=False)
    return dist


def _class_figures(
    parts_a: np.ndarray | None,
    parts_b: np.ndarray | None,
    extent: shapely.Geometry,
    step: float,
    margin: float,
) -> dict[str, float]:
    search = shapely.buffer(extent, margin, join_style="mitre")
    figures: dict[str, float] = dict.fromkeys(COLUMNS[2:], math.nan)
    clipped = {}
    for key, parts in (("a", parts_a), ("b", parts_b)):
        if parts is None:
            continue
        inside = shapely.intersection(parts, extent)
        clipped[key] = inside[~shapely.is_empty(inside)]
        figures[f"area_{key}_m2"] = float(shapely.area(clipped[key]).sum())
    if parts_a is None or parts_b is None:
        return figures
    a, b = clipped["a"], clipped["b"]
    left, right = shapely.STRtree(b).query(a, predicate="intersects")
    inter = float(shapely.area(shapely.intersection(a[left], b[right])).sum())
    union = figures["area_a_m2"] + figures["area_b_m2"] - inter
    figures["iou"] = inter / union if union > 0 else math.nan
    points_a = _sample(_outline(parts_a, extent), step)
    points_b = _sample(_outline(parts_b, extent), step)
    a_to_b = _distances(points_a, _outline(parts_b, search))
    b_to_a = _distances(points_b, _outline(parts_a, search))
    dist = np.concatenate([a_to_b, b_to_a])
    if len(dist):
        figures["boundary_mean_m"] = float(dist.mean())
        figures["boundary_median_m"] = float(np.median(dist))
    for key, directed in (("a_to_b", a_to_b), ("b_to_a", b_to_a)):
        if len(directed):
            figures[f"boundary_{key}_m"] = float(directed.mean())
    return figures


def compare_maps(
    a: MapLayers,
    b: MapLayers,
    name_b: str = "map B",
    *,
    boundary_step_m: float = 1.0,
    edge_margin_m: float = 25.0,
) -> MapComparison:
    """Compare map ``b`` with map ``a`` class by class over their common extent.

    Parameters
    ----------
    a, b
        The two maps; ``b`` is projected into ``a``'s CRS.
    name_b
        How to name ``b`` in an error (e.g. its path).
    boundary_step_m
        Spacing (m) of the points sampled along class outlines for the boundary distance.
    edge_margin_m
        How far (m) outside the common extent the nearest outline is looked for.

    Returns
    -------
    MapComparison
        Per-class figures (see the module docstring) and the extent compared.

    Raises
    ------
    CurbsideInputError
        When the two maps' extents do not overlap.
    ValueError
        A step that is not positive or a negative margin.
    """
    if not (boundary_step_m > 0 and edge_margin_m >= 0):
        raise ValueError(
            f"need boundary_step_m > 0 and edge_margin_m >= 0, got {boundary_step_m}, {edge_margin_m}"
        )
    ext_a, ext_b = map_extent(a), map_extent(b)
    west, south = max(ext_a[0], ext_b[0]), max(ext_a[1], ext_b[1])
    east, north = min(ext_a[2], ext_b[2]), min(ext_a[3], ext_b[3])
    if not (west < east and south < north):
        raise CurbsideInputError(name_b, f"its extent {list(ext_b)} does not overlap map A's {list(ext_a)}")
    extent = gpd.GeoSeries([shapely.box(west, south, east, north)], crs=WGS84).to_crs(a.crs).iloc[0]
    gdf_b = b.gdf.to_crs(a.crs)
    rows = {}
    for cls in CLASSES:
        geoms = {}
        for key, gdf in (("a", a.gdf), ("b", gdf_b)):
            mask = (gdf["class"] == cls).to_numpy()
            geoms[key] = gdf.geometry.to_numpy()[mask] if mask.any() else None
        if geoms["a"] is None and geoms["b"] is None:
            continue
        row = {
            f"count_{key}": math.nan if g is None else int(shapely.intersects(g, extent).sum())
            for key, g in geoms.items()
        }
        parts = {key: None if g is None else dissolve(g) for key, g in geoms.items()}
        row.update(_class_figures(parts["a"], parts["b"], extent, boundary_step_m, edge_margin_m))
        rows[cls] = row
    table = pd.DataFrame.from_dict(rows, orient="index", columns=list(COLUMNS))
    table.index.name = "class"
    return MapComparison(table, (west, south, east, north), float(shapely.area(extent)), boundary_step_m)


def format_comparison(result: MapComparison, name_a: str = "A", name_b: str = "B") -> str:
    """The comparison as a text table, headed by the extent it covers."""
    west, south, east, north = result.extent_wgs84
    table = result.table.astype({"count_a": "Int64", "count_b": "Int64"})
    head = (
        f"A = {name_a}\nB = {name_b}\n"
        f"Compared only over the overlap of the two maps' extents: W {west:.5f} S {south:.5f} "
        f"E {east:.5f} N {north:.5f} ({result.extent_area_m2 / 1e6:.3f} km^2)"
    )
    text = format_table(
        table,
        headers={
            "count_a": "n A", "count_b": "n B", "area_a_m2": "area A m^2", "area_b_m2": "area B m^2",
            "iou": "IoU", "boundary_mean_m": "boundary mean m", "boundary_median_m": "median m",
            "boundary_a_to_b_m": "A->B m", "boundary_b_to_a_m": "B->A m",
        },
        digits={"area_a_m2": 0, "area_b_m2": 0, "iou": 3} | dict.fromkeys(COLUMNS[5:], 2),
    )
    return f"{head}\n{text}"


def write_comparison(result: MapComparison, path: str | Path, name_a: str, name_b: str) -> Path:
    """Write the comparison as JSON (atomically), with the two maps' names.

    Parameters
    ----------
    result
        From :func:`compare_maps`.
    path
        Destination ``.json``.
    name_a, name_b
        How to name the maps in the file (e.g. their paths).

    Returns
    -------
    pathlib.Path
        ``path``.
    """
    path = Path(path)
    doc = {"generator": f"curbside {__version__}", "a": name_a, "b": name_b, **result.to_dict()}
    with atomic_path(path) as tmp:
        tmp.write_text(json.dumps(doc, indent=2), encoding="utf-8")
    return path
