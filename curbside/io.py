"""Small file helpers shared by every stage: atomic writes, opening HDF5 datasets."""

from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING

from curbside.errors import CurbsideInputError

if TYPE_CHECKING:
    import h5py


@contextlib.contextmanager
def atomic_path(dst: str | os.PathLike[str]) -> Iterator[Path]:
    """Yield a temporary path next to ``dst``; move it onto ``dst`` only if the block succeeds.

    Works for files and for directories (the block may create either at the yielded path).
    Nothing half-written is left behind when the block raises.

    Parameters
    ----------
    dst
        Final path of the file or directory.

    Yields
    ------
    pathlib.Path
        A path in the same directory as ``dst`` that does not exist yet.
    """
    dst = Path(dst)
    dst.parent.mkdir(parents=True, exist_ok=True)
    tmp_dir = Path(tempfile.mkdtemp(prefix=f".{dst.name}.", dir=dst.parent))
    tmp = tmp_dir / dst.name
    try:
        yield tmp
        if dst.is_dir() and not dst.is_symlink():
            shutil.rmtree(dst)
        os.replace(tmp, dst)
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
