"""File helpers shared by every stage: safe output folders, atomic writes, opening HDF5 datasets.

Output rules (every command that writes goes through here):

- a **file** is written to a temporary name beside it and renamed into place, so a reader sees the
  old file or the new one, never half of one (:func:`atomic_path`). A command replaces an existing
  file only when curbside wrote it (:func:`written_by_curbside`: listed in its folder's marker, or
  carrying curbside's signature, as every map, page, figure and JSON report it writes does) or the
  command was given ``--overwrite``; never one of the command's own inputs, and never anything but a
  regular file (a device, a link) (:func:`check_output_file`);
- a **folder** may be written when it does not exist, is empty, or holds the marker
  ``.curbside-output`` that records an output of the same command there (a previous output of it). Any
  other folder, another command's output included (a session folder is not a run folder), is refused
  unless the command was given ``--overwrite``; even then, only the files the command writes are
  replaced, and nothing else is deleted (:func:`output_folder`, :func:`check_output_folder`). The marker
  records the files each command wrote there (``commands``; ``command`` names the one that made the
  folder, and ``files`` lists them all), so the next run of a command into the folder removes its own
  stale files (e.g. ``particles.npz`` from a run with ``--save-particles``) and nothing else, and a
  command writing beside another's output (``localize run S -o S --overwrite``) leaves the other's
  record, and its right to write there again, as it was. A file another command added to the output
  (``localize ronin``'s ``velocity.csv``) stays while the files it was computed from come back
  byte-identical, and is otherwise removed with a warning (:mod:`curbside.marker`);
- a path that cannot be written (permission denied, a file where a folder should be, a read-only
  disk) is bad input: :class:`~curbside.errors.CurbsideInputError`, not an internal error.
"""

from __future__ import annotations

import contextlib
import logging
import math
import os
import shutil
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Any

from curbside.errors import CurbsideInputError
from curbside.marker import (
    MARKER,
    command_files,
    derived_files,
    note_record,
    read_marker,
    settle_derived,
    write_marker,
)
from curbside.marker import note_written as note_written  # re-exported: the output rules' API
from curbside.marker import note_written_by as note_written_by
from curbside.marker import writer_of as writer_of

if TYPE_CHECKING:
    import h5py

logger = logging.getLogger(__name__)

_STAGING_PREFIX = ".curbside-staging-"

#: What marks a single file as curbside's own, searched for in its first :data:`_SIGNATURE_BYTES`: a map
#: (``mapio.write_map``), a page (``<meta name="generator">``), a JSON report, a PNG figure (its
#: ``Software`` text chunk).
SIGNATURES = (
    b'{"type":"FeatureCollection","curbside":',
    b'<meta name="generator" content="curbside',
    b'"generator": "curbside',
    b"tEXtSoftware\x00curbside",
)
_SIGNATURE_BYTES = 8192


