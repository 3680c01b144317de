"""Small synthetic maps shared by the filter and raster tests (metres in UTM zone 10, downtown SF)."""

from __future__ import annotations

import geopandas as gpd
import shapely

from curbside.localize.filter import MotionConfig
from curbside.osmseg.mapio import MapLayers

UTM10 = 32610
X0, Y0 = 551000.0, 4182000.0  # downtown San Francisco in EPSG:32610
#: A motion model without noise: its cloud does not widen between fixes (as a cloud the map's walls cut
#: at corners does not, while the walker's error grows).
QUIET_MOTION = MotionConfig(
    step_noise_fraction=0.0,
    step_noise_floor_m=0.0,
    heading_noise_deg=0.0,
    scale_noise_per_step=0.0,
    scale_init_sigma=0.0,
)


def box(x0: float, y0: float, x1: float, y1: float) -> shapely.Polygon:
    """A rectangle relative to ``(X0, Y0)``."""
    return shapely.box(X0 + x0, Y0 + y0, X0 + x1, Y0 + y1)


def block_map() -> MapLayers:
    """A street along x with a crosswalk, a sidewalk north of it and a building beyond."""
    rows = [
        ("street", box(-100, -6, 100, 6), None),
        ("crosswalk", box(-3, -6, 3, 6), None),
        ("sidewalk", box(-100, 6, 100, 10), "N1"),
        ("building", box(-100, 10, 100, 60), None),
    ]
    gdf = gpd.GeoDataFrame(
        {"class": [r[0] for r in rows], "segment_id": [r[2] for r in rows], "street": None, "side": None},
        geometry=[r[1] for r in rows],
        crs=UTM10,
    )
    return MapLayers(gdf)


def shifted_building_map() -> MapLayers:
    """:func:`block_map` with its building drawn 2 m too far south, over half of the sidewalk (a building
    layer from another source than the streets)."""
    layers = block_map()
    gdf = layers.gdf.copy()
    gdf.loc[gdf["class"] == "building", "geometry"] = box(-100, 8, 100, 60)
    return MapLayers(gdf)


def two_sidewalk_map() -> MapLayers:
    """A street along x with a sidewalk on each side: "N" (6 < y < 10) and "S" (-10 < y < -6)."""
    bands = ((-6, 6), (6, 10), (-10, -6), (40, 45))
    geoms = [box(-100, y0, 100, y1) for y0, y1 in bands]
    gdf = gpd.GeoDataFrame(
        {
            "class": ["street", "sidewalk", "sidewalk", "building"],
            "segment_id": [None, "N", "S", None],
            "street": None,
            "side": None,
        },
        geometry=geoms,
        crs=UTM10,
    )
    return MapLayers(gdf)


def blocked_sidewalk_map() -> MapLayers:
    """A sidewalk along x (0 < y < 4) between buildings, with a wall across it at 40 < x < 44: a
    building the map has and the street does not (an old or misdrawn footprint)."""
    rows = [
        ("sidewalk", box(-40, 0, 200, 4), "E"),
        ("building", box(-40, 4, 200, 40), None),
        ("building", box(-40, -40, 200, 0), None),
        ("building", box(40, 0, 44, 4), None),
    ]
    gdf = gpd.GeoDataFrame(
        {"class": [r[0] for r in rows], "segment_id": [r[2] for r in rows], "street": None, "side": None},
        geometry=[r[1] for r in rows],
        crs=UTM10,
    )
    return MapLayers(gdf)
