"""The JSON the tracking service takes and gives (pydantic models; they make the OpenAPI page).

Rows are keyed by the SPEC's column names and carry the SPEC's units: ``imu`` rows are ``imu.csv`` rows
(``t`` s, ``ax, ay, az`` m/s² with gravity, ``gx, gy, gz`` rad/s, optionally the device-to-world
quaternion ``qx, qy, qz, qw``), ``gnss`` rows are ``gnss.csv`` rows (``t`` s, ``lat, lon`` WGS84
degrees, ``accuracy_m`` metres, null or <= 0 for an invalid fix). Both streams share one clock.

Values are taken as their JSON types (strict): a number for a number (an integer is one), ``true`` or
``false`` for ``end``; ``"9.81"`` or ``true`` where a number belongs is refused, not read as 9.81 or 1.
An optional field may be ``null``, which is the same as leaving it out.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator

from curbside.localize.live import GNSS_COLUMNS, IMU_COLUMNS, IMU_QUAT_COLUMNS
from curbside.localize.track_result import OFF_SIDEWALK_M, place_text

#: Most rows one request may carry per stream: four minutes of IMU at 50 Hz, of GNSS at 1 Hz.
MAX_IMU_ROWS = 12_000
MAX_GNSS_ROWS = 240

_ROW = ConfigDict(extra="forbid", allow_inf_nan=False, strict=True)


class ImuRow(BaseModel):
    """One ``imu.csv`` row."""

    model_config = _ROW
    t: float = Field(description="time, s (the session's clock)")
    ax: float = Field(description="acceleration, m/s², gravity included (phone frame)")
    ay: float
    az: float
    gx: float = Field(description="rotation rate, rad/s (phone frame)")
    gy: float
    gz: float
    qx: float | None = Field(None, description="device-to-world quaternion (all four or none)")
    qy: float | None = None
    qz: float | None = None
    qw: float | None = None

    @model_validator(mode="after")
    def _quaternion_whole(self) -> ImuRow:
        given = [q is not None for q in (self.qx, self.qy, self.qz, self.qw)]
        if any(given) and not all(given):
            raise ValueError("give all of qx, qy, qz, qw or none")
        return self


class GnssRow(BaseModel):
    """One ``gnss.csv`` row."""

    model_config = _ROW
    t: float = Field(description="time, s (the session's clock)")
    lat: float = Field(description="WGS84 latitude, degrees")
    lon: float = Field(description="WGS84 longitude, degrees")
    accuracy_m: float | None = Field(
        None,
        description="horizontal accuracy, m: the 68 % radius (iOS horizontalAccuracy, Android "
        "getAccuracy()); null or <= 0: invalid",
    )


class Samples(BaseModel):
    """A batch of rows of one session, each stream in time order, after every row sent before."""

    model_config = ConfigDict(extra="forbid", strict=True)
    imu: list[ImuRow] | None = Field(None, max_length=MAX_IMU_ROWS, description="null: none")
    gnss: list[GnssRow] | None = Field(None, max_length=MAX_GNSS_ROWS, description="null: none")
    end: bool | None = Field(False, description="WebSocket only: end the session after this batch")

    @model_validator(mode="after")
    def _one_layout(self) -> Samples:
        with_q = {row.qw is not None for row in self.imu or ()}
        if len(with_q) > 1:
            raise ValueError("imu: the quaternion is in some rows and not in others")
        return self

    def imu_array(self) -> tuple[np.ndarray, tuple[str, ...]]:
        """The IMU rows as an ``(N, 7)`` or ``(N, 11)`` array and their columns."""
        imu = self.imu or []
        columns = IMU_QUAT_COLUMNS if imu and imu[0].qw is not None else IMU_COLUMNS
        values = np.array([[getattr(r, c) for c in columns] for r in imu], float)
        return values.reshape(len(imu), len(columns)), columns

    def gnss_array(self) -> np.ndarray:
        """The fixes as an ``(M, 4)`` array (accuracy null -> NaN)."""
        fixes = self.gnss or []
        rows = [[r.t, r.lat, r.lon, np.nan if r.accuracy_m is None else r.accuracy_m] for r in fixes]
        return np.array(rows, float).reshape(len(rows), len(GNSS_COLUMNS))


class StartPose(BaseModel):
    """A known start, as ``meta.json``'s ``start``."""

    model_config = _ROW
    lat: float = Field(ge=-90, le=90)
    lon: float = Field(ge=-180, le=180)
    heading_deg: float = Field(
        ge=-360, le=360, description="walking direction, degrees clockwise from north (-360 to 360)"
    )
    t: float | None = Field(
        None, description="when the walk starts (s, session clock); default: the data's start"
    )


