"""On-disk caches: one folder, content-hash keys, npz for arrays, GeoParquet for tables.

Every cache of curbside lives under ``settings.cache_dir`` (the user's cache folder from
:func:`platformdirs.user_cache_dir`, ``$CURBSIDE_CACHE_DIR`` or whatever a program sets), one
sub-folder per kind of entry (``rasters``, ``osmsource``, ``overpass``, ``nominatim``). An entry is named by
a SHA-256 of everything it was derived from (:func:`content_key`), so a changed input or parameter
is a new entry and nothing is ever invalidated by hand.

Entries hold only plain data: numpy arrays in ``.npz`` (read with ``allow_pickle=False``) and
GeoDataFrames in GeoParquet, never pickles, so a cache file cannot run code. Writes are atomic (a
temporary file renamed into place), so a crash leaves no half-written entry; an entry that cannot be
read is reported with a warning and rebuilt, and a cache folder that cannot be written only costs
the rebuild next time.

Examples
--------
>>> from curbside import cache
>>> key = cache.content_key("raster-v2", 0.5, map_bytes)  # doctest: +SKIP
>>> arrays = cache.cached_arrays("rasters", key, build=lambda: {"codes": rasterise()},
...                              required=("codes",))  # doctest: +SKIP
"""

from __future__ import annotations

import contextlib
import hashlib
import logging
import os
import shutil
import uuid
from collections.abc import Callable, Iterable, Iterator, Mapping
from pathlib import Path

import geopandas as gpd
import numpy as np

from curbside import settings

log = logging.getLogger(__name__)

_CHUNK = 1 << 20


def cache_root() -> Path:
    """The cache folder now in force (``settings.cache_dir``; not created here)."""
    return Path(settings.cache_dir).expanduser()


def file_digest(path: str | Path) -> bytes:
    """SHA-256 of a file's bytes, read in chunks."""
    digest = hashlib.sha256()
    with open(path, "rb") as fh:
        while chunk := fh.read(_CHUNK):
            digest.update(chunk)
    return digest.digest()


def content_key(*parts: object) -> str:
    """SHA-256 hex digest of ``parts``, for naming a cache entry.

    Parameters
    ----------
    *parts
        ``bytes`` are hashed as they are, a :class:`pathlib.Path` by its file's content (not its
        name), a numpy array by its dtype, shape and bytes, a ``str`` as UTF-8 and anything else by
        its ``repr``. Each part is length-prefixed, so ``("ab", "c")`` and ``("a", "bc")`` differ.

    Returns
    -------
    str
        64 hex digits.
    """
    digest = hashlib.sha256()
    for part in parts:
        if isinstance(part, Path):
            data = b"file:" + file_digest(part)
        elif isinstance(part, bytes | bytearray | memoryview):
            data = b"bytes:" + bytes(part)
        elif isinstance(part, np.ndarray):
            array = np.ascontiguousarray(part)
            data = f"array:{array.dtype.str}:{array.shape}:".encode() + array.tobytes()
        elif isinstance(part, str):
            data = b"str:" + part.encode()
        else:
            data = b"repr:" + repr(part).encode()
        digest.update(len(data).to_bytes(8, "little"))
        digest.update(data)
    return digest.hexdigest()


def entry_path(kind: str, key: str, suffix: str) -> Path:
    """Where the entry ``key`` of ``kind`` lives: ``cache_root() / kind / (key + suffix)``."""
    return cache_root() / kind / f"{key}{suffix}"


def load_arrays(kind: str, key: str, required: Iterable[str] = ()) -> dict[str, np.ndarray] | None:
    """The arrays of an ``.npz`` entry, or ``None`` when it is absent or unreadable (with a warning).

    Parameters
    ----------
    kind, key
        See :func:`entry_path`.
    required
        Names the entry must hold; one missing makes the entry unreadable.
    """
    path = entry_path(kind, key, ".npz")
    if not path.is_file():
        return None
    try:
        with np.load(path, allow_pickle=False) as npz:
            arrays = {name: npz[name] for name in npz.files}
        missing = sorted(set(required) - set(arrays))
        if missing:
            raise KeyError(f"no {', '.join(missing)}")
    except Exception as exc:  # noqa: BLE001 - any unreadable entry is rebuilt, whatever numpy raises
        log.warning("rebuilding unreadable cache entry %s (%s: %s)", path, type(exc).__name__, exc)
        return None
    log.debug("cache hit %s", path)
    return arrays


