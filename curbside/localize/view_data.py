"""The replay page's data: each run and session of :mod:`curbside.localize.view` as the JSON its script reads.

A run becomes its footsteps' times and positions, the panel's columns (sidewalk segment, ``segment_prob``,
error against the ground truth, ``accuracy_m``, ``n_eff``, recoveries so far), the names of its sidewalk
segments, where the estimate is off its segment (whole metres from it beyond
:data:`~curbside.localize.track_result.OFF_SIDEWALK_M`, and the wording the page fills:
:data:`~curbside.localize.track_result.OFF_SIDEWALK_TEXT`) and its particle clouds. A column the run's
track lacks is ``None``; the page then shows "—" in its cells, leaves the column out when no run has it,
and does not promise the 68 % radius in the legend of a run without ``accuracy_m``.

Particle clouds travel as base64 int16 offsets from each footstep's estimate in micro-degrees (exact
lon/lat to 0.1 m, ±3.6 km).
"""

from __future__ import annotations

import base64
import logging
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pandas as pd
import pyproj

from curbside.errors import CurbsideInputError
from curbside.evaluate.groundtruth import groundtruth_at
from curbside.evaluate.metrics import format_waypoint_summary, waypoint_errors, waypoint_summary
from curbside.localize.particle_store import ParticleClouds
from curbside.localize.session import Session
from curbside.localize.track_result import OFF_SIDEWALK_TEXT, off_sidewalk_m, sidewalk_shapes
from curbside.osmseg.mapio import MapLayers, read_map
from curbside.osmseg.webmap import sidewalk_labels
from curbside.projection import WGS84, LocalFrame

if TYPE_CHECKING:
    from curbside.localize.view import ViewRun

log = logging.getLogger(__name__)

#: Degrees per unit of the particle offsets sent to the page.
PAGE_OFFSET_UNIT_DEG = 1e-6
#: Clouds of more particles are drawn thinned to about this many (every k-th particle): the page
#: stays the size it had at the paper's N = 500, and a cloud of 500 dots shows its shape as well.
MAX_DRAWN_PARTICLES = 500


def _round(values: np.ndarray, decimals: int) -> list:
    values = np.round(np.asarray(values, float), decimals)
    return [None if not np.isfinite(v) else float(v) for v in values]


def _b64(values: np.ndarray, dtype: str) -> str:
    return base64.b64encode(np.ascontiguousarray(values, dtype=dtype).tobytes()).decode("ascii")


