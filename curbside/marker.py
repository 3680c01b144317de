"""The marker ``.curbside-output``: what curbside wrote into a folder, and which command wrote it.

Every output folder holds one (:mod:`curbside.io` writes it when it commits an output there). It is
JSON: ``command`` (the command that made the folder), ``written_utc``, ``files`` (every file curbside
wrote there), ``commands`` (the files of each command) and, for a file that a command added to another
command's folder (``localize ronin``'s ``velocity.csv`` in a converted session), ``writers``: that
command, the file's size and modification time, and the SHA-256 of the files in the folder it was
computed from (``from``). An output written again into the folder keeps such a file when those come
back byte-identical, and otherwise removes it with a warning (:func:`derived_files`,
:func:`settle_derived`).
"""

from __future__ import annotations

import datetime
import hashlib
import json
import logging
import os
from pathlib import Path
from typing import Any

logger = logging.getLogger(__name__)

#: Marker file curbside writes into every output folder: JSON with the command and the files written.
MARKER = ".curbside-output"


def read_marker(folder: str | os.PathLike[str]) -> dict | None:
    """The marker of a curbside output folder, or ``None`` when ``folder`` has none (or an unreadable one).

    Parameters
    ----------
    folder
        A folder.

    Returns
    -------
    dict or None
        ``{"command": str, "written_utc": str, "files": [relative paths], "commands": {command: [relative
        paths]}}``: the command that made the folder, when the marker was last written, every file
        curbside wrote there and the files of each command (:func:`command_files`; a marker written
        before ``commands`` existed lacks it); ``writers`` when a command added a file
        (:func:`note_written_by`).
    """
    path = Path(folder) / MARKER
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    if not isinstance(doc, dict) or not isinstance(doc.get("files", []), list):
        return None
    return doc


def command_files(doc: dict) -> dict[str, list[str]]:
    """The files each command wrote into a folder, from its marker (:func:`read_marker`).

    Parameters
    ----------
    doc
        The marker.

    Returns
    -------
    dict
        Command -> the relative paths it wrote, the command that made the folder first. A marker without
        ``commands`` (written before it existed) holds one command's files: ``command`` and ``files``.
    """
    records = doc.get("commands")
    if isinstance(records, dict) and records and all(isinstance(v, list) for v in records.values()):
        return {str(command): [str(f) for f in files] for command, files in records.items()}
    return {str(doc.get("command", "curbside")): [str(f) for f in doc.get("files", [])]}


def _save(folder: Path, doc: dict) -> None:
    tmp = folder / f"{MARKER}.tmp"
    tmp.write_text(json.dumps(doc, indent=1), encoding="utf-8")
    os.replace(tmp, folder / MARKER)


def _writers(doc: dict) -> dict:
    return doc["writers"] if isinstance(doc.get("writers"), dict) else {}


def _record_holds(path: Path, record: Any) -> bool:
    """Whether a ``writers`` record still describes the file ``path`` (same size and modification time)."""
    if not isinstance(record, dict) or not os.path.isfile(path):
        return False
    stat = path.stat()
    return (record.get("size"), record.get("mtime_ns")) == (stat.st_size, stat.st_mtime_ns)


def write_marker(folder: Path, command: str, files: list[str]) -> None:
    """Record in ``folder``'s marker that ``command``'s output there is ``files`` now.

    Its earlier record is replaced; the other commands' records are kept, less the files ``command``
    wrote over (a command left with none drops out), and so are the marker's other members, less the
    ``writers`` records that no longer describe a file listed there.

    Parameters
    ----------
    folder
        The output folder.
    command
        What wrote ``files``, e.g. ``"localize convert"``.
    files
        Its files there, relative to ``folder``.
    """
    previous = read_marker(folder) or {}
    records = command_files(previous) if previous else {}
    records[command] = sorted(files)  # a command already recorded keeps its place: the folder's maker first
    claimed = set(files)
    records = {c: own if c == command else [f for f in own if f not in claimed] for c, own in records.items()}
    records = {c: own for c, own in records.items() if own or c == command}
    doc = {
        **previous,
        "command": next(iter(records)),
        "written_utc": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
        "files": sorted({f for own in records.values() for f in own}),
        "commands": records,
    }
    if "writers" in previous:
        doc["writers"] = {name: record for name, record in _writers(previous).items()
                          if name in doc["files"] and _record_holds(folder / name, record)}
    _save(folder, doc)


def note_written(path: str | os.PathLike[str], command: str = "curbside") -> None:
    """Record in its folder's marker a file curbside added to a folder.

    ``localize ronin`` writes ``velocity.csv`` into a session folder that ``localize convert`` wrote;
    listing it among the files of the command that made the folder lets the next ``localize ronin``
    replace it (:func:`curbside.io.written_by_curbside`). A folder without a marker gets one naming
    ``command`` and this file alone, which no other command's output may then be written over
    (:func:`curbside.io.check_output_folder`).

    Parameters
    ----------
    path
        The file just written.
    command
        What wrote it, for a folder that has no marker yet.
    """
    path = Path(os.path.abspath(path))
    doc = read_marker(path.parent)
    if doc is None:
        write_marker(path.parent, command, [path.name])
    elif path.name not in doc["files"]:
        maker, files = next(iter(command_files(doc).items()))
        write_marker(path.parent, maker, sorted([*files, path.name]))


