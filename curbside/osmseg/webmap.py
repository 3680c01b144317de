"""Self-contained offline Leaflet pages: what the map page, the replay viewer and the map editor share.

Every page inlines the vendored Leaflet (``curbside/data/web``) and its data, loads nothing and uses no
tile server: the map classes are drawn from the map itself. The page skeleton (:func:`leaflet_page`)
creates ``map`` (canvas renderer), the © OpenStreetMap attribution, a scale bar and a layer control
``layers``, expanded unless the map is narrower than :data:`NARROW_MAP_PX`; each page adds its own
script after that.
"""

from __future__ import annotations

import html
import json
import re
from pathlib import Path

import geopandas as gpd
import shapely

from curbside import __version__, settings
from curbside.osmseg.mapio import MapLayers, to_geojson
from curbside.osmseg.places import sidewalk_places
from curbside.osmseg.style import BACKGROUND, CLASS_STYLE, CONFLICT_COLOUR, stroke_colour
from curbside.projection import WGS84

#: Decimals of the lon/lat coordinates written into pages (6 decimals ~ 0.1 m: display only; the
#: GeoJSON map files keep 7).
COORDINATE_DECIMALS = 6

#: A map narrower than this (CSS pixels: a phone held upright) gets its layer control folded.
NARROW_MAP_PX = 600

#: The layer control's button (three stacked sheets), inlined: Leaflet's own is a PNG file.
LAYERS_ICON = (
    "data:image/svg+xml,%3Csvg xmlns='http://www.w3.org/2000/svg' viewBox='0 0 26 26'%3E"
    "%3Cg stroke='%23333' stroke-width='1.6' stroke-linejoin='round'%3E"
    "%3Cpath d='M3 17l10 5 10-5' fill='none'/%3E%3Cpath d='M3 13l10 5 10-5' fill='none'/%3E"
    "%3Cpath d='M13 4 3 9l10 5 10-5z' fill='%23fff'/%3E%3C/g%3E%3C/svg%3E"
)

#: The vendored web libraries (scripts, stylesheets, licences); see ``curbside/data/web/README.md``.
WEB_ASSETS = Path(__file__).resolve().parents[1] / "data" / "web"
# The source maps are not vendored; without the comment no devtools asks for them.
_SOURCE_MAP = re.compile(r"^\s*(//# sourceMappingURL=\S+|/\*# sourceMappingURL=\S+ \*/)\s*$", re.MULTILINE)


def asset_text(name: str) -> str:
    """A vendored script or stylesheet, without its ``sourceMappingURL`` comment."""
    return _SOURCE_MAP.sub("", (WEB_ASSETS / name).read_text(encoding="utf-8"))


def script_json(value: object) -> str:
    """``value`` as JSON that can sit inside a ``<script>`` element (no ``</script>`` can close it)."""
    return json.dumps(value, separators=(",", ":"), ensure_ascii=False).replace("<", "\\u003c")


def attribution(layers: MapLayers | None) -> str:
    """The map's attribution (the OSM one when the map names none)."""
    meta = layers.meta if layers is not None else {}
    return str(meta.get("attribution") or settings.osm_attribution)


def sidewalk_labels(layers: MapLayers) -> dict[str, str]:
    """``segment_id`` -> ``"Market Street, north side"`` for every sidewalk segment of a map
    (:func:`curbside.osmseg.places.sidewalk_places`), for the tooltips."""
    return {segment_id: place.label for segment_id, place in sidewalk_places(layers).items()}


