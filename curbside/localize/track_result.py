"""What a tracking run gives, in one batch (:func:`~curbside.localize.pipeline.track_session`) or live
(:class:`~curbside.localize.live.LiveSession`): :class:`TrackResult`, its ``track.csv`` table of the
engine's rows (:func:`track_table`), and the finished tracker's counts (:func:`tracker_record`).

It also says where the estimate is in words, the one wording of the service and the replay page: the
named sidewalk segment's label ("Market Street, north side"), or, when the estimate lies more than
:data:`OFF_SIDEWALK_M` from that segment's polygon, :data:`OFF_SIDEWALK_TEXT` (:func:`place_text`).
The filter names the segment its particles' weight favours, and particles up to
``filter.map.segment_reach_m`` (25 m) from a sidewalk count for it, so a named segment alone does not
say that the walker is on it. An app that calls :class:`~curbside.localize.filter.Tracker` itself gets
the same words and distance per estimate from :class:`EstimatePlaces`.
"""

from __future__ import annotations

import math
import weakref
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
import pandas as pd
import shapely

from curbside.errors import CurbsideValueError
from curbside.localize.engine import Row
from curbside.localize.filter.particles import Estimate
from curbside.localize.filter.tracker import Tracker
from curbside.localize.runconfig import RunConfig
from curbside.osmseg.mapio import MapLayers
from curbside.osmseg.places import sidewalk_places
from curbside.projection import LocalFrame

#: Columns of ``track.csv`` in order (:data:`SEGMENT_COLUMNS` follow when the map has sidewalks).
TRACK_COLUMNS = (
    "t",
    "lat",
    "lon",
    "x_m",
    "y_m",
    "accuracy_m",
    "update",
    "gnss_used",
    "theta_drift_deg",
    "speed_scale",
    "n_eff",
    "recovered",
    "injected",
    "motion",
)

#: Columns added with a map that has sidewalk segments: the filter's MAP segment (the polygon under the
#: estimate in ``gnss`` mode), its posterior probability (empty in ``gnss`` mode), the mode estimate and
#: the distance (m) from ``x_m, y_m`` to that segment's polygon (0 on it; empty without a segment).
SEGMENT_COLUMNS = ("sidewalk_segment_id", "segment_prob", "mode_lat", "mode_lon", "segment_distance_m")

#: An estimate farther than this (m) from the sidewalk segment it names is said to be off the sidewalk.
#: The map's sidewalks are 2.5-5 m deep (``osmseg``: ``min_sidewalk_width_m`` 2.5, ``sidewalk_depth_m``
#: 5; the San Francisco map's median 5.0 m, 5th percentile 2.6 m), and its curbs are placed within
#: about 1 m: an estimate more than 3 m out is farther from the sidewalk than its narrowest sidewalks
#: are deep, and three curb errors beyond it (docs/filter.md, "How far the estimate is from its segment").
OFF_SIDEWALK_M = 3.0
#: The place in words when the estimate is off its sidewalk (``str.format`` fields: the whole metres
#: and the segment's label). The replay page fills the same template.
OFF_SIDEWALK_TEXT = "off the sidewalk, {distance_m} m from {place}"


