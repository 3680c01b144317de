"""Global settings, in one place instead of hidden module globals (osmnx style).

Change them at run time, e.g. ``curbside.settings.cache_dir = Path("/tmp/cs")``.
"""

from __future__ import annotations

import os
from pathlib import Path

#: Root of the on-disk caches (Overpass responses, map rasters).
cache_dir: Path = Path(os.environ.get("CURBSIDE_CACHE_DIR", "cache"))

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

#: Default particle-filter parameters (the paper's values where it gives them).
default_particles: int = 500
default_jaywalk_weight: float = 0.4

#: Map-likelihood raster resolution in metres per cell.
raster_resolution_m: float = 0.5
