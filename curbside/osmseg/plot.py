"""Render map layers: a static PNG (matplotlib) or a self-contained interactive HTML map (Leaflet).

Both renderers work on any map of the schema in :mod:`curbside.osmseg.mapio`, including hand-labelled
maps with only some of the classes. Drawing happens in the map's local metric CRS (PNG) or in WGS84
(HTML); the optional ``bbox`` is always given in WGS84 degrees.
"""

from __future__ import annotations

import html
import logging
import math
from pathlib import Path

import geopandas as gpd
import shapely
from matplotlib.axes import Axes
from matplotlib.figure import Figure
from matplotlib.patches import Patch
from mpl_toolkits.axes_grid1.anchored_artists import AnchoredSizeBar

from curbside import __version__
from curbside.errors import CurbsideInputError
from curbside.io import atomic_path
from curbside.osmseg.inputs import output_format
from curbside.osmseg.mapio import MapLayers
from curbside.osmseg.style import BACKGROUND, CLASS_STYLE, CONFLICT_COLOUR, background_label
from curbside.osmseg.webmap import (
    attribution,
    bounds_js,
    class_features,
    class_overlay_js,
    conflict_overlay_js,
    leaflet_page,
    script_json,
    sidewalk_labels,
    swatch_label,
)
from curbside.projection import WGS84

log = logging.getLogger(__name__)

#: The smallest piece of building over sidewalk drawn (osmseg's sliver size: shared edges drawn twice
#: leave overlaps of a few square decimetres on any map).
MIN_CONFLICT_AREA_M2 = 0.5


def _degrees(value: float) -> str:
    """A longitude or latitude as given, to at most 6 decimals (0.1 m)."""
    return format(round(float(value), 6), ".10g")


def map_title(layers: MapLayers, bbox: tuple[float, float, float, float] | None = None) -> str:
    """``"curbside map layers: <source>"``, and the window shown when ``bbox`` is given.

    Parameters
    ----------
    layers
        The map (its ``source`` metadata names it).
    bbox
        The WGS84 ``(west, south, east, north)`` window drawn, if any.

    Returns
    -------
    str
        The title, e.g. ``"curbside map layers: sf.osm.bz2, bbox -122.408, 37.785, -122.403, 37.788"``.
    """
    source = layers.meta.get("source")
    if isinstance(source, list):
        source = ", ".join(map(str, source))
    title = f"curbside map layers: {source}" if source else "curbside map layers"
    if bbox is not None:
        title += ", bbox " + ", ".join(_degrees(v) for v in bbox)
    return title


def clip_to_bbox(layers: MapLayers, bbox: tuple[float, float, float, float]) -> MapLayers:
    """The part of a map inside a WGS84 bounding box.

    Parameters
    ----------
    layers
        The map.
    bbox
        ``(west, south, east, north)`` in degrees.

    Returns
    -------
    MapLayers
        Polygons clipped to the box (in the map's CRS); metadata copied, ``bbox`` replaced.

    Raises
    ------
    CurbsideInputError
        When no polygon of the map lies in the box.
    """
    box = gpd.GeoSeries([shapely.box(*bbox)], crs=WGS84).to_crs(layers.crs).iloc[0]
    clipped = layers.gdf.clip(box)
    clipped = clipped[clipped.geom_type.isin(["Polygon", "MultiPolygon"]) & ~clipped.is_empty]
    if len(clipped) == 0:
        raise CurbsideInputError("--bbox", f"{list(bbox)} contains no polygon of the map")
    return MapLayers(clipped.reset_index(drop=True), {**layers.meta, "bbox": list(bbox)})


def _nice_length(max_m: float) -> float:
    """The largest 1, 2 or 5 x 10^k metres not above ``max_m``."""
    power = 10.0 ** math.floor(math.log10(max_m))
    return max(m * power for m in (1, 2, 5) if m * power <= max_m)


def _scale_bar(ax: Axes, extent: tuple[float, float, float, float]) -> None:
    """A scale bar a fifth of the map wide at most, in the lower left, on a white box sized to the bar and
    its label (a box in map units grew with the map: on a tall one it covered a block)."""
    minx, _, maxx, _ = extent
    length = _nice_length((maxx - minx) / 5)
    label = f"{length / 1000:g} km" if length >= 1000 else f"{length:g} m"
    bar = AnchoredSizeBar(
        ax.transData, length, label, "lower left", pad=0.5, borderpad=0.8, sep=3, frameon=True,
        size_vertical=(maxx - minx) / 300, label_top=True, fontproperties={"size": 8},
    )
    bar.patch.set(facecolor="white", edgecolor="#999999", linewidth=0.5, alpha=0.85)
    bar.set_zorder(10)
    ax.add_artist(bar)


