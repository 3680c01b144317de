"""The map-layer schema of SPEC.md: read, validate and write GeoJSON map layers.

A map is one FeatureCollection in WGS84 whose features carry ``properties.class`` in
:data:`CLASSES`; ``sidewalk`` features also carry ``segment_id``, ``street`` and ``side``, and maps
that ``osmseg build`` wrote also ``facing_deg`` (the bearing from the street to the segment). A top-level
``"curbside"`` member holds metadata, ``buildings_source`` among it (:func:`buildings_source`). In
memory a map is a :class:`MapLayers`: a GeoDataFrame in the local UTM CRS plus that metadata.
"""

from __future__ import annotations

import json
import logging
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import geopandas as gpd
import numpy as np
import pandas as pd
import shapely

from curbside.errors import CurbsideInputError
from curbside.io import atomic_path
from curbside.osmseg.inputs import map_document
from curbside.projection import WGS84, utm_crs_for

if TYPE_CHECKING:
    from pyproj import CRS

log = logging.getLogger(__name__)

CLASSES: tuple[str, ...] = ("building", "street", "crosswalk", "sidewalk")
#: Values of the ``buildings_source`` metadata, where a map's building polygons came from: ``osmseg
#: build`` (OpenStreetMap), ``osmseg import-datasf`` (the DataSF 2013 footprints, with or without another
#: map's streets) and ``osmseg edit`` (a map saved by the editor, whatever it was made from).
BUILDINGS_SOURCES: tuple[str, ...] = ("osm", "datasf", "edited")


@dataclass
class MapLayers:
    """Map layers in a local metric CRS.

    Attributes
    ----------
    gdf
        One row per polygon: ``class``, ``geometry`` and, for sidewalks, ``segment_id``, ``street``,
        ``side`` (null elsewhere). CRS: local UTM.
    meta
        The ``"curbside"`` metadata member (``source``, ``bbox``, ``generator``, ``buildings_source``,
        ``params``...).
    """

    gdf: gpd.GeoDataFrame
    meta: dict[str, Any] = field(default_factory=dict)

    @property
    def crs(self) -> CRS:
        """The metric CRS of :attr:`gdf`."""
        return self.gdf.crs

    def layer(self, cls: str) -> gpd.GeoDataFrame:
        """Rows of one class (``building``, ``street``, ``crosswalk`` or ``sidewalk``)."""
        return self.gdf[self.gdf["class"] == cls]

    def union(self, cls: str) -> shapely.Geometry:
        """Union of all polygons of one class (an empty polygon when there are none)."""
        geoms = self.layer(cls).geometry.values
        return shapely.union_all(geoms) if len(geoms) else shapely.Polygon()


def buildings_source(meta: dict[str, Any]) -> str | None:
    """Where a map's buildings came from, one of :data:`BUILDINGS_SOURCES`, or ``None`` when unknown.

    Parameters
    ----------
    meta
        A map's ``"curbside"`` metadata member.

    Returns
    -------
    str or None
        Its ``buildings_source``. A file written before that field existed is judged by the rest of its
        metadata: ``edits`` (only the editor writes it) means ``"edited"``, an ``attribution`` naming
        DataSF ``"datasf"``, an ``osm_timestamp`` (only ``osmseg build`` writes it) ``"osm"``. ``None``
        for a map without such metadata (drawn in QGIS, geojson.io...) or with another value.
    """
    value = meta.get("buildings_source")
    if value is not None:
        return value if value in BUILDINGS_SOURCES else None
    if "edits" in meta:
        return "edited"
    if "DataSF" in str(meta.get("attribution") or ""):
        return "datasf"
    return "osm" if "osm_timestamp" in meta else None


def from_wgs84(gdf: gpd.GeoDataFrame, meta: dict[str, Any] | None = None) -> MapLayers:
    """Project a WGS84 layer table to its local UTM zone and wrap it as :class:`MapLayers`."""
    if len(gdf) == 0:
        raise ValueError("empty map")
    minx, miny, maxx, maxy = gdf.total_bounds
    crs = utm_crs_for((minx + maxx) / 2, (miny + maxy) / 2)
    out = gdf.to_crs(crs)
    for col in ("segment_id", "street", "side"):
        if col not in out:
            out[col] = None
    if "facing_deg" not in out:
        out["facing_deg"] = np.nan
    return MapLayers(out.reset_index(drop=True), dict(meta or {}))


