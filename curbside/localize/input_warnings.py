"""The warnings :func:`~curbside.localize.pipeline.track_session` gives about a session's inputs: what it
tracks through, but not as the user may expect (a held fix, an unanchored start, fixes it cannot use).

Each names the session as the user gave it (:attr:`~curbside.localize.session.Session.source`).
"""

from __future__ import annotations

import logging

import numpy as np

from curbside.localize.engine import StartPose
from curbside.localize.runconfig import RunConfig
from curbside.localize.session import Session

logger = logging.getLogger(__name__)


def report_gnss_holds(session: Session, config: RunConfig) -> None:
    """Warn of GNSS gaps longer than ``engine.interp_max_gap_s``, which the ``gnss`` track holds through.

    A simulated session's gaps (``meta.json`` with a ``simulation`` record: the GNSS model's outages, a
    benchmark's own walks) are logged at INFO: there is nothing in them to fix.
    """
    gnss = session.gnss
    if gnss is None or len(gnss) < 2:
        return
    gaps = np.diff(gnss["t"].to_numpy(float))
    long = gaps[gaps > config.engine.interp_max_gap_s]
    if len(long):
        logger.log(
            logging.INFO if session.simulated else logging.WARNING,
            "%s: %d GNSS gap(s) longer than %g s (longest %.0f s): the gnss track holds the last fix "
            "through them",
            session.source,
            len(long),
            config.engine.interp_max_gap_s,
            long.max(),
        )


def report_unanchored_inertial(session: Session, config: RunConfig, start: StartPose | None) -> None:
    """Warn when an ``inertial`` track has no start pose to start from, only a fix and the map."""
    if config.mode == "inertial" and (start is None or not config.use_start_pose):
        logger.warning(
            "%s: no start pose: the inertial track starts at the first usable GNSS fix with its heading "
            "unknown (spread over the full circle), so it is anchored only by that fix and the map; add a "
            "start pose (lat, lon, heading_deg) to meta.json for an inertial track from a known start",
            session.source,
        )


def report_unusable_fixes(session: Session) -> None:
    """Warn when no fix reports a usable accuracy: the walk is then tracked as if it had no GNSS."""
    gnss = session.gnss
    if gnss is None or len(gnss) == 0:
        return
    accuracy = gnss["accuracy_m"].to_numpy(float)
    if not np.any(np.isfinite(accuracy) & (accuracy > 0)):
        logger.warning(
            "%s: none of its %d fixes reports a usable accuracy (a positive accuracy_m): the walk "
            "is tracked as if it had no GNSS", session.file_source("gnss.csv"), len(gnss),
        )


def report_short_velocity(session: Session, velocity_t: np.ndarray, source: str) -> None:
    """Warn when the velocity starts well after the walk or stops well before it (a truncated
    ``velocity.csv``): outside its rows the particles stand still and only the fixes move the track.

    The walk's span is that of its footsteps (``steps.csv``) where the session has them, since a
    recording often starts and ends standing; else that of its other streams (fixes, IMU, waypoints). A
    gap at either end longer than 10 s or 5 % of that span is reported. PDR's velocity is not judged: it
    runs from the first footstep to the last by construction.

    Parameters
    ----------
    session
        The recording.
    velocity_t
        The velocity's times (s, increasing), on the session's clock.
    source
        Where the velocity came from (``file``, ``ronin``, ``pdr``): ``file`` names ``velocity.csv``.
    """
    streams = (session.steps,) if session.steps is not None and len(session.steps) else (
        session.gnss, session.imu, session.waypoints)
    others = [frame["t"].to_numpy(float) for frame in streams if frame is not None and len(frame)]
    if source == "pdr" or not others or len(velocity_t) == 0:
        return
    walk_begin_s = min(float(np.nanmin(t)) for t in others)
    walk_end_s = max(float(np.nanmax(t)) for t in others)
    allowed_s = max(10.0, 0.05 * (walk_end_s - walk_begin_s))
    v_begin_s, v_end_s = float(velocity_t[0]), float(velocity_t[-1])
    if v_begin_s - walk_begin_s > allowed_s or walk_end_s - v_end_s > allowed_s:
        name = (session.file_source("velocity.csv") if source == "file"
                else f"{session.source} ({source} velocity)")
        logger.warning(
            "%s: the velocity covers t=%.1f-%.1f s of the walk's %.1f-%.1f s: outside it the particles "
            "stand still and only the fixes move the track (a truncated file?)",
            name, v_begin_s, v_end_s, walk_begin_s, walk_end_s,
        )