@dataclass
class TrackResult:
    """The output of :func:`~curbside.localize.pipeline.track_session`.

    Attributes
    ----------
    track
        One row per update: :data:`TRACK_COLUMNS` (and :data:`SEGMENT_COLUMNS` with a map with sidewalks).
    config
        The whole run configuration (``run.json``'s ``config``).
    velocity_source, step_source
        Where the velocity and the footsteps came from (``None`` for velocity in ``gnss`` mode).
    recoveries, injections, heading_corrections
        Collapses re-seeded; particles injected by the divergence recovery; re-draws of the heading
        correction (:func:`tracker_record`).
    calibration
        The calibration of ``segment_prob`` and ``accuracy_m`` at the end of the walk: the fixes'
        persistence, the temperature and the pairs it was read from (``None`` without one).
    unseen_velocity_from_s
        Time from which the filter moved with the unseen-velocity motion model (``None``: never).
    familiar_velocity
        The familiar-velocity test's record (``None`` when it did not run; see
        :attr:`~curbside.localize.engine.SessionEngine.familiar_velocity`).
    fix_lag
        The fixes' lag compensated: ``mode`` and ``lag_s``, and under ``auto`` the estimate's blocks and
        residual per candidate (``None`` with ``fix_lag.mode = off`` or without fixes to compensate).
    ronin_familiarity
        Whether the RoNIN model knows the recording, by its yaw-equivariance spread
        (:meth:`curbside.localize.ronin.familiarity.Familiarity.to_dict`; ``None`` without RoNIN).
    wall_tolerance_m
        How soft the walls were (m; ``None`` without a map): ``filter.map.wall_tolerance_m``, or
        ``conflict_wall_tolerance_m`` on a map whose buildings cover its sidewalks.
    walkable_first
        Whether the map's sidewalks and crosswalks won over its buildings (``filter.map.conflict_*``;
        ``None`` without a map).
    snapshots
        With ``save_particles``: the cloud at each update, packed as it was taken: the arrays of
        ``particles.npz`` (:mod:`curbside.localize.particle_store`; ``unpack_particles`` reads them), on
        disk (a :class:`~curbside.localize.particle_spill.SpilledClouds`, read as memory maps), with
        ``weight_u8`` when the weights are not all uniform (particles killed by the map keep their place,
        with no weight, until the next resampling).
    """

    track: pd.DataFrame
    config: RunConfig
    velocity_source: str | None
    step_source: str
    recoveries: int = 0
    injections: int = 0
    snapshots: Mapping[str, np.ndarray] | None = None
    unseen_velocity_from_s: float | None = None
    wall_tolerance_m: float | None = None
    walkable_first: bool | None = None
    familiar_velocity: dict[str, object] | None = None
    fix_lag: dict[str, object] | None = None
    ronin_familiarity: dict | None = None
    heading_corrections: int = 0
    calibration: dict[str, float] | None = None

    @property
    def mode(self) -> str:
        """The method run."""
        return self.config.mode


def tracker_record(tracker: Tracker | None) -> dict[str, object]:
    """``recoveries``, ``injections`` and ``heading_corrections`` of a finished tracker (0 without one),
    and its ``calibration`` record (``None`` without one)."""
    if tracker is None:
        return {"recoveries": 0, "injections": 0, "heading_corrections": 0, "calibration": None}
    return {
        "recoveries": tracker.recoveries,
        "injections": 0 if tracker.divergence is None else tracker.divergence.injections,
        "heading_corrections": 0 if tracker.turn is None else tracker.turn.corrections,
        "calibration": None if tracker.calibration is None else tracker.calibration.record(),
    }


def track_table(
    rows: list[Row], frame: LocalFrame, map_layers: MapLayers | None, segments: bool, smoothed: bool = False
) -> pd.DataFrame:
    """The ``track.csv`` table of the engine's rows (``smooth_lat, smooth_lon`` when ``smoothed``)."""
    x = np.array([r.x for r in rows])
    y = np.array([r.y for r in rows])
    lon, lat = frame.to_lonlat(x, y)
    track = pd.DataFrame(
        {
            "t": [r.t for r in rows],
            "lat": np.atleast_1d(lat),
            "lon": np.atleast_1d(lon),
            "x_m": x,
            "y_m": y,
            "accuracy_m": [r.accuracy_m for r in rows],
            "update": [r.kind for r in rows],
            "gnss_used": np.array([r.fix_used for r in rows], dtype=int),
            "theta_drift_deg": np.degrees([r.theta for r in rows]),
            "speed_scale": [r.scale for r in rows],
            "n_eff": [r.n_eff for r in rows],
            "recovered": np.array([r.recovered for r in rows], dtype=int),
            "injected": np.array([r.injected for r in rows], dtype=int),
            "motion": [r.motion for r in rows],
        }
    )
    if smoothed:
        smooth_lon, smooth_lat = frame.to_lonlat(
            np.array([r.smooth_x for r in rows]), np.array([r.smooth_y for r in rows])
        )
        track["smooth_lat"], track["smooth_lon"] = np.atleast_1d(smooth_lat), np.atleast_1d(smooth_lon)
    if map_layers is None or not len(map_layers.layer("sidewalk")):
        return track
    if segments:
        mode_lon, mode_lat = frame.to_lonlat(
            np.array([r.mode_x for r in rows]), np.array([r.mode_y for r in rows])
        )
        track["sidewalk_segment_id"] = np.array([r.segment_id for r in rows], dtype=object)
        track["segment_prob"] = [r.segment_prob for r in rows]
        track["mode_lat"], track["mode_lon"] = np.atleast_1d(mode_lat), np.atleast_1d(mode_lon)
    else:  # no particles (gnss mode) or no segment estimate: the polygon under the track's position
        track["sidewalk_segment_id"] = sidewalk_segments_at(map_layers, x, y)
        track["segment_prob"] = np.nan
        track["mode_lat"], track["mode_lon"] = track["lat"], track["lon"]
    track["segment_distance_m"] = sidewalk_shapes(map_layers).distances_m(track["sidewalk_segment_id"], x, y)
    return track