def polygonal_parts(geoms: np.ndarray) -> np.ndarray:
    """The polygonal part of each geometry: polygons pass, collections and lines keep their polygons.

    ``make_valid`` turns a spike of a hand-drawn polygon into a stray line beside the polygon, and a
    zero-area polygon into a line; rasterised, such a line would become a one-cell-wide wall.

    Parameters
    ----------
    geoms
        Array of (valid) geometries.

    Returns
    -------
    numpy.ndarray
        Polygons and multipolygons unchanged; anything else replaced by the multipolygon of its
        polygons, or by an empty polygon when it has none.
    """
    geoms = np.array(geoms, dtype=object)
    other = np.flatnonzero(~np.isin(shapely.get_type_id(geoms), (3, 6)))
    if len(other) == 0:
        return geoms
    parts, owner = shapely.get_parts(geoms[other], return_index=True)
    parts, sub = shapely.get_parts(parts, return_index=True)
    owner = owner[sub]
    keep = shapely.get_type_id(parts) == 3
    geoms[other] = shapely.Polygon()
    if keep.any():
        owners, group = np.unique(owner[keep], return_inverse=True)
        geoms[other[owners]] = shapely.multipolygons(parts[keep], indices=group)
    return geoms


def _check_classes(path: Path, features: list, gdf: gpd.GeoDataFrame) -> None:
    """Refuse a map whose polygons lack a class or have one outside :data:`CLASSES`, naming the first.

    Other features (a marker left in a geojson.io file) are ignored, class or not.
    """
    classes = gdf["class"]
    polygon = gdf.geom_type.isin(["Polygon", "MultiPolygon"]).to_numpy()
    bad = np.flatnonzero(~np.isin(classes.astype(object).fillna("").astype(str), CLASSES) & polygon)
    if len(bad) == 0:
        return
    i = int(bad[0])
    feature = features[i] if isinstance(features[i], dict) else {}
    label = f"feature {i}" + (f" (id {feature['id']!r})" if "id" in feature else "")
    value = classes.iloc[i]
    what = (
        f"{label} has no properties.class" if value is None or value != value
        else f"unknown feature class {value!r} at {label}"
    )
    raise CurbsideInputError(path, f"{what} ({len(bad)} such polygon(s)); expected one of {list(CLASSES)}")


def _check_crs_member(path: Path, crs: Any) -> None:
    """Refuse a (pre-RFC 7946) ``crs`` member naming anything but WGS84 lon/lat.

    QGIS and GDAL write one when exporting from another CRS; coordinates of a projected CRS in small
    units (km, a local grid) could otherwise pass for degrees.
    """
    if crs is None:
        return
    props = crs.get("properties") if isinstance(crs, dict) else None
    name = str(props["name"]) if isinstance(props, dict) and "name" in props else json.dumps(crs)
    if not (name.endswith("CRS84") or name.endswith(":4326")):
        raise CurbsideInputError(
            path, f"declares CRS {name}: coordinates not WGS84 lon/lat (GeoJSON must be EPSG:4326); "
            "reproject it on export",
        )


