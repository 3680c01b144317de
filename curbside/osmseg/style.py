"""How the map classes look, in the PNG figures (:mod:`curbside.osmseg.plot`) and the HTML pages
(:mod:`curbside.osmseg.webmap`) alike."""

from __future__ import annotations

from typing import Any

from curbside.osmseg.mapio import buildings_source

#: Drawing style of each class: fill, outline, hatch and legend label. Drawn bottom to top in this order.
CLASS_STYLE: dict[str, dict[str, object]] = {
    "street": {"facecolor": "#8e9aab", "edgecolor": "none", "linewidth": 0.0, "label": "street (jaywalking)"},
    "crosswalk": {
        "facecolor": "#f4cf3a",
        "edgecolor": "#b8961b",
        "hatchcolor": "white",
        "hatch": "////",
        "linewidth": 0.3,
        "label": "crosswalk",
    },
    "sidewalk": {
        "facecolor": "#bfe5a6", "edgecolor": "#5f9a4a", "linewidth": 0.3, "label": "sidewalk segment"
    },
    "building": {"facecolor": "#6f4646", "edgecolor": "#3f2626", "linewidth": 0.2, "label": "building"},
}
#: One colour per tracking method, in every report figure and replay page: GNSS red, RoNIN+PF green,
#: the paper's method orange, curbside fused purple. Picked (from the Okabe-Ito palette, the purple
#: darkened) so that every pair stays apart for readers with red-green colour blindness too;
#: matplotlib's default red, green and orange merge under deuteranopia and protanopia.
METHOD_COLOURS: dict[str, str] = {
    "gnss": "#c8102e", "inertial": "#009e73", "paper": "#e69f00", "fused": "#7b2d8e"
}
#: The GNSS fixes and their accuracy circles (apart from every method's colour in the same way).
GNSS_FIX_COLOUR = "#3a9ad9"
#: Where a map's buildings stand on its own sidewalks (a map assembled from two sources).
CONFLICT_COLOUR = "#d62728"
#: Colour of the space no polygon covers.
BACKGROUND = "#f3efe6"
#: Legend label of that space on a map whose buildings' source is unknown. No polygon means no building
#: *in the map*, not open ground: where a source lacks building outlines (OSM in the bundled extract's
#: southern band, see ``docs/maps.md``) whole blocks are this colour.
BACKGROUND_LABEL = "free space (no building in this map)"
#: That label by where the map's buildings came from (:func:`curbside.osmseg.mapio.buildings_source`).
BACKGROUND_LABELS: dict[str, str] = {
    "osm": "free space (no building mapped in OSM)",
    "datasf": "free space (no building in the DataSF 2013 footprints)",
    "edited": "free space (no building in this hand-edited map)",
}


def background_label(meta: dict[str, Any]) -> str:
    """The legend label of the space no polygon covers, true to where the map's buildings came from.

    Parameters
    ----------
    meta
        The map's ``"curbside"`` metadata member.

    Returns
    -------
    str
        :data:`BACKGROUND_LABELS` of its :func:`~curbside.osmseg.mapio.buildings_source`, else
        :data:`BACKGROUND_LABEL`.
    """
    return BACKGROUND_LABELS.get(buildings_source(meta) or "", BACKGROUND_LABEL)


def stroke_colour(cls: str) -> str:
    """The outline colour of a class in HTML (its fill when it has no outline)."""
    style = CLASS_STYLE[cls]
    return str(style["edgecolor"] if style["edgecolor"] != "none" else style["facecolor"])
