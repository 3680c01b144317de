"""What a tracking run gives, in one batch (:func:`~curbside.localize.pipeline.track_session`) or live
(:class:`~curbside.localize.live.LiveSession`): :class:`TrackResult`, its ``track.csv`` table of the
engine's rows (:func:`track_table`), and the finished tracker's counts (:func:`tracker_record`).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
import pandas as pd
import shapely

from curbside.localize.engine import Row
from curbside.localize.filter.tracker import Tracker
from curbside.localize.runconfig import RunConfig
from curbside.osmseg.mapio import MapLayers
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
#: estimate in ``gnss`` mode), its posterior probability (empty in ``gnss`` mode) and the mode estimate.
SEGMENT_COLUMNS = ("sidewalk_segment_id", "segment_prob", "mode_lat", "mode_lon")


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