def class_features(
    layers: MapLayers, keep_properties: bool = False, places: dict[str, str] | None = None
) -> dict[str, list[dict]]:
    """The map's GeoJSON features by class, coordinates rounded to :data:`COORDINATE_DECIMALS`.

    Parameters
    ----------
    layers
        The map.
    keep_properties
        Keep every feature's properties; by default only sidewalks keep theirs (the layer says the class).
    places
        :func:`sidewalk_labels`, when ``layers`` is a window of a larger map: taken on the whole map, a
        segment at the window's edge still finds its own carriageway outside the window. Default: those
        of ``layers``.

    Returns
    -------
    dict
        ``{class: [feature, ...]}`` for every class of :data:`~curbside.osmseg.style.CLASS_STYLE`, in
        drawing order. Sidewalks with a ``segment_id`` also get ``place``, their street and compass side
        (:func:`sidewalk_labels`), for the tooltip.
    """
    doc = to_geojson(layers, precision=COORDINATE_DECIMALS)
    places = sidewalk_labels(layers) if places is None else places
    by_class: dict[str, list[dict]] = {cls: [] for cls in CLASS_STYLE}
    for feature in doc["features"]:
        props = feature["properties"]
        if props["class"] == "sidewalk" and props.get("segment_id") in places:
            feature = {**feature, "properties": {**props, "place": places[props["segment_id"]]}}
        elif not keep_properties and props["class"] != "sidewalk":
            feature = {**feature, "properties": {}}
        by_class[props["class"]].append(feature)
    return by_class


def swatch_label(colour: str, stroke: str, text: str) -> str:
    """Layer-control label: a colour swatch and the (escaped) text."""
    swatch = f'<span class="swatch" style="background:{colour};border-color:{stroke}"></span>'
    return f"{swatch} {html.escape(text)}"


def class_overlay_js(cls: str, features: list[dict], prefix: str = "", visible: bool = True) -> str:
    """One ``L.geoJson`` overlay statement: the class's polygons, style and layer-control label.

    Parameters
    ----------
    cls
        Map class.
    features
        Its GeoJSON features (WGS84).
    prefix
        Text before the label (the map's name when a page shows several maps).
    visible
        Add the overlay to the map (else only to the layer control).
    """
    fill, stroke = str(CLASS_STYLE[cls]["facecolor"]), stroke_colour(cls)
    path_style = {
        "fillColor": fill, "color": stroke, "weight": 0 if cls == "street" else 1,
        "opacity": 1, "fillOpacity": 0.9,
    }
    label = swatch_label(fill, stroke, f"{prefix}{CLASS_STYLE[cls]['label']} ({len(features):,})")
    collection = {"type": "FeatureCollection", "features": features}
    interactive = ", onEachFeature: describeSegment" if cls == "sidewalk" else ", interactive: false"
    add = ".addTo(map)" if visible else ""
    return (
        f"layers.addOverlay(L.geoJson({script_json(collection)}, "
        f"{{style: () => ({script_json(path_style)}){interactive}}}){add}, {script_json(label)});"
    )


def conflict_overlay_js(pieces: gpd.GeoSeries) -> str:
    """The overlay of :func:`curbside.osmseg.plot.sidewalk_under_buildings` (red, above the classes;
    area in its label)."""
    area_m2 = float(shapely.area(pieces.values).sum())
    shown = shapely.set_precision(pieces.to_crs(WGS84).values, 10.0**-COORDINATE_DECIMALS)
    features = [{"type": "Feature", "properties": {}, "geometry": json.loads(shapely.to_geojson(g))}
                for g in shown if not g.is_empty]
    style = {"fillColor": CONFLICT_COLOUR, "color": CONFLICT_COLOUR, "weight": 1, "fillOpacity": 0.9}
    label = swatch_label(CONFLICT_COLOUR, CONFLICT_COLOUR, f"building over sidewalk ({area_m2:,.0f} m²)")
    collection = {"type": "FeatureCollection", "features": features}
    return (
        f"layers.addOverlay(L.geoJson({script_json(collection)}, {{style: () => ({script_json(style)}), "
        f"interactive: false}}).addTo(map), {script_json(label)});"
    )


def bounds_js(west: float, south: float, east: float, north: float) -> str:
    """A Leaflet ``[[south, west], [north, east]]`` bounds literal."""
    return script_json([[south, west], [north, east]])


