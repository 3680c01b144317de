"""Small file helpers shared by every stage: atomic writes."""

from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
from collections.abc import Iterator
from pathlib import Path


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