def sidewalk_under_buildings(layers: MapLayers) -> gpd.GeoSeries:
    """Where a building polygon covers a sidewalk polygon (empty for a map ``osmseg`` built, whose classes
    are disjoint): a building layer from another source or year than the streets."""
    buildings = layers.layer("building").geometry.values
    sidewalks = layers.layer("sidewalk").geometry.values
    if len(buildings) == 0 or len(sidewalks) == 0:
        return gpd.GeoSeries([], crs=layers.crs)
    i, j = shapely.STRtree(buildings).query(sidewalks, predicate="intersects")
    pieces = shapely.intersection(sidewalks[i], buildings[j])
    pieces = pieces[shapely.area(pieces) >= MIN_CONFLICT_AREA_M2]
    return gpd.GeoSeries(pieces, crs=layers.crs)


def plot_map(layers: MapLayers, ax: Axes, title: str | None = None) -> Axes:
    """Draw a map's classes, a legend, a scale bar and the attribution on a matplotlib axes; where its
    buildings stand on its sidewalks (:func:`sidewalk_under_buildings`), that area in red. The legend's
    background line says where the buildings came from (:func:`~curbside.osmseg.style.background_label`).

    Parameters
    ----------
    layers
        The map (local metric CRS, so the scale bar is in metres).
    ax
        Axes to draw on; its aspect is set to equal and its frame hidden.
    title
        Axes title (default: ``"curbside map layers: <source>"``).

    Returns
    -------
    matplotlib.axes.Axes
        ``ax``.
    """
    ax.set_facecolor(BACKGROUND)
    handles = []
    for cls, style in CLASS_STYLE.items():
        rows = layers.layer(cls)
        if len(rows) == 0:
            continue
        fill = {k: v for k, v in style.items() if k not in ("label", "hatch", "hatchcolor")}
        rows.geometry.plot(ax=ax, **fill)
        if "hatch" in style:
            # a second, unfilled pass: hatches take the edge colour on every matplotlib version
            stripes = {"facecolor": "none", "edgecolor": style["hatchcolor"], "hatch": style["hatch"]}
            rows.geometry.plot(ax=ax, linewidth=0.0, **stripes)
            fill = {**fill, **stripes, "facecolor": style["facecolor"]}
        handles.append(Patch(**fill, label=f"{style['label']} ({len(rows):,})"))
    handles.append(
        Patch(facecolor=BACKGROUND, edgecolor="#999999", linewidth=0.5, label=background_label(layers.meta))
    )
    conflict = sidewalk_under_buildings(layers)
    if len(conflict):
        conflict.plot(ax=ax, facecolor=CONFLICT_COLOUR, edgecolor="none", zorder=5)
        area_m2 = float(shapely.area(conflict.values).sum())
        handles.append(Patch(facecolor=CONFLICT_COLOUR, label=f"building over sidewalk ({area_m2:,.0f} m²)"))
    minx, miny, maxx, maxy = layers.gdf.total_bounds
    pad = 0.01 * max(maxx - minx, maxy - miny)
    extent = (minx - pad, miny - pad, maxx + pad, maxy + pad)
    ax.set_xlim(extent[0], extent[2])
    ax.set_ylim(extent[1], extent[3])
    ax.set_aspect("equal")
    ax.set_xticks([])
    ax.set_yticks([])
    ax.set_xlabel("")
    ax.set_ylabel("")
    for spine in ax.spines.values():
        spine.set_edgecolor("#999999")
    _scale_bar(ax, extent)
    # outside the map, right of it: a legend over the polygons would hide them
    ax.legend(handles=handles, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0.0, fontsize=8,
              frameon=False)
    ax.text(
        0.995, 0.005, attribution(layers), transform=ax.transAxes, ha="right", va="bottom", fontsize=7,
        bbox={"facecolor": "white", "edgecolor": "none", "alpha": 0.8, "pad": 1.5}, zorder=11,
    )
    ax.set_title(title or map_title(layers), fontsize=11)
    return ax