def cloud_data(clouds: ParticleClouds, every: int = 1) -> dict:
    """Every ``every``-th cloud as base64 little-endian int16 micro-degree offsets from its mean, each
    thinned to every k-th particle when it has more than :data:`MAX_DRAWN_PARTICLES`."""
    to_wgs84 = pyproj.Transformer.from_crs(pyproj.CRS(clouds.crs), WGS84, always_xy=True)
    stride = -(-clouds.n_particles // MAX_DRAWN_PARTICLES)
    drawn = (slice(None, None, every), slice(None, None, stride))
    lon, lat = to_wgs84.transform(clouds.x[drawn], clouds.y[drawn])
    ref_lon, ref_lat = np.mean(lon, axis=1), np.mean(lat, axis=1)
    limit = np.iinfo(np.int16).max
    dlon = np.rint((lon - ref_lon[:, None]) / PAGE_OFFSET_UNIT_DEG)
    dlat = np.rint((lat - ref_lat[:, None]) / PAGE_OFFSET_UNIT_DEG)
    far = int(np.count_nonzero((np.abs(dlon) > limit) | (np.abs(dlat) > limit)))
    if far:
        log.warning("%d particle(s) more than 3 km from their cloud's mean are drawn at the edge", far)
    out = {
        "t": _round(clouds.t[::every], 3),
        "n": lon.shape[1],
        "n_total": clouds.n_particles,
        "ref_lat": _round(ref_lat, 7),
        "ref_lon": _round(ref_lon, 7),
        "dlat": _b64(np.clip(dlat, -limit, limit), "<i2"),
        "dlon": _b64(np.clip(dlon, -limit, limit), "<i2"),
    }
    if clouds.weight is not None:
        weight = clouds.weight[drawn]
        peak = np.maximum(weight.max(axis=1, keepdims=True), 1e-300)
        out["alpha"] = _b64(np.rint(255 * weight / peak), "u1")
    return out


def truth_errors(run: ViewRun) -> tuple[list | None, str | None]:
    """Error against the ground truth at each footstep, and the waypoint-error summary line."""
    waypoints = run.session.waypoints if run.session is not None else None
    if waypoints is None or len(waypoints) < 2:
        return None, None
    track = run.track
    frame = LocalFrame.around(float(waypoints["lon"].iat[0]), float(waypoints["lat"].iat[0]))
    t = track["t"].to_numpy(float)
    gx, gy = groundtruth_at(waypoints, t, frame)
    ex, ey = frame.to_xy(track["lon"].to_numpy(float), track["lat"].to_numpy(float))
    errors = _round(np.hypot(ex - gx, ey - gy), 2)
    try:
        summary = format_waypoint_summary(waypoint_summary(waypoint_errors(track, waypoints)))
    except CurbsideInputError:
        summary = None
    return errors, summary


class SegmentNamer:
    """Reads each map once and names its sidewalk segments in words once ("Market Street, north side"):
    a page's map layers and its panel share them, and so do the pages of a report.

    Parameters
    ----------
    read
        Reads a map by path (default :func:`curbside.osmseg.mapio.read_map`).
    """

    def __init__(self, read: Callable[[str], MapLayers] | None = None) -> None:
        self._read = read or read_map
        self._maps: dict[str, MapLayers] = {}
        self._places: list[tuple[MapLayers, dict[str, str]]] = []
        self._unreadable: set[str] = set()

    def read(self, map_path: str) -> MapLayers:
        """The map at ``map_path``, read on the first call only (by absolute path)."""
        key = str(Path(map_path).resolve())
        if key not in self._maps:
            self._maps[key] = self._read(map_path)
        return self._maps[key]

    def places(self, layers: MapLayers) -> dict[str, str]:
        """``segment_id`` -> label of every sidewalk segment of ``layers`` (:func:`sidewalk_labels`, worked
        out on the first call for these layers only)."""
        for known, places in self._places:
            if known is layers:
                return places
        places = sidewalk_labels(layers)
        self._places.append((layers, places))
        return places

    def labels(self, map_path: str | None) -> dict[str, str]:
        """``segment_id`` -> label of every sidewalk segment of a map (empty when it cannot be read)."""
        if not map_path or map_path in self._unreadable:
            return {}
        try:
            return self.places(self.read(map_path))
        except (CurbsideInputError, OSError) as exc:
            log.warning("no street names for the segments of %s (%s)", map_path, exc)
            self._unreadable.add(map_path)
            return {}

    def of(self, segments: list | None, map_path: str | None) -> dict[str, str] | None:
        """The labels of the segments a run visits (``None`` without segments or names)."""
        if not segments:
            return None
        labels = self.labels(map_path)
        ids = {str(s) for s in segments if s is not None}
        named = {s: labels[s] for s in sorted(ids) if s in labels}
        return named or None


def _column(track: pd.DataFrame, name: str, decimals: int) -> list | None:
    return _round(track[name], decimals) if name in track else None


def _off_sidewalk(
    track: pd.DataFrame, segments: list | None, namer: SegmentNamer | None, segment_map: str | None
) -> list | None:
    """Whole metres from its segment where the estimate is off it (``None`` elsewhere): from the track's
    ``segment_distance_m``, or worked out on the segment map for a track without it (an older run, a
    report's scored track); ``None`` when neither can say."""
    if "segment_distance_m" in track:
        distance = track["segment_distance_m"].to_numpy(float)
    elif segments and namer is not None and namer.labels(segment_map):  # labels: the map reads
        layers = namer.read(segment_map)
        x, y = LocalFrame(pyproj.CRS(layers.crs)).to_xy(track["lon"], track["lat"])
        distance = sidewalk_shapes(layers).distances_m(segments, x, y)
    else:
        return None
    return _round(off_sidewalk_m(distance), 0)


def run_data(run: ViewRun, colour: str, cloud_every: int = 1, namer: SegmentNamer | None = None) -> dict:
    """One run as the page reads it (see the module docstring).

    Parameters
    ----------
    run
        The run.
    colour
        Its track colour.
    cloud_every
        Keep every ``cloud_every``-th particle cloud.
    namer
        Names its segments (none: the raw ids only).

    Returns
    -------
    dict
        ``label, colour, session, t, lat, lon`` and the panel's columns (``None`` where unknown).
    """
    track = run.track
    errors, summary = truth_errors(run)
    recovered = np.zeros(len(track), int)
    if "recovered" in track:
        recovered = track["recovered"].fillna(0).to_numpy(int)
    segments = None
    if "sidewalk_segment_id" in track:
        ids = track["sidewalk_segment_id"].astype(object)
        segments = ids.where(ids.notna(), None).tolist()
    segment_map = run.segment_map if run.segment_map is not None else run.map_path
    return {
        "label": run.label,
        "colour": colour,
        "session": run.session_key,
        "t": _round(track["t"], 3),
        "lat": _round(track["lat"], 7),
        "lon": _round(track["lon"], 7),
        "n_eff": _column(track, "n_eff", 1),
        "recoveries_so_far": np.cumsum(recovered > 0).tolist(),
        "recoveries": int(max(run.recoveries, int((recovered > 0).sum()))),
        "segment": segments,
        "segment_names": namer.of(segments, segment_map) if namer is not None else None,
        "off_sidewalk_m": _off_sidewalk(track, segments, namer, segment_map),
        "off_sidewalk_text": OFF_SIDEWALK_TEXT,
        "segment_prob": _column(track, "segment_prob", 3),
        "accuracy_m": _column(track, "accuracy_m", 1),
        "error_m": errors,
        "waypoint_summary": summary,
        "cloud": cloud_data(run.particles, cloud_every) if run.particles is not None else None,
    }


def session_data(session: Session, key: str) -> dict:
    """A session's GNSS fixes (with their accuracy) and ground truth, as the page reads them."""
    data: dict = {"key": key, "name": session.name, "gnss": None, "truth": None}
    if session.gnss is not None and len(session.gnss):
        g = session.gnss
        acc = g["accuracy_m"].to_numpy(float)
        valid = np.isfinite(acc) & (acc > 0)
        data["gnss"] = {
            "t": _round(g["t"][valid], 3),
            "lat": _round(g["lat"][valid], 7),
            "lon": _round(g["lon"][valid], 7),
            "acc": _round(acc[valid], 1),
        }
    if session.waypoints is not None and len(session.waypoints) >= 2:
        w = session.waypoints
        data["truth"] = {"t": _round(w["t"], 3), "lat": _round(w["lat"], 7), "lon": _round(w["lon"], 7)}
    return data
