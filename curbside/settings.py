"""Global settings, in one place instead of hidden module globals (osmnx style).

Change them at run time, e.g. ``curbside.settings.cache_dir = Path("/tmp/cs")``.
"""

from __future__ import annotations

import os
from pathlib import Path

import platformdirs


def _default_cache_dir() -> Path:
    """``$CURBSIDE_CACHE_DIR`` if set, else the user's cache folder (``~/.cache/curbside`` on Linux)."""
    override = os.environ.get("CURBSIDE_CACHE_DIR")
    if override:
        return Path(override).expanduser()
    return Path(platformdirs.user_cache_dir("curbside", appauthor=False))


#: Root of the on-disk caches (:mod:`curbside.cache`): Overpass responses (``overpass/``), the
#: simulator's OSM tables (``osmsource/``), map rasters (``rasters/``). Safe to delete at any time.
cache_dir: Path = _default_cache_dir()

#: Seconds to wait for Overpass to accept a connection (and to answer its status query) before the
#: build gives up with a one-line error; a dead network fails in this time, not osmnx's minutes.
overpass_connect_timeout_s: float = 5.0

#: Seconds an Overpass query may run (osmnx's ``requests_timeout``) once the server is reachable.
overpass_timeout_s: float = 180.0

#: Where ``localize serve`` keeps the tracks of ended sessions (under ``tracks/``): the user's data folder
#: (``~/.local/share/curbside`` on Linux) unless ``CURBSIDE_DATA_DIR`` says otherwise.
data_dir: Path = Path(os.environ.get("CURBSIDE_DATA_DIR") or platformdirs.user_data_dir("curbside"))

#: The bundled OpenStreetMap extract (downtown San Francisco, 2026). © OpenStreetMap contributors, ODbL.
default_osm_file: Path = Path(__file__).parent / "data" / "sf-downtown-2026.osm.bz2"

#: Bounds of the bundled extract, (west, south, east, north) in WGS84 degrees.
default_extract_bbox: tuple[float, float, float, float] = (-122.4125, 37.7800, -122.3850, 37.8020)

#: Area built by ``osmseg build`` with no ``--bbox``: the whole bundled extract.
default_bbox: tuple[float, float, float, float] = default_extract_bbox

#: Largest bbox (km^2) osmseg accepts; larger areas should be split (Overpass and memory limits).
max_bbox_area_km2: float = 25.0

#: Attribution that must accompany any map or data derived from OpenStreetMap.
osm_attribution: str = "© OpenStreetMap contributors (ODbL 1.0)"


# --- RoNIN inertial odometry (curbside.localize.ronin). Its algorithm parameters are in
# curbside.localize.ronin.stream.RoninStreamConfig and curbside.localize.imu.ImuConfig. -----------------

#: Weights loaded by ``ronin_velocity`` when no model is given (state_dict + JSON config beside it).
ronin_default_weights: Path = Path(__file__).parent / "localize" / "ronin" / "weights" / "ronin_compact.pt"

# --- osmseg show / compare / import-datasf ------------------------------------------------------

#: Spacing (m) of the points sampled along class boundaries for ``osmseg compare``'s boundary distance.
compare_boundary_step_m: float = 1.0

#: ``osmseg compare`` looks for the nearest outline up to this far (m) outside the common extent.
compare_edge_margin_m: float = 25.0

#: DataSF footprints from different tiles overlapping with at least this IoU are one building twice.
datasf_duplicate_iou: float = 0.9

#: Polygon parts (m^2) below this left by repairing DataSF's self-intersecting rings are dropped.
datasf_min_area_m2: float = 1.0

#: GPX files rarely carry an accuracy radius; when a point has <hdop>, accuracy_m = hdop * this
#: user-equivalent range error (m). Without <hdop> the accuracy is NaN: the fix is invalid.
gpx_uere_m: float = 5.0

# ---------------------------------------------------------------------------------------------------
# evaluate: ground truth, metrics, simulator. Sources of each value in docs/evaluate.md.
# ---------------------------------------------------------------------------------------------------