def save_png(
    layers: MapLayers, path: str | Path, width_in: float = 12.0, dpi: int = 200, title: str | None = None
) -> Path:
    """Render the map to a PNG file (atomically).

    Parameters
    ----------
    layers
        The map.
    path
        Destination ``.png``.
    width_in
        Width of the map in inches; the height follows the map's aspect ratio. The legend, right of the
        map, widens the image.
    dpi
        Resolution.
    title
        Title (default: :func:`map_title`).

    Returns
    -------
    pathlib.Path
        ``path``.
    """
    minx, miny, maxx, maxy = layers.gdf.total_bounds
    aspect = (maxy - miny) / max(maxx - minx, 1e-9)
    fig = Figure(figsize=(width_in, min(max(width_in * aspect, 4.0), 2.5 * width_in) + 0.6), dpi=dpi)
    ax = fig.add_axes((0.01, 0.01, 0.98, 0.94))
    plot_map(layers, ax, title)
    path = Path(path)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", facecolor="white", bbox_inches="tight", pad_inches=0.1,
                    metadata={"Software": f"curbside {__version__}"})
    log.info("wrote %s", path)
    return path


def html_page(layers: MapLayers, title: str | None = None, places: dict[str, str] | None = None) -> str:
    """A self-contained interactive map page: plain Leaflet, inlined, with no tile server.

    The page loads nothing: the vendored Leaflet script and stylesheet (``curbside/data/web``) and the
    polygons are inlined, so it opens offline. Each class present is one toggleable overlay in an
    expanded layer control, under which a swatch says what the background is
    (:func:`~curbside.osmseg.style.background_label`); sidewalk segments show the street with its
    compass side, ``segment_id`` and the OSM ``side`` in a tooltip and thicken their outline under the
    pointer. Coordinates are rounded to :data:`curbside.osmseg.webmap.COORDINATE_DECIMALS` for display.
    The attribution goes to Leaflet's attribution control.

    Parameters
    ----------
    layers
        The map.
    title
        Page title (default: :func:`map_title`).
    places
        The sidewalks' street and compass side (:func:`curbside.osmseg.webmap.sidewalk_labels`), taken
        on the whole map when ``layers`` is a window of it (default: taken on ``layers``).

    Returns
    -------
    str
        The HTML document.
    """
    by_class = class_features(layers, places=places)
    west, south, east, north = layers.gdf.to_crs(WGS84).total_bounds
    script = "\n".join(class_overlay_js(cls, f) for cls, f in by_class.items() if f)
    conflict = sidewalk_under_buildings(layers)
    if len(conflict):
        script += "\n" + conflict_overlay_js(conflict)
    script += "\n" + _background_legend_js(background_label(layers.meta))
    script += f"\nmap.fitBounds({bounds_js(west, south, east, north)});"
    return leaflet_page(
        title or map_title(layers), script, attribution_html=html.escape(attribution(layers)),
        page_css=".background-legend { margin-top: 5px; padding-top: 5px; border-top: 1px solid #ddd; }",
    )


def _background_legend_js(text: str) -> str:
    """A swatch of the background, labelled ``text``, below the layer control's overlays (a legend line,
    not a layer)."""
    label = swatch_label(BACKGROUND, "#999999", text)
    return (
        'const background = document.createElement("div");\n'
        'background.className = "background-legend";\n'
        f"background.innerHTML = {script_json(label)};\n"
        'layers.getContainer().querySelector(".leaflet-control-layers-list").append(background);'
    )


def save_html(
    layers: MapLayers, path: str | Path, title: str | None = None, places: dict[str, str] | None = None
) -> Path:
    """Write the self-contained interactive map of :func:`html_page` to an HTML file (atomically).

    Parameters
    ----------
    layers
        The map.
    path
        Destination ``.html``.
    title, places
        See :func:`html_page`.

    Returns
    -------
    pathlib.Path
        ``path``.
    """
    page = html_page(layers, title, places)
    path = Path(path)
    with atomic_path(path) as tmp:
        tmp.write_text(page, encoding="utf-8")
    log.info("wrote %s (%.1f MB)", path, path.stat().st_size / 1e6)
    return path


def render_map(
    layers: MapLayers, path: str | Path, bbox: tuple[float, float, float, float] | None = None
) -> Path:
    """Render a map to PNG or HTML, chosen by the extension of ``path``.

    Parameters
    ----------
    layers
        The map.
    path
        ``.png`` or ``.html`` / ``.htm``.
    bbox
        Optional WGS84 ``(west, south, east, north)`` window to show (named in the title).

    Returns
    -------
    pathlib.Path
        ``path``.

    Raises
    ------
    CurbsideInputError
        Unsupported extension, or a bbox with nothing of the map in it.
    """
    fmt = output_format(path)
    title = map_title(layers, bbox)
    shown = layers if bbox is None else clip_to_bbox(layers, bbox)
    if fmt == "png":
        return save_png(shown, path, title=title)
    return save_html(shown, path, title, places=sidewalk_labels(layers))  # sides found on the whole map