def read_map(path: str | Path) -> MapLayers:
    """Read and validate a map GeoJSON (the automatic OSM map or a hand-labelled one).

    Parameters
    ----------
    path
        A GeoJSON FeatureCollection in WGS84 following SPEC.md.

    Returns
    -------
    MapLayers
        Projected to the local UTM zone; invalid polygons repaired with ``make_valid`` (a warning
        says how many), keeping only the polygonal part of the repair (:func:`polygonal_parts`):
        stray lines are dropped, and so is a feature left without area.

    Raises
    ------
    CurbsideInputError
        Missing or unreadable file, not a FeatureCollection, unknown classes, coordinates that are
        not lon/lat degrees, no polygons.
    """
    path = Path(path)
    doc = map_document(path)
    _check_crs_member(path, doc.get("crs"))
    features = doc.get("features") or []
    if not features:
        raise CurbsideInputError(path, "the map has no features")
    try:
        gdf = gpd.GeoDataFrame.from_features(features, crs=WGS84)
    except Exception as exc:  # noqa: BLE001 - shapely/geopandas raise many types for bad geometry
        raise CurbsideInputError(path, f"bad feature geometry ({exc})") from None
    if "class" not in gdf:  # no feature has one: name the first polygon, as when some lack it
        gdf["class"] = None
    _check_classes(path, features, gdf)
    gdf = gdf[~gdf.geometry.is_empty & gdf.geometry.notna()]
    gdf = gdf[gdf.geom_type.isin(["Polygon", "MultiPolygon"])]
    if len(gdf) == 0:
        raise CurbsideInputError(path, "the map has no polygons")
    minx, miny, maxx, maxy = gdf.total_bounds
    if not (-180 <= minx <= maxx <= 180 and -90 <= miny <= maxy <= 90):
        raise CurbsideInputError(
            path, "coordinates are not WGS84 lon/lat degrees (GeoJSON must be EPSG:4326)"
        )
    invalid = ~shapely.is_valid(gdf.geometry.values)
    gdf = gdf.set_geometry(polygonal_parts(shapely.make_valid(gdf.geometry.values)))
    collapsed = gdf.geometry.is_empty.to_numpy()
    if invalid.any():
        log.warning(
            "%s: repaired %d invalid (e.g. self-intersecting) polygon(s); %d had no area left and "
            "were dropped", path, int(invalid.sum()), int(collapsed.sum()),
        )
    gdf = gdf[~collapsed]
    if len(gdf) == 0:
        raise CurbsideInputError(path, "the map has no polygons with an area")
    if "facing_deg" in gdf:
        gdf = gdf.assign(facing_deg=_facing_bearings(path, gdf["facing_deg"]))
    meta = doc.get("curbside") if isinstance(doc.get("curbside"), dict) else {}
    return from_wgs84(gdf, meta)


def _facing_bearings(path: Path, values: pd.Series) -> np.ndarray:
    """``facing_deg`` as degrees in [0, 360) (absent: NaN); a value that is not a number is refused."""
    numbers = pd.to_numeric(values, errors="coerce")
    bad = numbers.isna() & values.notna() | ~np.isfinite(numbers.fillna(0.0))
    if bad.any():
        raise CurbsideInputError(
            path, f"properties.facing_deg must be a bearing in degrees; got {values[bad].iloc[0]!r} "
            f"({int(bad.sum())} such feature(s))",
        )
    return numbers.to_numpy(dtype=float) % 360.0


def _clean(value: Any) -> Any:
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return None
    if isinstance(value, np.generic):
        return value.item()
    return value


def to_geojson(layers: MapLayers, precision: int = 7) -> dict[str, Any]:
    """The map as a GeoJSON dict in WGS84, with the ``"curbside"`` metadata member."""
    gdf = layers.gdf.to_crs(WGS84)
    # Reprojection can make a valid metric polygon self-touch in degrees; snap-rounding needs valid input,
    # and the "structure" repair keeps polygons polygonal (no stray collapsed lines).
    valid = shapely.make_valid(gdf.geometry.values, method="structure", keep_collapsed=False)
    geoms = shapely.set_precision(valid, 10.0 ** -precision)
    geoms = shapely.make_valid(geoms)
    features = []
    facings = gdf["facing_deg"] if "facing_deg" in gdf else [None] * len(gdf)
    for cls, geom, seg, street, side, facing in zip(
        gdf["class"], geoms, gdf["segment_id"], gdf["street"], gdf["side"], facings, strict=True
    ):
        if geom is None or geom.is_empty:
            continue
        props: dict[str, Any] = {"class": cls}
        if cls == "sidewalk":
            props.update(segment_id=_clean(seg), street=_clean(street), side=_clean(side))
            if _clean(facing) is not None:
                props["facing_deg"] = round(float(facing), 1)
        features.append(
            {"type": "Feature", "properties": props, "geometry": shapely.geometry.mapping(geom)}
        )
    return {"type": "FeatureCollection", "curbside": layers.meta, "features": features}


def write_map(layers: MapLayers, path: str | Path) -> Path:
    """Write the map as GeoJSON (atomically: a temporary file renamed into place).

    Parameters
    ----------
    layers
        The map.
    path
        Destination ``.geojson``.

    Returns
    -------
    pathlib.Path
        ``path``.
    """
    path = Path(path)
    doc = to_geojson(layers)
    with atomic_path(path) as tmp:
        tmp.write_text(json.dumps(doc, separators=(",", ":"), ensure_ascii=False), encoding="utf-8")
    return path
