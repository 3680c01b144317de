"""Global settings of the environment, in one place instead of hidden module globals (osmnx style).

Only the environment lives here: folders, network timeouts, the bundled data and its attribution, size
limits. Change them at run time, e.g. ``curbside.settings.cache_dir = Path("/tmp/cs")``. Algorithm
parameters are fields of the config dataclasses of the modules that use them
(:class:`curbside.osmseg.config.SegmentationConfig`, :class:`curbside.evaluate.metrics.MetricsConfig`,
:class:`curbside.evaluate.osmsource.OsmSourceConfig`, :mod:`curbside.localize.filter.config` ...).
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


#: Root of the on-disk caches (:mod:`curbside.cache`): Overpass answers (``overpass/``), Nominatim's
#: answers to ``osmseg build --place`` (``nominatim/``), the simulator's OSM tables (``osmsource/``), map
#: rasters (``rasters/``). Safe to delete at any time.
cache_dir: Path = _default_cache_dir()

#: Seconds to wait for Overpass or Nominatim to accept a connection (and Overpass to answer its status
#: query) before the build gives up with a one-line error; a dead network fails in this time.
overpass_connect_timeout_s: float = 5.0

#: Seconds an Overpass query may run once the server is reachable: written into the query as the
#: server's own time limit (it then stops with a "runtime error"); its answer is awaited 15 s longer.
overpass_timeout_s: float = 180.0

#: Seconds to wait before asking a busy Overpass server (HTTP 429, 503, 504) again, one per retry;
#: after the last the build gives up with a one-line error (osmnx alone retried every 55 s forever).
overpass_busy_waits_s: tuple[float, ...] = (10.0, 30.0)

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
