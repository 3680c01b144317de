"""The map editor: one offline HTML page to correct a map by hand and save it in curbside's schema.

``osmseg edit MAP -o edit.html`` writes a page that shows the map's polygons by class, editable with the
vendored Leaflet-Geoman plug-in (``curbside/data/web``): click a polygon to select it, then drag its
vertices (a vertex is added by dragging a mid-point marker, removed by a right click), change its class
or its sidewalk fields, or delete it; the toolbar draws new polygons and rectangles of a chosen class.
*Save* downloads a GeoJSON of the map schema (:mod:`curbside.osmseg.mapio`) in which

- every feature keeps its GeoJSON ``id``: its index in the map file the page was made from (with
  ``--bbox``, in the clipped map); drawn ones are ``new-1``, ``new-2``... Edited ones carry
  ``properties.edited`` (``geometry``, ``class``, ``fields``, ``drawn``, comma separated);
- the ``curbside`` metadata member keeps the original's (its ``bbox`` set to the original's extent
  when it had none, so that deleting a polygon at the edge does not shrink the map, its
  ``buildings_source`` set to ``edited``) and adds
  ``edits``: the file it was made from, when it was saved, and the ids of the features changed in
  each way (``geometry``, ``class``, ``fields``, ``drawn``, ``deleted``).

Unedited features are saved exactly as they are in the map file (with ``--bbox``: as clipped). The
saved file is read like any map (:func:`curbside.osmseg.mapio.read_map` validates it), e.g. by
``osmseg compare auto.geojson hand.geojson`` or ``localize evaluate --maps auto.geojson hand.geojson``.
"""

from __future__ import annotations

import html
import json
import logging
from pathlib import Path

import curbside
from curbside.io import atomic_path
from curbside.osmseg.compare import map_extent
from curbside.osmseg.mapio import MapLayers, to_geojson
from curbside.osmseg.style import CLASS_STYLE, stroke_colour
from curbside.osmseg.webmap import asset_text, attribution, bounds_js, leaflet_page, script_json
from curbside.projection import WGS84

log = logging.getLogger(__name__)

#: Decimal places of the coordinates in the page and the saved file (1e-7 degree: about 1 cm).
EDIT_COORDINATE_DECIMALS = 7


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


def editor_data(layers: MapLayers, source: str, features: list[dict] | None = None) -> dict:
    """What the editor page needs: the features with ids, the metadata and the class styles.

    Parameters
    ----------
    layers
        The map to edit.
    source
        Name of the map file (recorded in the saved file's provenance).
    features
        The features as written in the map file (:func:`file_features`); default: ``layers`` written
        out, numbered in order.

    Returns
    -------
    dict
        ``source``, ``filename`` (the suggested name of the saved file), ``generator``, ``meta``,
        ``classes`` (``{class: {fill, stroke, label}}``) and ``features``.
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
        "features": features,
    }


def editor_page(layers: MapLayers, source: str, features: list[dict] | None = None) -> str:
    """The self-contained editor page (Leaflet and Leaflet-Geoman inlined; no network).

    Parameters
    ----------
    layers
        The map to edit.
    source
        Name of the map file.
    features
        See :func:`editor_data`.

    Returns
    -------
    str
        The HTML document.
    """
    west, south, east, north = layers.gdf.to_crs(WGS84).total_bounds
    script = "\n".join(
        [
            f"const EDIT = {script_json(editor_data(layers, source, features))};",
            f"map.fitBounds({bounds_js(west, south, east, north)});",
            asset_text("curbside-edit.js"),
        ]
    )
    return leaflet_page(
        f"curbside map editor: {Path(source).name}",
        script,
        attribution_html=html.escape(attribution(layers)),
        body=asset_text("curbside-edit.html"),
        page_css=asset_text("curbside-edit.css"),
        scripts=("leaflet.js", "leaflet-geoman.min.js"),
        styles=("leaflet.css", "leaflet-geoman.css"),
    )


def write_editor(
    layers: MapLayers, source: str, path: str | Path, features: list[dict] | None = None
) -> Path:
    """Write :func:`editor_page` to an HTML file (atomically).

    Returns
    -------
    pathlib.Path
        ``path``.
    """
    page = editor_page(layers, source, features)
    path = Path(path)
    with atomic_path(path) as tmp:
        tmp.write_text(page, encoding="utf-8")
    log.info("wrote %s (%.1f MB)", path, path.stat().st_size / 1e6)
    return path
