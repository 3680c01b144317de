"""The map editor: one offline HTML page to correct a map by hand and save it in curbside's schema.

``osmseg edit MAP -o edit.html`` writes a page that shows the map's polygons by class, editable with the
vendored Leaflet-Geoman plug-in (``curbside/data/web``): click a polygon (or pick it in the panel's list
of polygons, by keyboard too) to select it, then drag its vertices (a vertex is added by dragging a
mid-point marker, removed by a right click) or move, add and remove them by keyboard (vertex mode, ``V``),
change its class or its sidewalk fields, or delete it; the toolbar draws new polygons and rectangles of
a chosen class; *undo* (Ctrl+Z) takes back the last edit.
With a window (``--bbox``) the page shows and edits only the polygons that meet it, whole; the others
ride along unseen and are saved as they are. *Save* downloads a GeoJSON of the map schema
(:mod:`curbside.osmseg.mapio`) holding every polygon of the map file, in which

- every feature keeps its GeoJSON ``id``: its index in the map file the page was made from; drawn ones
  are ``new-1``, ``new-2``... Edited ones carry ``properties.edited`` (``geometry``, ``class``,
  ``fields``, ``drawn``, comma separated);
- the ``curbside`` metadata member keeps the original's (its ``bbox`` set to the original's extent
  when it had none, so that deleting a polygon at the edge does not shrink the map, its
  ``buildings_source`` set to ``edited``) and adds
  ``edits``: the file it was made from, when it was saved, the window (``null`` without one), and the
  ids of the features changed in each way (``geometry``, ``class``, ``fields``, ``drawn``,
  ``deleted``).

Unedited features, in the window or not, are saved exactly as they are in the map file. The saved file
is read like any map (:func:`curbside.osmseg.mapio.read_map` validates it), e.g. by
``osmseg compare auto.geojson hand.geojson`` or ``localize evaluate --maps auto.geojson hand.geojson``.
"""

from __future__ import annotations

import html
import json
import logging
from pathlib import Path

import shapely

import curbside
from curbside.errors import CurbsideInputError
from curbside.io import atomic_path
from curbside.osmseg.compare import map_extent
from curbside.osmseg.mapio import MapLayers, to_geojson
from curbside.osmseg.style import CLASS_STYLE, stroke_colour
from curbside.osmseg.webmap import asset_text, attribution, bounds_js, leaflet_page, script_json
from curbside.projection import WGS84

log = logging.getLogger(__name__)

#: Decimal places of the coordinates in the page and the saved file (1e-7 degree: about 1 cm).
EDIT_COORDINATE_DECIMALS = 7

#: The page's element that holds the features outside the window (JSON), saved unchanged.
KEPT_ELEMENT_ID = "edit-kept"

#: A WGS84 window: (west, south, east, north) in degrees.
BBox = tuple[float, float, float, float]


def file_features(path: str | Path) -> list[dict]:
    """The polygon features of a map file as they are written there, each with its index as ``id``.

    Read the file with :func:`curbside.osmseg.mapio.read_map` first: this keeps what it keeps (polygons
    of a known class) without repairing or rounding them, so that unedited features are saved unchanged.
    """
    doc = json.loads(Path(path).read_text(encoding="utf-8"))
    return [
        {**feature, "id": i}
        for i, feature in enumerate(doc["features"])
        if (feature.get("geometry") or {}).get("type") in ("Polygon", "MultiPolygon")
        and (feature.get("properties") or {}).get("class") in CLASS_STYLE
    ]


def window_features(features: list[dict], bbox: BBox) -> tuple[list[dict], list[dict]]:
    """Split a map's features into those that meet a WGS84 window and the others.

    Parameters
    ----------
    features
        GeoJSON features in WGS84 (:func:`file_features`).
    bbox
        ``(west, south, east, north)`` in degrees.

    Returns
    -------
    tuple of list of dict
        The features that meet the window (shown and editable in the page, whole: not clipped) and
        the others (saved unchanged), each in the input order.

    Raises
    ------
    CurbsideInputError
        When no polygon meets the window.
    """
    geometries = shapely.from_geojson([json.dumps(feature["geometry"]) for feature in features])
    # A polygon that crosses itself in the file still gets an answer: test its repaired outline.
    inside = shapely.intersects(shapely.make_valid(geometries), shapely.box(*bbox))
    if not inside.any():
        raise CurbsideInputError("--bbox", f"{list(bbox)} contains no polygon of the map")
    shown = [feature for feature, meets in zip(features, inside, strict=True) if meets]
    kept = [feature for feature, meets in zip(features, inside, strict=True) if not meets]
    return shown, kept