def json_ready(value: Any) -> Any:
    """``value`` with numpy scalars unwrapped, keys as strings and non-finite floats as ``None`` (strict
    JSON has no NaN)."""
    import numpy as np  # here: the output checks run before a command imports numpy

    if isinstance(value, dict):
        return {str(k): json_ready(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [json_ready(v) for v in value]
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def _absolute(path: str | os.PathLike[str]) -> Path:
    # abspath, not resolve: "-o ." must name the folder itself, and a symlinked folder stays a symlink
    return Path(os.path.abspath(path))


def _cannot_write(path: Path, exc: OSError) -> CurbsideInputError:
    reason = exc.strerror or type(exc).__name__
    return CurbsideInputError(path, f"cannot write here ({reason})")


def _existing_ancestor(path: Path) -> Path:
    """The nearest existing path at or above ``path`` (something always exists: the root)."""
    probe = path
    while not os.path.lexists(probe):
        probe = probe.parent
    return probe


def _check_creatable(path: Path) -> None:
    """Raise unless ``path`` (absent) could be created: its nearest existing ancestor is a writable folder."""
    ancestor = _existing_ancestor(path.parent)
    if not ancestor.is_dir():
        raise CurbsideInputError(path, f"cannot write here: {ancestor} is a file, not a folder")
    if not os.access(ancestor, os.W_OK | os.X_OK):
        raise CurbsideInputError(path, f"cannot write here: no write permission in {ancestor}")


def written_by_curbside(path: str | os.PathLike[str]) -> bool:
    """Whether curbside wrote the file ``path``: its folder's marker lists it, or it carries a signature.

    Parameters
    ----------
    path
        An existing file.

    Returns
    -------
    bool
        ``True`` for a file listed in ``.curbside-output`` beside it, or one whose first bytes hold one
        of :data:`SIGNATURES`.
    """
    path = _absolute(path)
    doc = read_marker(path.parent)
    if doc is not None and path.name in doc["files"]:
        return True
    try:
        with open(path, "rb") as fh:
            head = fh.read(_SIGNATURE_BYTES)
    except OSError:
        return False
    return any(signature in head for signature in SIGNATURES)


def _same_file(a: Path, b: str | os.PathLike[str]) -> bool:
    try:
        return os.path.samefile(a, b)
    except OSError:
        return False


def check_output_file(
    path: str | os.PathLike[str],
    overwrite: bool = False,
    inputs: tuple[str | os.PathLike[str], ...] = (),
) -> Path:
    """Check early, before long work, that a command may write the file ``path``.

    Parameters
    ----------
    path
        The output file.
    overwrite
        Allow replacing an existing regular file that curbside did not write.
    inputs
        The command's input files: none of them may be the output.

    Returns
    -------
    pathlib.Path
        ``path`` made absolute.

    Raises
    ------
    CurbsideInputError
        ``path`` is a folder, a link or another non-regular file, one of ``inputs``, an existing file
        curbside did not write (without ``overwrite``), or neither it nor its missing parent folders
        can be written.
    """
    dst = _absolute(path)
    if dst.is_symlink():
        raise CurbsideInputError(path, "is a symbolic link; give the path of the file itself")
    if dst.is_dir():
        raise CurbsideInputError(path, "is a folder; give a file name")
    if not os.path.lexists(dst):
        _check_creatable(dst)
        return dst
    if not dst.is_file():
        raise CurbsideInputError(path, "exists and is not a regular file; give a file name")
    if any(_same_file(dst, source) for source in inputs):
        raise CurbsideInputError(path, "is also an input of this command; write the output elsewhere")
    if not overwrite and not written_by_curbside(dst):
        raise CurbsideInputError(
            path, "exists and was not written by curbside; pass --overwrite to replace it, or choose another "
            "name",
        )
    if not os.access(dst.parent, os.W_OK | os.X_OK):
        raise CurbsideInputError(path, f"cannot write here: no write permission in {dst.parent}")
    return dst


def check_output_folder(
    folder: str | os.PathLike[str], overwrite: bool = False, command: str | None = None
) -> Path:
    """Check early, before long work, that a command may write the folder ``folder``.

    Parameters
    ----------
    folder
        The output folder (``.`` allowed).
    overwrite
        Allow a non-empty folder that this command did not write (only the command's own files are
        replaced).
    command
        What will write it (as its marker records it, e.g. ``"localize run"``): a folder holding only other
        commands' output is refused without ``overwrite``. ``None`` accepts any curbside output.

    Returns
    -------
    pathlib.Path
        ``folder`` made absolute.

    Raises
    ------
    CurbsideInputError
        ``folder`` is a file; it is a non-empty folder without the curbside marker, or with another
        command's, and ``overwrite`` is off; or it cannot be written.
    """
    dst = _absolute(folder)
    if not os.path.lexists(dst):
        _check_creatable(dst)
        return dst
    if not dst.is_dir():
        raise CurbsideInputError(folder, "exists and is not a folder")
    if not os.access(dst, os.W_OK | os.X_OK):
        raise CurbsideInputError(folder, "cannot write here: no write permission")
    entries = [p.name for p in dst.iterdir() if not p.name.startswith(_STAGING_PREFIX)]
    if entries and read_marker(dst) is None and not overwrite:
        count = f"{len(entries)} entr{'y' if len(entries) == 1 else 'ies'}"
        raise CurbsideInputError(
            folder,
            f"folder is not empty ({count}) and was not written by curbside; pass --overwrite to write "
            "into it anyway (files curbside does not write are kept)",
        )
    others = _other_commands(dst, command)
    if entries and others and not overwrite:
        raise CurbsideInputError(
            folder,
            f"holds the output of {' and '.join(map(repr, others))}, not of '{command}'; write into another "
            "folder, or pass --overwrite to add this output beside it (nothing of the other is deleted)",
        )
    return dst


def _other_commands(folder: Path, command: str | None) -> list[str]:
    """The commands whose output ``folder``'s marker records, when ``command`` is not one of them (empty:
    it is, or no marker, or no command to compare)."""
    doc = read_marker(folder)
    if doc is None or command is None:
        return []
    records = command_files(doc)
    return [] if command in records else list(records)


def _staged_files(staged: Path) -> list[str]:
    files = []
    for path in staged.rglob("*"):
        if path.is_file() or path.is_symlink():
            rel = path.relative_to(staged).as_posix()
            if rel != MARKER:
                files.append(rel)
    return sorted(files)


def _check_conflicts(dst: Path, files: list[str]) -> None:
    for rel in files:
        target = dst / rel
        if target.is_dir() and not target.is_symlink():
            raise CurbsideInputError(target, "is a folder where the output has a file; move it")
        for parent in Path(rel).parents:
            if str(parent) != "." and (dst / parent).exists() and not (dst / parent).is_dir():
                raise CurbsideInputError(dst / parent, "is a file where the output has a folder; move it")


def _remove_stale(dst: Path, old: list[str], new: list[str]) -> None:
    """Delete files a previous curbside run listed in the marker and this run did not write again."""
    keep = set(new)
    removed_dirs = set()
    for rel in old:
        if rel in keep or rel == MARKER or Path(rel).is_absolute() or ".." in Path(rel).parts:
            continue
        path = dst / rel
        if path.is_file() or path.is_symlink():
            path.unlink()
            removed_dirs.update(p for p in Path(rel).parents if str(p) != ".")
    for rel_dir in sorted(removed_dirs, key=lambda p: len(p.parts), reverse=True):
        with contextlib.suppress(OSError):
            (dst / rel_dir).rmdir()  # only when empty: a user's file keeps its folder


def _commit_folder(staged: Path, dst: Path, command: str, overwrite: bool) -> None:
    """Move the staged folder's files onto ``dst`` under the output-folder rules."""
    check_output_folder(dst, overwrite, command)  # again: the folder may have changed during the run
    files = _staged_files(staged)
    if not os.path.lexists(dst):
        write_marker(staged, command, files)
        os.replace(staged, dst)
        return
    # Only this command's own earlier files are stale; another command's (with --overwrite) stay, and so
    # does what one derived from them (localize ronin's velocity.csv) while they come back unchanged.
    marker = read_marker(dst)
    old = [str(f) for f in command_files(marker).get(command, [])] if marker is not None else []
    derived = derived_files(dst, old, files)
    _check_conflicts(dst, files)
    for rel in files:
        target = dst / rel
        target.parent.mkdir(parents=True, exist_ok=True)
        os.replace(staged / rel, target)
    kept = settle_derived(dst, derived)
    _remove_stale(dst, old, files + kept)
    write_marker(dst, command, files)
    for rel in kept:
        note_record(dst / rel, derived[rel])


def _staging_dir(dst: Path) -> Path:
    """An empty temporary folder on the same file system as ``dst`` (inside it when it exists)."""
    base = dst if dst.is_dir() else dst.parent
    try:
        base.mkdir(parents=True, exist_ok=True)
        return Path(tempfile.mkdtemp(prefix=_STAGING_PREFIX if base == dst else f".{dst.name}.", dir=base))
    except OSError as exc:
        raise _cannot_write(dst, exc) from None


@contextlib.contextmanager
def output_folder(
    folder: str | os.PathLike[str], command: str, *, overwrite: bool = False
) -> Iterator[Path]:
    """Yield an empty staging folder; on success move its files into ``folder`` (see the module rules).

    Parameters
    ----------
    folder
        Destination folder; ``.`` and existing folders are fine when the rules allow them.
    command
        What writes it (recorded in the marker), e.g. ``"localize convert"``.
    overwrite
        Allow a non-empty folder that curbside did not write; only the command's files are replaced.

    Yields
    ------
    pathlib.Path
        An existing, empty folder to write into.

    Raises
    ------
    CurbsideInputError
        The folder may not or cannot be written (checked before the block runs and again after).
    """
    dst = check_output_folder(folder, overwrite, command)
    tmp_dir = _staging_dir(dst)
    staged = tmp_dir / "out"
    staged.mkdir()
    try:
        yield staged
        try:
            _commit_folder(staged, dst, command, overwrite)
        except OSError as exc:
            raise _cannot_write(dst, exc) from None
    finally:
        shutil.rmtree(tmp_dir, ignore_errors=True)


@contextlib.contextmanager
def atomic_path(dst: str | os.PathLike[str]) -> Iterator[Path]:
    """Yield a temporary path next to ``dst``; move it onto ``dst`` only if the block succeeds.

    The block creates a file or a folder at the yielded path. A file replaces ``dst`` (never a folder:
    that is an error). A folder is committed under the output-folder rules of :func:`output_folder`
    without ``--overwrite``: ``dst`` must be absent, empty or a previous curbside output, and files
    curbside did not write are kept. Nothing half-written is left behind when the block raises.

    Parameters
    ----------
    dst
        Final path of the file or directory.

    Yields
    ------
    pathlib.Path
        A path in the same file system as ``dst`` that does not exist yet.

    Raises
    ------
    CurbsideInputError
        ``dst`` cannot be written, or the block made a file where ``dst`` is a folder.
    """
    dst = _absolute(dst)
    tmp_dir = _staging_dir(dst)
    tmp = tmp_dir / (dst.name or "out")
    try:
        yield tmp
        if tmp.is_dir():
            try:
                _commit_folder(tmp, dst, "curbside", overwrite=False)
            except OSError as exc:
                raise _cannot_write(dst, exc) from None
        elif os.path.lexists(tmp):
            if dst.is_dir() and not dst.is_symlink():
                raise CurbsideInputError(dst, "is a folder; give a file name")
            try:
                os.replace(tmp, dst)
            except OSError as exc:
                raise _cannot_write(dst, exc) from None
    finally:
        shutil.rmtree(tmp_dir, ignore_errors=True)


def open_h5(path: str | os.PathLike[str]) -> h5py.File:
    """Open an HDF5 file read-only, or raise :class:`CurbsideInputError` naming it.

    Parameters
    ----------
    path
        The ``.h5`` file.

    Returns
    -------
    h5py.File
        Use it as a context manager.
    """
    import h5py  # only the HDF5 readers need it

    path = Path(path)
    if not path.is_file():
        raise CurbsideInputError(path, "no such file")
    try:
        return h5py.File(path, "r")
    except OSError as exc:
        raise CurbsideInputError(path, f"not a readable HDF5 file ({exc})") from None
