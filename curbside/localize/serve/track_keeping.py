"""How the tracking service keeps the tracks of ended sessions: written, retained, found and removed.

:class:`TrackKeeping` is the part of :class:`~curbside.localize.serve.service.TrackingService` that works
on the I/O thread and the track store (:class:`~curbside.localize.serve.store.TrackStore`). Once an ending
session's last RoNIN windows are back, its summary, track and ``run.json`` record are made and the track
is written under ``DATA_DIR/tracks`` on the I/O thread, so that formatting a long track holds no other
session up; a session whose streams could not be finished is saved at once with the track it has so far.
A track goes with ``DELETE /tracks/{id}`` (:meth:`TrackKeeping.delete_track`) or by the opt-in retention
limits: a pass runs on the I/O thread when the service starts and every :data:`RETENTION_PERIOD_S` after,
in slices of :data:`RETENTION_SLICE_S`, so that a track write or ``DELETE`` waits for one slice, not for
the pass.
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Callable
from datetime import datetime, timezone
from pathlib import Path
from typing import TYPE_CHECKING, Any

from curbside.errors import CurbsideInputError
from curbside.localize.serve.common import ServiceConfig, ServiceError
from curbside.localize.serve.store import ForeignFolderError, TrackStore, run_for

if TYPE_CHECKING:
    from concurrent.futures import ThreadPoolExecutor

    from curbside.localize.live import InferenceQueue
    from curbside.localize.serve.service import SessionEntry, SessionOp

# the service's one logger: the log names it on every line
logger = logging.getLogger("curbside.localize.serve.service")

#: How often the retention limits are applied (s); a pass stats each track's run.json.
RETENTION_PERIOD_S = 60.0
#: How long the I/O thread works on a retention pass before it turns to the track writes waiting (s).
RETENTION_SLICE_S = 0.1


def now_iso() -> str:
    """The time now, UTC, to the second, in ISO 8601 (``run.json``'s ``created`` and ``ended``)."""
    return datetime.now(timezone.utc).isoformat(timespec="seconds")


class TrackKeeping:
    """The tracks of a :class:`~curbside.localize.serve.service.TrackingService`'s ended sessions (see the
    module docstring): a base class of the service, working on the service's attributes below."""

    config: ServiceConfig
    queue: InferenceQueue
    store: TrackStore
    sessions: dict[str, SessionEntry]
    _io_executor: ThreadPoolExecutor
    _writing: list[SessionOp]  # their tracks being written
    _written: list[SessionOp]  # to be answered
    _wake: asyncio.Event | None

    def _write(self, op: SessionOp) -> None:
        """Write an ended session's track on the I/O thread (an hour's walk takes half a second to
        format, which would hold every other session up); its request is answered once it is written."""
        summary, result, info = self._track(op.entry, op.reason)
        op.result = summary
        if result is None:
            self._written.append(op)
            return
        future = self._on_io(self.store.save, op.entry.id, result, info)
        self._writing.append(op)

        def done(f: asyncio.Future) -> None:
            self._writing.remove(op)
            op.error = f.exception()
            if op.error is not None:
                logger.error("%s: saving its track failed", op.entry.live.name, exc_info=op.error)
            self._written.append(op)
            self._wake.set()

        future.add_done_callback(done)

    def _abandon(self, entry: SessionEntry, reason: str, error: Exception) -> ServiceError:
        """End a session whose streams could not be finished: save its track so far; the reply's error."""
        live = entry.live
        client = isinstance(error, CurbsideInputError)
        what = str(error) if client else f"internal error ({type(error).__name__})"
        live.failed = live.failed or f"ending failed: {what}"
        try:
            saved = self._save(entry, reason)["saved"]
        except Exception:
            logger.exception("%s: saving its track failed", live.name)
            saved = False
        kept = "its track so far is at /tracks/{id}" if saved else "no track was saved"
        detail = f"the session has ended, but finishing it failed ({what}); {kept}"
        return ServiceError(422 if client else 500, detail)

    def _save(self, entry: SessionEntry, reason: str) -> dict[str, Any]:
        summary, result, info = self._track(entry, reason)
        if result is not None:
            self.store.save(entry.id, result, info)
        return summary

    def _track(self, entry: SessionEntry, reason: str) -> tuple[dict[str, Any], Any, dict[str, Any]]:
        """An ended session's summary (``TrackSummary``), track (``None`` without any update, or when
        the filter never started on data) and ``run.json`` service record."""
        live = entry.live
        self.queue.drop(live)
        rows = live.rows
        if rows and rows[0].t > live.received_until:
            # The data ended before the start pose's t, and finishing started the filter there: one
            # position at a time with no data. The session never tracked, and saves no track.
            logger.info("%s: its data ends at %.2f s, before the filter's start at %.2f s: no track",
                        live.name, live.received_until, rows[0].t)
            rows = []
        result = live.result() if rows else None
        info = {
            "map": self.config.map_path,
            "created": entry.created,
            "ended": now_iso(),
            "reason": reason,
            "start": None if live.start is None else vars(live.start),
            "failed": live.failed,
        }
        logger.info("%s ended (%s): %d updates", live.name, reason, len(rows))
        summary = {
            "key": self.store.key(entry.id),
            "reason": reason,
            "updates": len(rows),
            "t_start": rows[0].t if rows else None,
            "t_end": rows[-1].t if rows else None,
            "recoveries": live.recoveries,
            "saved": result is not None,
        }
        return summary, result, info

    async def _retain(self) -> None:
        while True:
            await self._retain_once()
            await asyncio.sleep(RETENTION_PERIOD_S)

    async def _retain_once(self) -> None:
        """Apply the retention limits on the I/O thread, one slice at a time between the track writes."""
        try:
            steps = self.store.retention_pass()
            while not await self._on_io(run_for, steps, RETENTION_SLICE_S):
                pass
        except Exception:  # a bug: the service goes on, and the next pass tries again
            logger.exception("removing old tracks failed")

    def _on_io(self, func: Callable[..., Any], *args: Any) -> asyncio.Future:
        return asyncio.get_running_loop().run_in_executor(self._io_executor, func, *args)

    def track_folder(self, session_id: str) -> Path:
        """The stored track of an ended session (404 otherwise; 409 while it is still open)."""
        folder = self.store.folder(session_id)
        if folder is None:
            if session_id in self.sessions:
                raise ServiceError(409, "the session is still open: DELETE it to finish its track")
            raise ServiceError(404, "no such track")
        return folder

    async def delete_track(self, session_id: str) -> dict[str, Any]:
        """Remove an ended session's track (``TrackStore.delete``).

        Parameters
        ----------
        session_id
            The session's id (the track is found by its key).

        Returns
        -------
        dict
            The removed track's listing entry (``TrackInfo``).

        Raises
        ------
        ServiceError
            404 no such track; 409 the session is still open, or the folder is not one the service wrote.
        """
        if session_id in self.sessions:
            raise ServiceError(409, "the session is still open: DELETE /sessions/{id} ends it first")
        try:
            listed = await self._on_io(self.store.delete, self.store.key(session_id))
        except ForeignFolderError as exc:
            raise ServiceError(409, str(exc)) from None
        if listed is None:
            raise ServiceError(404, "no such track")
        return listed
