"""What the tracking service's modules share: its settings (:class:`ServiceConfig`), its refusals
(:class:`ServiceError`: an HTTP status and a one-line reason) and how the log names a session
(:func:`session_label`)."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from curbside import settings
from curbside.errors import CurbsideInputError
from curbside.localize.live import LiveLimits
from curbside.localize.serve.store import TrackStore

#: Hex digits of a session's track key that name the session in the log.
LABEL_DIGITS = 8


@dataclass(frozen=True)
class ServiceConfig:
    """How ``localize serve`` runs.

    Attributes
    ----------
    map_path
        Map layers GeoJSON; ``None`` tracks without a map likelihood (as ``localize run`` without
        ``--map``).
    data_dir
        Finished tracks go to ``data_dir / "tracks"``.
    token
        Bearer token every request must carry; ``None``: none needed.
    mode, overrides
        Every session's run configuration: ``RunConfig.for_mode(mode)`` with these ``--set``
        overrides, then the session's own.
    idle_timeout_s
        A session without a request for this long ends (its track is saved).
    max_sessions
        Open sessions at most; more get 503.
    max_particles
        Largest ``filter.n_particles`` a session may ask for.
    inference_wait_s
        Longest a partial RoNIN batch waits for more windows.
    limits
        What each session accepts (:class:`~curbside.localize.live.LiveLimits`).
    keep_tracks_days, max_tracks
        Retention (``None``: none): finished tracks older than this many days, and the oldest beyond
        this many, are removed by a pass at start (in the background) and every
        :data:`~curbside.localize.serve.track_keeping.RETENTION_PERIOD_S`; the count also holds as each track
        is written.
    """

    map_path: str | None = None
    data_dir: Path = field(default_factory=lambda: settings.data_dir)
    token: str | None = None
    mode: str = "fused"
    overrides: dict[str, Any] = field(default_factory=dict)
    idle_timeout_s: float = 300.0
    max_sessions: int = 1000
    max_particles: int = 5000
    inference_wait_s: float = 0.25
    limits: LiveLimits = field(default_factory=LiveLimits)
    keep_tracks_days: float | None = None
    max_tracks: int | None = None


class ServiceError(Exception):
    """A request the service refuses: an HTTP status and a one-line reason."""

    def __init__(self, status: int, detail: str) -> None:
        super().__init__(detail)
        self.status = status
        self.detail = detail


def as_service_error(exc: Exception) -> ServiceError:
    """The refusal of an exception: itself, a 422 for bad input, else a 500 naming only its type."""
    if isinstance(exc, ServiceError):
        return exc
    if isinstance(exc, CurbsideInputError):
        return ServiceError(422, str(exc))
    return ServiceError(500, f"internal error ({type(exc).__name__}); see the service log")


def session_label(session_id: str) -> str:
    """A session's name in the log: ``session`` and the first :data:`LABEL_DIGITS` hex digits of its
    track key (``DATA_DIR/tracks/KEY``, a hash of the id). The id is the key to the session and its
    track: it is never logged, nor is any part of it."""
    return f"session {TrackStore.key(session_id)[:LABEL_DIGITS]}"