def sidewalk_segments_at(map_layers: MapLayers, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """``segment_id`` of the sidewalk polygon under each point (``None`` off sidewalks)."""
    sidewalks = map_layers.layer("sidewalk")
    out = np.full(len(x), None, dtype=object)
    if len(sidewalks) == 0 or len(x) == 0:
        return out
    point_idx, poly_idx = sidewalks.sindex.query(shapely.points(x, y), predicate="within")
    out[point_idx[::-1]] = sidewalks["segment_id"].to_numpy()[poly_idx[::-1]]  # first match wins
    return out


def off_sidewalk_m(distance_m: float | np.ndarray | None) -> np.ndarray:
    """Whole metres from the named segment where the estimate is off it (farther than
    :data:`OFF_SIDEWALK_M`), NaN where it is on it or the distance is unknown (``None`` or NaN).

    Rounded half up, as the replay page's script would (``Math.round``).
    """
    distance = np.asarray(np.nan if distance_m is None else distance_m, float)
    with np.errstate(invalid="ignore"):
        return np.where(distance > OFF_SIDEWALK_M, np.floor(distance + 0.5), np.nan)


def place_text(label: str, distance_m: float | None) -> str:
    """Where the estimate is, in words: the segment's ``label`` ("Market Street, north side"), or
    :data:`OFF_SIDEWALK_TEXT` when the estimate is ``distance_m`` (m) from it, more than
    :data:`OFF_SIDEWALK_M` ("off the sidewalk, 19 m from Market Street, north side")."""
    off = float(off_sidewalk_m(distance_m))
    return label if math.isnan(off) else OFF_SIDEWALK_TEXT.format(distance_m=int(off), place=label)


class SidewalkShapes:
    """A map's sidewalk polygons by ``segment_id``, for the distance from a point to the segment it names.

    Parameters
    ----------
    map_layers
        The map (its metric CRS is the points' CRS). Polygons sharing a ``segment_id`` count as one.
    """

    def __init__(self, map_layers: MapLayers) -> None:
        sidewalks = map_layers.layer("sidewalk")
        if "segment_id" in sidewalks:
            sidewalks = sidewalks[sidewalks["segment_id"].notna()]
        else:
            sidewalks = sidewalks.iloc[:0]
        geoms = sidewalks.geometry.to_numpy()
        #: Sorted distinct ``segment_id`` strings and the polygon (or union) of each.
        self.ids, inverse = np.unique(sidewalks["segment_id"].astype(str).to_numpy(str), return_inverse=True)
        self.shapes = np.empty(len(self.ids), dtype=object)
        self.shapes[inverse] = geoms
        for k in np.flatnonzero(np.bincount(inverse, minlength=len(self.ids)) > 1):
            self.shapes[k] = shapely.union_all(geoms[inverse == k])

    def distances_m(self, segment_ids: Sequence | np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Distance (m) from each point to the polygon of its segment, 0 inside it.

        Parameters
        ----------
        segment_ids
            One ``segment_id`` per point (``None`` or NaN: none).
        x, y
            The points, metres in the map's CRS.

        Returns
        -------
        numpy.ndarray
            ``float`` per point; NaN without a segment or for an id the map does not hold.
        """
        ids = np.asarray(segment_ids, dtype=object)
        out = np.full(len(ids), np.nan)
        named = np.flatnonzero(~pd.isna(ids))
        if len(named) == 0 or len(self.ids) == 0:
            return out
        keys = ids[named].astype(str)
        pos = np.minimum(np.searchsorted(self.ids, keys), len(self.ids) - 1)
        known = self.ids[pos] == keys
        rows = named[known]
        points = shapely.points(np.asarray(x, float)[rows], np.asarray(y, float)[rows])
        out[rows] = shapely.distance(self.shapes[pos[known]], points)
        return out


_SHAPES: dict[int, tuple[weakref.ref, SidewalkShapes]] = {}


def sidewalk_shapes(map_layers: MapLayers) -> SidewalkShapes:
    """The :class:`SidewalkShapes` of a map, made once per map object while it lives (the service asks
    at every estimate, for every session on its one map)."""
    held = _SHAPES.get(id(map_layers))
    if held is not None and held[0]() is map_layers:
        return held[1]
    for key in [key for key, (ref, _) in _SHAPES.items() if ref() is None]:
        del _SHAPES[key]
    shapes = SidewalkShapes(map_layers)
    _SHAPES[id(map_layers)] = (weakref.ref(map_layers), shapes)
    return shapes


class Place(NamedTuple):
    """Where one estimate is, in the service's words (all ``None`` without a named segment).

    Attributes
    ----------
    segment_id, street, side, label
        The named sidewalk segment (``Estimate.segment_id``) and its words
        (:class:`~curbside.osmseg.places.SidewalkPlace`; ``street`` and ``side`` may be ``None``).
    distance_m
        From the estimate's ``x, y`` to that segment's polygon, m (0 on it): ``segment_distance_m``.
    text
        :func:`place_text`: the label, or "off the sidewalk, 18 m from 2nd Street, northeast side"
        beyond :data:`OFF_SIDEWALK_M`.
    """

    segment_id: str | None = None
    street: str | None = None
    side: str | None = None
    label: str | None = None
    distance_m: float | None = None
    text: str | None = None


class EstimatePlaces:
    """The place words and segment distance of a tracker's estimates on one map (the service's
    ``place`` and ``segment_distance_m``, and ``track.csv``'s distance).

    Made once per map (its segments' words and polygons: 0.1-0.2 s for the San Francisco map's 2,735
    segments), then :meth:`describe` per estimate (26 µs, against 130 µs for a standing
    ``Tracker.step`` at N = 2000). Trackers of the same map may share one.

    Parameters
    ----------
    map_layers
        The map the tracker was made from (the estimates' ``x, y`` are in its CRS).
    """

    def __init__(self, map_layers: MapLayers) -> None:
        self.map_layers = map_layers
        self.places = sidewalk_places(map_layers)
        shapes = sidewalk_shapes(map_layers)
        #: Each segment's polygon (or union) by ``segment_id``, as :class:`SidewalkShapes` measures.
        self.shapes = dict(zip(shapes.ids.tolist(), shapes.shapes, strict=True))
        self._frames_checked: set[int] = set()

    def describe(self, estimate: Estimate) -> Place:
        """The :class:`Place` of ``estimate`` (a :class:`~curbside.localize.filter.Estimate`).

        Raises
        ------
        CurbsideValueError
            The estimate's frame is not the map's CRS (a tracker made with another ``frame``).
        """
        frame = estimate.frame
        if frame is not None and id(frame) not in self._frames_checked:
            if not frame.crs.equals(self.map_layers.crs):
                raise CurbsideValueError("estimate", "its frame is not the map's CRS: no distance to measure")
            self._frames_checked.add(id(frame))
        place = self.places.get(estimate.segment_id) if estimate.segment_id else None
        shape = self.shapes.get(estimate.segment_id)
        if place is None or shape is None:
            return Place()
        distance = float(shapely.distance(shape, shapely.Point(estimate.x, estimate.y)))
        text = place_text(place.label, distance)
        return Place(place.segment_id, place.street, place.side, place.label, distance, text)