@contextlib.contextmanager
def _staged(path: Path) -> Iterator[Path]:
    """A temporary name beside ``path`` (a file or a folder), renamed onto it when the block succeeds.

    Cache entries are curbside's own: an old entry at ``path`` is replaced; nothing is left behind on
    failure. (User-facing outputs go through :func:`curbside.io.output_folder` instead.)
    """
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp-{os.getpid()}-{uuid.uuid4().hex[:8]}")
    try:
        yield tmp
        if path.is_dir():
            shutil.rmtree(path)
        os.replace(tmp, path)
    finally:
        if tmp.is_dir():
            shutil.rmtree(tmp, ignore_errors=True)
        elif tmp.exists():
            tmp.unlink()


def save_arrays(kind: str, key: str, arrays: Mapping[str, np.ndarray]) -> Path | None:
    """Store arrays as a compressed ``.npz`` entry, atomically; ``None`` (and a warning) if it cannot.

    Object arrays are refused (they would need pickling): store strings as a numpy string dtype.
    """
    path = entry_path(kind, key, ".npz")
    for name, value in arrays.items():
        if np.asarray(value).dtype == object:
            raise TypeError(f"cache entry {kind}/{key}: array {name!r} has dtype object (would pickle)")
    try:
        with _staged(path) as tmp, open(tmp, "wb") as fh:
            np.savez_compressed(fh, **{name: np.asarray(value) for name, value in arrays.items()})
    except OSError as exc:
        log.warning("could not write cache entry %s (%s)", path, exc)
        return None
    return path


def load_frames(kind: str, key: str, names: Iterable[str]) -> dict[str, gpd.GeoDataFrame] | None:
    """The GeoDataFrames of a GeoParquet entry (a folder of ``<name>.parquet``), or ``None``.

    ``None`` when the entry is absent, or unreadable or lacking one of ``names`` (with a warning).
    """
    folder = entry_path(kind, key, "")
    if not folder.is_dir():
        return None
    try:
        frames = {name: gpd.read_parquet(folder / f"{name}.parquet") for name in names}
    except Exception as exc:  # noqa: BLE001 - pyarrow and geopandas raise many types for a bad file
        log.warning("rebuilding unreadable cache entry %s (%s: %s)", folder, type(exc).__name__, exc)
        return None
    log.debug("cache hit %s", folder)
    return frames


def save_frames(kind: str, key: str, frames: Mapping[str, gpd.GeoDataFrame]) -> Path | None:
    """Store GeoDataFrames as one GeoParquet file each in the entry's folder, atomically.

    Returns the folder, or ``None`` (and a warning) when it cannot be written.
    """
    folder = entry_path(kind, key, "")
    try:
        with _staged(folder) as tmp:
            tmp.mkdir()
            for name, frame in frames.items():
                frame.to_parquet(tmp / f"{name}.parquet")
    except OSError as exc:
        log.warning("could not write cache entry %s (%s)", folder, exc)
        return None
    return folder


def cached_arrays(
    kind: str,
    key: str,
    build: Callable[[], Mapping[str, np.ndarray]],
    required: Iterable[str] = (),
) -> dict[str, np.ndarray]:
    """The entry's arrays, or ``build()`` stored as the entry when it is absent or unreadable."""
    arrays = load_arrays(kind, key, required)
    if arrays is None:
        arrays = dict(build())
        save_arrays(kind, key, arrays)
    return arrays


def cached_frames(
    kind: str,
    key: str,
    build: Callable[[], Mapping[str, gpd.GeoDataFrame]],
    names: Iterable[str],
) -> dict[str, gpd.GeoDataFrame]:
    """The entry's GeoDataFrames, or ``build()`` stored as the entry when it is absent or unreadable."""
    names = tuple(names)
    frames = load_frames(kind, key, names)
    if frames is None:
        frames = dict(build())
        save_frames(kind, key, frames)
    return frames