def _sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def note_written_by(
    path: str | os.PathLike[str], command: str, inputs: tuple[str | os.PathLike[str], ...] = ()
) -> None:
    """Record in its folder's marker that ``command`` wrote the file ``path`` (:func:`note_written`), and
    which command it was, for :func:`writer_of`, and what it was computed from.

    A session folder holds files of several commands under one marker: ``localize simulate`` writes a
    ``velocity.csv`` (its stand-in for RoNIN), and so does ``localize ronin``. The marker's ``writers``
    names the command that wrote such a file, with the file's size and modification time then, so that
    the record no longer holds once anything else has written the file again, and the SHA-256 of each of
    ``inputs`` that lies in the same folder (``from``), which decide whether the next output written into
    the folder keeps the file (:func:`settle_derived`).

    Parameters
    ----------
    path
        The file just written.
    command
        What wrote it, e.g. ``"localize ronin"``.
    inputs
        The files it was computed from (``imu.csv`` for ``localize ronin``); those of other folders are
        left out.
    """
    path = Path(os.path.abspath(path))
    stat = path.stat()
    record: dict[str, Any] = {"command": command, "size": stat.st_size, "mtime_ns": stat.st_mtime_ns}
    sources = [Path(os.path.abspath(p)) for p in inputs]
    sources = [p for p in sources if p.parent == path.parent and p.is_file()]
    if sources:
        record["from"] = {p.name: _sha256(p) for p in sources}
    note_record(path, record)


def note_record(path: Path, record: dict) -> None:
    """:func:`note_written` the file ``path``, with ``record`` as its ``writers`` record.

    Parameters
    ----------
    path
        An existing file, absolute.
    record
        What :func:`note_written_by` records: ``command``, ``size``, ``mtime_ns`` and maybe ``from``.
    """
    note_written(path, str(record["command"]))
    doc = read_marker(path.parent)
    if doc is not None:
        _save(path.parent, {**doc, "writers": {**_writers(doc), path.name: record}})


def writer_of(path: str | os.PathLike[str]) -> str | None:
    """The command that wrote the file ``path``, as its folder's marker records it.

    Parameters
    ----------
    path
        An existing file.

    Returns
    -------
    str or None
        The command :func:`note_written_by` recorded for this very file (the same size and modification
        time), else the command whose files the marker lists it among; ``None`` for a file no marker lists.
    """
    path = Path(os.path.abspath(path))
    doc = read_marker(path.parent)
    if doc is None or path.name not in doc["files"]:
        return None
    record = _writers(doc).get(path.name)
    if _record_holds(path, record):
        return str(record.get("command"))
    owners = [command for command, files in command_files(doc).items() if path.name in files]
    return owners[0] if owners else None


def derived_files(dst: Path, old: list[str], files: list[str]) -> dict[str, dict]:
    """The files another command added to the output about to be written again, and not written again.

    Parameters
    ----------
    dst
        The output folder, which exists.
    old
        The files the writing command wrote there before (its marker record).
    files
        The files it writes now, relative to ``dst``; a nested marker among them replaces the output
        folder it stands in (``localize convert --all``'s trial folders).

    Returns
    -------
    dict
        Path relative to ``dst`` -> its ``writers`` record (:func:`note_written_by`), for each file of
        ``old``, or of the files a replaced nested marker lists, that ``files`` do not hold.
    """
    scopes = {".": set(old)}
    for rel in files:
        if Path(rel).name == MARKER:
            doc = read_marker(dst / Path(rel).parent)
            scopes[Path(rel).parent.as_posix()] = set(doc["files"]) if doc else set()
    derived = {}
    for sub, listed in scopes.items():
        for name, record in _writers(read_marker(dst / sub) or {}).items():
            rel = (Path(sub) / name).as_posix()
            if name in listed and rel not in files and isinstance(record, dict):
                derived[rel] = record
    return derived


def settle_derived(dst: Path, derived: dict[str, dict]) -> list[str]:
    """Keep each derived file whose sources came back byte-identical; remove the others, with a warning.

    Parameters
    ----------
    dst
        The output folder, its new files in place.
    derived
        :func:`derived_files`, found before they were.

    Returns
    -------
    list of str
        The files kept (relative to ``dst``): record them again with :func:`note_record`.
    """
    kept = []
    for rel, record in derived.items():
        path = dst / rel
        if not path.is_file():
            continue
        sources = record["from"] if isinstance(record.get("from"), dict) else {}
        changed = [name for name, sha256 in sources.items()
                   if not (path.parent / name).is_file() or _sha256(path.parent / name) != sha256]
        if sources and not changed:
            kept.append(rel)
            continue
        path.unlink()
        writer = record.get("command", "curbside")
        why = (f" from the previous {', '.join(sources)}) removed: {', '.join(changed)} changed" if sources
               else ") removed: what it was computed from is not recorded")
        shown = os.path.relpath(path) if path.is_relative_to(Path.cwd()) else path
        logger.warning("%s (written by %s%s; run %s again", shown, writer, why, writer)
    return kept
