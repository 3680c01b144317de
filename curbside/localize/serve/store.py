"""Finished tracks of the tracking service on disk: one ``localize run`` output folder per session.

A track lives in ``DATA_DIR/tracks/KEY/`` (``track.csv``, ``track.geojson``, ``run.json``, written
atomically by :func:`curbside.localize.track.write_track`), where ``KEY`` is a SHA-256 hash of the
session id. The listing shows keys, so an operator sees what is stored, and only a client holding a
session's id can read its track: the id is the session's only key, and it is never written to disk.

A track is removed by ``DELETE /tracks/{id}`` (:meth:`TrackStore.delete`) or by the opt-in retention
limits (:meth:`TrackStore.retention_pass`: older than ``max_age_s``, or the oldest beyond ``max_count``;
the count is also kept at each :meth:`TrackStore.save`). Only a folder the service wrote is touched
(:func:`foreign_reason`), and in it only the files it wrote.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import re
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from curbside.io import MARKER, read_marker
from curbside.localize.track import write_track
from curbside.localize.track_result import TrackResult

logger = logging.getLogger(__name__)

#: Files of a track folder that ``GET /tracks/{id}/{name}`` serves.
TRACK_FILES = ("track.csv", "track.geojson", "run.json")
#: What ``write_track`` records as the writer in a track folder's marker.
WRITER = "localize run"
#: Files of a track folder the service may remove (``particles.npz``: ``write_track`` may write it).
_OWN_FILES = ("run.json", "track.csv", "track.geojson", "particles.npz")
_KEY = re.compile(r"[0-9a-f]{32}")


class ForeignFolderError(Exception):
    """A folder in the tracks folder that the service did not write: it is never removed."""

    def __init__(self, key: str, reason: str) -> None:
        super().__init__(f"the folder {key} was not written by the service ({reason}); it is left alone")
        self.key = key
        self.reason = reason


class TrackStore:
    """The tracks folder (created when missing).

    The listing is read from disk once, when the store is made, and kept up to date by :meth:`save` and
    :meth:`delete`: reading every ``run.json`` at each ``GET /tracks`` took 0.6 s with 5,000 tracks, with
    every live session waiting. :meth:`save`, :meth:`delete` and the retention pass may run on another
    thread than :meth:`list` (one thread for the three of them).

    The store also knows which listed folders are its own tracks and when each was written: those it
    wrote, and those a retention pass has checked (the pass also renews their ages). :meth:`save` keeps
    ``max_count`` with that, one track out for the one in (a backlog is the pass's, in steps): the
    oldest of a part of the tracks is never one of the newest ``max_count`` of them all, so this is right
    even before the first pass has checked every folder.

    Parameters
    ----------
    root
        ``DATA_DIR/tracks``.
    max_age_s, max_count
        Retention limits that :meth:`retain` applies (``None``: none): a track older than ``max_age_s``
        goes, and so do the oldest beyond ``max_count``.
    """

    def __init__(
        self, root: str | Path, max_age_s: float | None = None, max_count: int | None = None
    ) -> None:
        self.root = Path(root)
        self.root.mkdir(parents=True, exist_ok=True)
        self.max_age_s = max_age_s
        self.max_count = max_count
        self._lock = threading.Lock()
        # Listed folders found to be the service's own tracks (with when their run.json was written, Unix
        # s), or not (warned once): checked once each.
        self._own: dict[str, float] = {}
        self._foreign: set[str] = set()
        self._listing: dict[str, dict[str, Any]] = {}
        for folder in sorted(p for p in self.root.iterdir() if p.is_dir()):
            info = _read_json(folder / "run.json")
            if info is not None:
                self._listing[folder.name] = _listed(folder.name, info)

    @staticmethod
    def key(session_id: str) -> str:
        """The folder name of a session's track (32 hex digits of SHA-256 of the id)."""
        return hashlib.sha256(session_id.encode()).hexdigest()[:32]

    def save(self, session_id: str, result: TrackResult, service_info: dict[str, Any]) -> Path:
        """Write a session's track atomically; ``service_info`` goes into ``run.json``'s ``service``.

        Then, over ``max_count`` tracks, the oldest the store knows goes (see the class docstring).
        """
        key = self.key(session_id)
        track = result.track
        info = {
            "session": f"live session {key}",
            "service": {
                **service_info,
                "t_start": float(track["t"].iat[0]) if len(track) else None,
                "t_end": float(track["t"].iat[-1]) if len(track) else None,
            },
        }
        folder = write_track(result, self.root / key, info)
        listed = _listed(key, _read_json(folder / "run.json") or {})
        written_s = (folder / "run.json").stat().st_mtime
        with self._lock:
            self._listing[key] = listed
            self._own[key] = written_s
            over = self.max_count is not None and len(self._own) > self.max_count
            others = [k for k in self._own if k != key]  # on a coarse clock the new one may tie: never it
            oldest = min(others, key=lambda k: (self._own[k], k)) if over and others else None
        if oldest is not None:
            self._remove(oldest, f"over {self.max_count} tracks")
        return folder

    def folder(self, session_id: str) -> Path | None:
        """The track folder of a session id, ``None`` when there is none."""
        folder = self.root / self.key(session_id)
        return folder if (folder / "run.json").is_file() else None

    def run_info(self, session_id: str) -> dict[str, Any] | None:
        """``run.json`` of a session's track."""
        folder = self.folder(session_id)
        return None if folder is None else _read_json(folder / "run.json")

    def list(self) -> list[dict[str, Any]]:
        """Every stored track, oldest end first: key, reason, created, ended, mode, updates, t range."""
        with self._lock:
            out = list(self._listing.values())
        return sorted(out, key=lambda item: (item["ended"] or "", item["key"]))

    def delete(self, key: str, why: str = "deleted") -> dict[str, Any] | None:
        """Remove the track ``key``: the files the service wrote in its folder, then the folder if empty.

        Files it did not write stay, and so does their folder (with a warning).

        Parameters
        ----------
        key
            The track's key (:meth:`key` of its session id).
        why
            What removes it, for the log.

        Returns
        -------
        dict or None
            Its listing entry (``None`` when there is no such track).

        Raises
        ------
        ForeignFolderError
            The folder is not one the service wrote (:func:`foreign_reason`): nothing is removed.
        OSError
            A file could not be removed.
        """
        folder = self.root / key
        if not (folder / "run.json").is_file():
            return None
        reason = foreign_reason(folder, key)
        if reason is not None:
            raise ForeignFolderError(key, reason)
        written = set((read_marker(folder) or {}).get("files", []))
        with self._lock:
            listed = self._listing.pop(key, None) or _listed(key, _read_json(folder / "run.json") or {})
            self._own.pop(key, None)
        for name in _OWN_FILES:  # run.json first: from then on it is no longer a track
            if name in written:
                (folder / name).unlink(missing_ok=True)
        (folder / MARKER).unlink(missing_ok=True)
        try:
            folder.rmdir()
        except OSError:
            others = ", ".join(sorted(p.name for p in folder.iterdir()))
            logger.warning("%s: track removed; the folder stays for files the service did not write (%s)",
                           folder, others)
        logger.info("track %s removed (%s)", key, why)
        return listed

    def retain(self, now_s: float | None = None) -> list[str]:
        """Remove the tracks beyond the retention limits at once (:meth:`retention_pass`, every step).

        Parameters
        ----------
        now_s
            The present, Unix seconds (default: now).

        Returns
        -------
        list of str
            The keys of the tracks removed, oldest first.
        """
        return [key for key in self.retention_pass(now_s) if key is not None]

    def retention_pass(self, now_s: float | None = None) -> Iterator[str | None]:
        """Remove the tracks beyond the retention limits, one step at a time (see :func:`run_for`).

        A track's age is the time since its ``run.json`` was written (its modification time). Folders the
        service did not write are left, and do not count towards ``max_count``. A step checks one listed
        folder (once per folder) and renews its age, or removes one track; between two steps the store
        may save and delete tracks: each removal is decided on the store as it is then.

        Parameters
        ----------
        now_s
            The present, Unix seconds (default: when the pass starts).

        Yields
        ------
        str or None
            The key of the track a step removed (oldest first), else ``None``.
        """
        if self.max_age_s is None and self.max_count is None:
            return
        now_s = time.time() if now_s is None else now_s
        with self._lock:
            keys = list(self._listing)
        for key in keys:
            with self._lock:
                listed = key in self._listing  # not deleted since
            if listed and self._is_own(key):
                written_s = _written_s(self.root / key)
                with self._lock:
                    if written_s is None:  # removed by hand
                        self._own.pop(key, None)
                    elif key in self._own:
                        self._own[key] = written_s
            yield None
        with self._lock:
            by_age = sorted(self._own.items(), key=lambda item: (item[1], item[0]))
        removed = 0
        for key, written_s in by_age:
            with self._lock:
                if key not in self._own:  # deleted since
                    continue
                over = self.max_count is not None and len(self._own) > self.max_count
            too_old = self.max_age_s is not None and now_s - written_s > self.max_age_s
            if not too_old and not over:
                break  # the rest are younger, and within the count
            age_days = (now_s - written_s) / 86400
            why = f"{age_days:.1f} days old" if too_old else f"over {self.max_count} tracks"
            gone = self._remove(key, why)
            removed += gone
            yield key if gone else None
        if removed:
            logger.info("retention removed %d track(s)", removed)

    def _remove(self, key: str, why: str) -> bool:
        """:meth:`delete` for the retention limits: whether the track went; it no longer counts anyway."""
        try:
            gone = self.delete(key, why) is not None
        except (ForeignFolderError, OSError) as exc:  # changed since it was checked; unremovable
            reason = getattr(exc, "strerror", None) or exc
            logger.warning("%s: cannot remove it (%s)", self.root / key, reason)
            gone = False
        with self._lock:
            self._own.pop(key, None)
        return gone

    def _is_own(self, key: str) -> bool:
        """Whether the listed folder ``key`` is a track the service wrote (checked once per folder)."""
        with self._lock:
            if key in self._own or key in self._foreign:
                return key in self._own
        if not os.path.lexists(self.root / key):  # removed by hand
            return False
        reason = foreign_reason(self.root / key, key)
        written_s = None if reason else _written_s(self.root / key)
        if reason:
            self._foreign.add(key)
            logger.warning("%s: %s", self.root / key, ForeignFolderError(key, reason))
        elif written_s is not None:
            with self._lock:
                self._own[key] = written_s
        return written_s is not None


def run_for(steps: Iterator[Any], budget_s: float) -> bool:
    """Take steps of ``steps`` (:meth:`TrackStore.retention_pass`) for about ``budget_s``.

    Parameters
    ----------
    steps
        The steps left.
    budget_s
        Seconds after which no further step starts.

    Returns
    -------
    bool
        Whether no step is left.
    """
    deadline_s = time.perf_counter() + budget_s
    return all(time.perf_counter() < deadline_s for _ in steps)


def foreign_reason(folder: Path, key: str) -> str | None:
    """Why ``folder`` is not a track folder this service wrote; ``None`` when it is one.

    A service track folder is a real folder named by a track key, holding ``write_track``'s marker
    (``.curbside-output`` naming ``localize run`` and the track's files) and a ``run.json`` that names
    the live session of that key and records the service's ``service`` block.

    Parameters
    ----------
    folder
        A folder in the tracks folder.
    key
        The track key it should hold (:meth:`TrackStore.key`).

    Returns
    -------
    str or None
        The first reason found, in a few words (for :class:`ForeignFolderError`).
    """
    if not _KEY.fullmatch(folder.name) or folder.name != key:
        return "its name is not a track key"
    if folder.is_symlink() or not folder.is_dir():
        return "not a folder"
    marker = read_marker(folder)
    if marker is None or marker.get("command") != WRITER:
        return f"no {MARKER} of {WRITER}"
    if not set(TRACK_FILES) <= set(marker.get("files", [])):
        return f"its {MARKER} does not list the track's files"
    info = _read_json(folder / "run.json") or {}
    if info.get("session") != f"live session {key}" or not isinstance(info.get("service"), dict):
        return "its run.json is not a live session's"
    return None


def _listed(key: str, info: dict[str, Any]) -> dict[str, Any]:
    """A track's entry in the listing, from its ``run.json``."""
    service = info.get("service") or {}
    return {
        "key": key,
        "reason": service.get("reason"),
        "created": service.get("created"),
        "ended": service.get("ended"),
        "mode": info.get("mode"),
        "updates": info.get("rows"),
        "t_start": service.get("t_start"),
        "t_end": service.get("t_end"),
    }


def _written_s(folder: Path) -> float | None:
    """When ``folder``'s ``run.json`` was written (Unix s); ``None`` when it is gone."""
    try:
        return (folder / "run.json").stat().st_mtime
    except OSError:
        return None


def _read_json(path: Path) -> dict[str, Any] | None:
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        return None
    except (OSError, ValueError) as exc:
        logger.warning("%s: unreadable (%s); skipped", path, exc)
        return None
    return data if isinstance(data, dict) else None