class NewSession(BaseModel):
    """``POST /sessions``: an optional start pose and run-configuration overrides."""

    model_config = ConfigDict(extra="forbid", strict=True)
    start: StartPose | None = Field(
        None, description="null: none (the filter starts at the first usable fix)"
    )
    config: dict[str, Any] | None = Field(
        None,
        description='overrides of run.json\'s config, e.g. {"seed": 3, "mode": "inertial", '
        '"filter.gnss.sigma_factor": 1.0}; null: none',
    )


class SessionCreated(BaseModel):
    """The new session: keep ``id`` secret, it is the only key to the session and its track."""

    id: str
    config: dict[str, Any] = Field(description="the session's whole run configuration (run.json's config)")
    fix_delay_s: float = Field(
        description="a fix may arrive at most this long after the IMU rows of its time"
    )
    idle_timeout_s: float = Field(description="the session ends after this long without a request")


class Estimate(BaseModel):
    """The latest filter update of a session (all null until the filter has started)."""

    status: str = Field(description="starting (no estimate yet), tracking, or failed (see warnings)")
    t: float | None = Field(None, description="time of the estimate, s (session clock)")
    lat: float | None = None
    lon: float | None = None
    accuracy_m: float | None = Field(
        None, description="radius around lat/lon holding the walker 68 % of the time, m (calibrated)"
    )
    segment_id: str | None = Field(None, description="most probable sidewalk segment (map segment_id)")
    segment_prob: float | None = Field(None, description="its probability, calibrated (docs/filter.md)")
    segment_distance_m: float | None = Field(
        None,
        description="distance from lat/lon to that segment's sidewalk polygon, m (0: on it); check it "
        "before announcing a side: the filter names a segment for estimates up to "
        "filter.map.segment_reach_m (25 m by default) away",
    )
    street: str | None = Field(None, description="street of that segment")
    side: str | None = Field(
        None, description="compass side of the street of that segment: north, northeast, ..."
    )
    place: str | None = Field(
        None,
        description=f'where the estimate is, in words: "Market Street, north side", or, more than '
        f'{OFF_SIDEWALK_M:g} m from the segment (segment_distance_m), '
        f'"{place_text("Market Street, north side", 19.0)}"',
    )
    n_eff: float | None = Field(None, description="effective number of particles")
    recoveries: int = Field(0, description="collapses of the particle cloud so far")
    unseen_velocity_from_s: float | None = Field(
        None,
        description="since when the filter moves with the motion model for a velocity model new to the "
        "phone or the place (--unseen-velocity; null: not so far)",
    )
    motion: str | None = Field(
        None,
        description="the motion model of the filter the estimate comes from: default, familiar (a velocity "
        "model that knows the walker: --familiar-velocity) or unseen (--unseen-velocity)",
    )
    update: str | None = Field(None, description="start, step (a footstep) or time (no footstep for 1 s)")
    gnss_used: bool | None = None
    updates: int = Field(0, description="filter updates so far")
    data_until: float | None = Field(None, description="latest row time received, s")
    lag_s: float | None = Field(None, description="data_until - t: how far the estimate trails the data")
    warnings: list[str] = Field(default_factory=list)


class TrackSummary(BaseModel):
    """An ended session's track, written to disk (retrieve it with ``GET /tracks/{id}``)."""

    key: str = Field(description="the track's name on disk and in GET /tracks (a hash of the id)")
    reason: str = Field(description="deleted, ended (the WebSocket's end message), expired or shutdown")
    updates: int
    t_start: float | None = None
    t_end: float | None = None
    recoveries: int = 0
    saved: bool = Field(description="whether a track was written (not without any estimate)")


class TrackInfo(BaseModel):
    """One finished track in ``GET /tracks`` (and the reply of ``DELETE /tracks/{id}``)."""

    key: str
    reason: str | None = None
    created: str | None = None
    ended: str | None = None
    mode: str | None = None
    updates: int | None = None
    t_start: float | None = None
    t_end: float | None = None


class Health(BaseModel):
    """``GET /health``."""

    status: str
    version: str
    sessions: int
    map: str | None
    sidewalk_segments: int


class ErrorMessage(BaseModel):
    """Every error: the HTTP status and one line saying what is wrong."""

    detail: str