#: Storey height used when an OSM building has ``building:levels`` but no ``height`` (metres).
evaluate_level_height_m: float = 3.5
#: Height of an OSM building with neither ``height`` nor ``building:levels`` (metres; ~3 storeys).
evaluate_default_height_m: float = 10.0
#: OSM ``highway`` values whose centrelines count as carriageways for mid-block (jaywalk) crossings.
evaluate_road_classes: tuple[str, ...] = (
    "primary", "primary_link", "secondary", "secondary_link", "tertiary", "tertiary_link",
    "residential", "unclassified", "living_street", "service", "busway",
)
#: Metrics: a ground truth farther than this from every sidewalk polygon is "on a crossing" (metres).
evaluate_on_sidewalk_m: float = 1.5
#: Metrics: on a crossing, sidewalk segments within this much of the nearest one count as joined (m).
evaluate_crossing_slack_m: float = 6.0
#: Metrics: RoNIN's relative-trajectory-error window (seconds).
evaluate_rte_window_s: float = 60.0

# --- osmseg build: derivation rules and widths ----------------------------------------------------
# Documented with their sources in docs/osmseg.md.

#: Carriageway width (m, curb to curb) per ``highway`` class when a way has neither ``width`` nor ``lanes``.
default_carriageway_width_m: dict[str, float] = {
    "motorway": 11.0, "motorway_link": 5.0, "trunk": 11.0, "trunk_link": 5.0,
    "primary": 13.0, "primary_link": 5.0, "secondary": 12.0, "secondary_link": 5.0,
    "tertiary": 10.0, "tertiary_link": 5.0, "residential": 8.0, "unclassified": 7.0,
    "living_street": 6.0, "service": 5.0, "busway": 7.0,
}  # fmt: skip

#: Width of one traffic lane (m) when the width comes from ``lanes`` (osm2streets uses 3.0 m too).
lane_width_m: float = 3.0

#: Width (m) of one side's on-street parking by ``parking:*`` orientation or ``parking:lane:*`` value.
parking_width_m: dict[str, float] = {"parallel": 2.2, "lane": 2.2, "diagonal": 4.5, "perpendicular": 5.0}

#: Parking assumed on each side of a street with sidewalks whose width comes from ``lanes`` and that
#: has no ``parking*`` tag (downtown streets mostly have curbside parking or loading lanes).
assumed_parking_width_m: float = 2.2

#: Narrowest half carriageway (m) after mapped sidewalks and building lines have capped it.
min_carriageway_half_width_m: float = 1.5

#: Width (m) of one painted cycle lane (``cycleway*=lane``).
cycle_lane_width_m: float = 1.5

#: ``highway`` classes whose sidewalks become ``sidewalk`` segments (motorways, service roads and
#: busways have none).
sidewalk_highways: frozenset[str] = frozenset({
    "trunk", "trunk_link", "primary", "primary_link", "secondary", "secondary_link",
    "tertiary", "tertiary_link", "residential", "unclassified", "living_street",
})  # fmt: skip

#: Depth (m) of a derived sidewalk, curb to building line, where no building is closer.
sidewalk_depth_m: float = 5.0

#: Least sidewalk (m) kept between a derived curb and the building line where no sidewalk is mapped.
min_sidewalk_width_m: float = 2.5

#: Width (m) of a separately mapped sidewalk (``footway=sidewalk``) without a ``width`` tag.
mapped_sidewalk_width_m: float = 2.0

#: How far (m) from a road's centreline a mapped sidewalk may lie and still set that side's curb.
mapped_sidewalk_search_m: float = 25.0

#: Width (m) of a crosswalk without a ``width`` tag (US crosswalks: 3 m / 10 ft).
crosswalk_width_m: float = 3.0

#: How far (m) crosswalks reach past the curb so that they join the sidewalk on both ends.
crosswalk_overlap_m: float = 0.5

#: Width (m) of a walkable passage carved through a building by a footway, corridor or platform
#: without a ``width`` tag (roads use their carriageway width).
passage_width_m: float = 3.0

#: Pieces of a carved building smaller than this (m^2), or thinner than
#: ``passage_island_thickness_m`` (2 x area / perimeter), are open floor between passages.
passage_island_area_m2: float = 200.0
passage_island_thickness_m: float = 5.0

#: What ``crossing=unmarked`` becomes: ``"crosswalk"`` or ``"street"``.
unmarked_crossing_as: str = "crosswalk"

#: Polygons smaller than this (m^2) are dropped as slivers.
min_polygon_area_m2: float = 0.5

# --- interactive HTML maps (osmseg show -o map.html) ---------------------------------------------------

#: Decimals of the lon/lat coordinates written into HTML maps (6 decimals ~ 0.1 m: display only; the
#: GeoJSON map files keep 7).
html_coordinate_decimals: int = 6