_PAGE = """<!DOCTYPE html>
<html lang="en">
<head>
<meta charset="utf-8">
<meta name="generator" content="curbside {version}">
<meta name="viewport" content="width=device-width, initial-scale=1.0">
<title>{title}</title>
{styles}
<style>
html, body {{ height: 100%; width: 100%; margin: 0; padding: 0; }}
#map {{ position: absolute; top: 0; bottom: 0; left: 0; right: 0; }}
.leaflet-container {{ background: {background}; }}
.leaflet-tooltip td:first-child {{ color: #666; padding-right: 0.6em; }}
.swatch {{ display: inline-block; width: 0.9em; height: 0.9em; border: 1px solid; vertical-align: -0.1em; }}
/* the folded layer control's button: leaflet.css would fetch images/layers.png from beside the page */
.leaflet-control-layers-toggle, .leaflet-retina .leaflet-control-layers-toggle {{
  background-image: url("{layers_icon}"); background-size: 26px 26px; }}
/* the attribution wraps beside the scale bar (at most 100 px wide) instead of running over it */
.leaflet-bottom.leaflet-right {{ max-width: calc(100% - 120px); }}
{page_css}
</style>
{scripts}
</head>
<body>
{body}
<script>
"use strict";
const map = L.map("map", {{preferCanvas: true, maxZoom: 22, zoomSnap: 0.25}});
map.attributionControl.addAttribution({attribution});
L.control.scale().addTo(map);
// on a phone-wide map the layer control folds into its button (tap it for the legend)
const layers = L.control.layers(null, null, {{collapsed: map.getSize().x < {narrow_px}}}).addTo(map);
const SEGMENT_FIELDS = [["segment", "segment_id"], ["OSM side", "side"]];
function segmentTable(layer) {{
  const props = layer.feature.properties;
  const box = document.createElement("div");
  const place = box.appendChild(document.createElement("strong"));
  place.textContent = props.place ?? props.street ?? "unnamed street";
  const table = box.appendChild(document.createElement("table"));
  for (const [label, key] of SEGMENT_FIELDS) {{
    const row = table.insertRow();
    row.insertCell().textContent = label;
    const value = props[key] ?? "\\u2014";
    row.insertCell().textContent = key === "side" && props[key] ? `${{value}} of the way as drawn` : value;
  }}
  return box;
}}
function describeSegment(feature, layer) {{
  layer.bindTooltip(segmentTable, {{sticky: true}});
  layer.on("mouseover", () => layer.setStyle({{weight: 3}}));
  layer.on("mouseout", () => layer.setStyle({{weight: 1}}));
}}
{script}
</script>
</body>
</html>
"""


def leaflet_page(
    title: str,
    script: str,
    *,
    attribution_html: str,
    body: str = '<div id="map"></div>',
    page_css: str = "",
    scripts: tuple[str, ...] = ("leaflet.js",),
    styles: tuple[str, ...] = ("leaflet.css",),
) -> str:
    """An offline Leaflet page: the vendored assets inlined, the map set up, then ``script``.

    Parameters
    ----------
    title
        Page title (escaped here).
    script
        JavaScript run after ``map`` and ``layers`` exist.
    attribution_html
        Attribution, already HTML-escaped.
    body
        Body markup before the script; must hold ``<div id="map">``.
    page_css
        The page's own CSS.
    scripts, styles
        Vendored assets to inline (names in :data:`WEB_ASSETS`), in order.

    Returns
    -------
    str
        The HTML document.
    """
    return _PAGE.format(
        version=__version__,
        title=html.escape(title),
        styles="\n".join(f"<style>\n{asset_text(name)}\n</style>" for name in styles),
        scripts="\n".join(f"<script>\n{asset_text(name)}\n</script>" for name in scripts),
        background=BACKGROUND,
        page_css=page_css,
        body=body,
        attribution=script_json(attribution_html),
        narrow_px=NARROW_MAP_PX,
        layers_icon=LAYERS_ICON,
        script=script,
    )