def editor_data(
    layers: MapLayers,
    source: str,
    features: list[dict] | None = None,
    kept: list[dict] | None = None,
    window: BBox | None = None,
) -> dict:
    """What the editor page needs: the features with ids, the metadata and the class styles.

    Parameters
    ----------
    layers
        The whole map (its metadata and extent go to the saved file).
    source
        Name of the map file (recorded in the saved file's provenance).
    features
        The features to show and edit, as written in the map file (:func:`file_features`); default:
        ``layers`` written out, numbered in order.
    kept
        Features of the map file not shown (outside ``window``: :func:`window_features`); the page
        saves them unchanged.
    window
        The WGS84 window the page opens on (recorded in ``edits.window``); default: the whole map.

    Returns
    -------
    dict
        ``source``, ``filename`` (the suggested name of the saved file), ``generator``, ``meta``,
        ``classes`` (``{class: {fill, stroke, label}}``), ``decimals``, ``window``, ``features`` and
        ``kept``.
    """
    doc = to_geojson(layers, precision=EDIT_COORDINATE_DECIMALS)
    # The saved map keeps the original's extent: without it, deleting a polygon at the edge of a map
    # that has no metadata bbox would shrink the area `osmseg compare` looks at and hide the deletion.
    # Whatever the map was made from, its saved buildings are the editor's (the legend says so).
    meta = {**doc["curbside"], "bbox": list(map_extent(layers)), "buildings_source": "edited"}
    if features is None:
        features = [{**feature, "id": i} for i, feature in enumerate(doc["features"])]
    classes = {  # in drawing order, bottom to top
        cls: {"fill": style["facecolor"], "stroke": stroke_colour(cls), "label": style["label"]}
        for cls, style in CLASS_STYLE.items()
    }
    return {
        "source": source,
        "filename": f"{Path(source).stem}-edited.geojson",
        "generator": f"curbside {curbside.__version__} osmseg edit",
        "meta": meta,
        "classes": classes,
        "decimals": EDIT_COORDINATE_DECIMALS,
        "window": None if window is None else [float(v) for v in window],
        "features": features,
        "kept": kept or [],
    }


def editor_page(
    layers: MapLayers,
    source: str,
    features: list[dict] | None = None,
    kept: list[dict] | None = None,
    window: BBox | None = None,
) -> str:
    """The self-contained editor page (Leaflet and Leaflet-Geoman inlined; no network).

    Parameters
    ----------
    layers, source, features, kept, window
        See :func:`editor_data`.

    Returns
    -------
    str
        The HTML document: ``EDIT`` (:func:`editor_data` but ``kept``, replaced by ``kept_count``) in
        the script, ``kept`` in the JSON element :data:`KEPT_ELEMENT_ID`.
    """
    west, south, east, north = window if window is not None else layers.gdf.to_crs(WGS84).total_bounds
    data = editor_data(layers, source, features, kept, window)
    # The features outside the window wait as JSON text, parsed only on saving: as part of `EDIT` they
    # would be compiled as a script on load (the whole map's worth, for a window of a few hundred).
    kept_json = script_json(data.pop("kept"))
    script = "\n".join(
        [
            f"const EDIT = {script_json({**data, 'kept_count': len(kept or [])})};",
            f"map.fitBounds({bounds_js(west, south, east, north)});",
            asset_text("curbside-edit-vertex.js"),  # vertex mode: definitions used by the next
            asset_text("curbside-edit.js"),
        ]
    )
    return leaflet_page(
        f"curbside map editor: {Path(source).name}",
        script,
        attribution_html=html.escape(attribution(layers)),
        body=(
            f"{asset_text('curbside-edit.html')}\n"
            f'<script type="application/json" id="{KEPT_ELEMENT_ID}">{kept_json}</script>'
        ),
        page_css=asset_text("curbside-edit.css"),
        scripts=("leaflet.js", "leaflet-geoman.min.js"),
        styles=("leaflet.css", "leaflet-geoman.css"),
    )


def write_editor(
    layers: MapLayers,
    source: str,
    path: str | Path,
    features: list[dict] | None = None,
    kept: list[dict] | None = None,
    window: BBox | None = None,
) -> Path:
    """Write :func:`editor_page` to an HTML file (atomically).

    Returns
    -------
    pathlib.Path
        ``path``.
    """
    page = editor_page(layers, source, features, kept, window)
    path = Path(path)
    with atomic_path(path) as tmp:
        tmp.write_text(page, encoding="utf-8")
    log.info("wrote %s (%.1f MB)", path, path.stat().st_size / 1e6)
    return path
