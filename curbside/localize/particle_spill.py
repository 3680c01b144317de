"""The particle clouds of a run on disk while the walk goes: the spill files behind ``--save-particles``.

A :class:`~curbside.localize.particle_recorder.CloudRecorder` appends each full chunk of packed footsteps
to one :class:`SpillFile` per member of ``particles.npz`` (:mod:`curbside.localize.particle_store`):
unnamed temporary files, in the run's output folder or its nearest existing parent
(:func:`spill_folder`), that go when they are closed or the process ends, however it ends.
:class:`SpilledClouds` reads them back as memory maps, and writes them into ``particles.npz``
:data:`WRITE_BYTES` at a time.
"""

from __future__ import annotations

import os
import tempfile
import zipfile
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import BinaryIO

import numpy as np

from curbside.errors import CurbsideInputError

#: The most :func:`~curbside.localize.particle_store.write_particles` reads from disk at once (zlib holds
#: about twice that while it packs).
WRITE_BYTES = 2**20


class SpillFile:
    """One member's rows on disk, appended a chunk at a time, in an unnamed temporary file: it has no name
    in ``folder``, and goes when it is closed or the process ends, however it ends.

    Parameters
    ----------
    folder
        Where the file goes (:func:`spill_folder`).
    dtype
        The member's type.
    row_shape
        The shape of one row (one footstep): ``(N,)`` or ``()``.

    Raises
    ------
    CurbsideInputError
        ``folder`` cannot be written.
    """

    def __init__(self, folder: Path, dtype: np.dtype, row_shape: tuple[int, ...]) -> None:
        self.folder, self.dtype, self.row_shape = folder, np.dtype(dtype), row_shape
        self.row_bytes = self.dtype.itemsize * int(np.prod(row_shape))
        try:
            self.file = tempfile.TemporaryFile(dir=folder)  # noqa: SIM115 (open for the recorder's life)
        except OSError as exc:
            raise _cannot_spill(folder, exc) from None

    def append(self, rows: np.ndarray) -> None:
        """Append ``rows`` (a full disk: :class:`~curbside.errors.CurbsideInputError`)."""
        try:
            self.file.write(np.ascontiguousarray(rows, self.dtype).data)
            self.file.flush()
        except OSError as exc:
            raise _cannot_spill(self.folder, exc) from None

    def array(self, rows: int) -> np.ndarray:
        """The first ``rows`` rows, mapped read-only: only the rows indexed are read."""
        return np.memmap(self.file, self.dtype, "r", shape=(rows, *self.row_shape))

    def blocks(self, rows: int, block_bytes: int) -> Iterator[np.ndarray]:
        """The first ``rows`` rows, ``block_bytes`` (or a row) at a time, each mapped while handed out."""
        step = max(1, block_bytes // max(self.row_bytes, 1))
        for start in range(0, rows, step):
            shape = (min(step, rows - start), *self.row_shape)
            yield np.memmap(self.file, self.dtype, "r", offset=start * self.row_bytes, shape=shape)


def _cannot_spill(folder: Path, exc: OSError) -> CurbsideInputError:
    return CurbsideInputError(folder, f"cannot hold the particle clouds on disk here ({exc.strerror or exc})")


def spill_folder(near: str | Path | None) -> Path:
    """Where a run's spill files go.

    Parameters
    ----------
    near
        A folder (a run's output folder, which may not exist yet), or ``None``.

    Returns
    -------
    pathlib.Path
        ``near`` if it is a folder, else its nearest existing parent (``None``: the temporary folder).
    """
    if near is None:
        return Path(tempfile.gettempdir())
    folder = Path(os.path.abspath(near))
    while not folder.is_dir() and folder != folder.parent:
        folder = folder.parent
    return folder


class SpilledClouds(Mapping[str, np.ndarray]):
    """The arrays of :func:`~curbside.localize.particle_store.pack_particles` for a
    :class:`~curbside.localize.particle_recorder.CloudRecorder`'s footsteps, their rows on disk.

    A member with a row per footstep reads as a read-only :class:`numpy.memmap` (indexing a few rows
    reads only them: :func:`~curbside.localize.particle_store.select_footsteps`);
    :func:`~curbside.localize.particle_store.write_particles` streams each member into ``particles.npz``
    a block at a time.
    """

    def __init__(self, small: dict[str, np.ndarray], spills: dict[str, SpillFile], rows: int,
                 order: list[str]) -> None:
        self._small, self._spills, self._rows, self._order = small, spills, rows, order

    def __getitem__(self, name: str) -> np.ndarray:
        if name not in self._order:
            raise KeyError(name)
        return self._small[name] if name in self._small else self._spills[name].array(self._rows)

    def __iter__(self) -> Iterator[str]:
        return iter(self._order)

    def __len__(self) -> int:
        return len(self._order)

    def write_npz(self, fh: BinaryIO) -> None:
        """Write the members as :func:`numpy.savez_compressed` does (the same members, in the same order,
        as the same bytes), reading :data:`WRITE_BYTES` of them at a time."""
        with zipfile.ZipFile(fh, "w", zipfile.ZIP_DEFLATED, allowZip64=True) as npz:
            for name in self._order:
                with npz.open(f"{name}.npy", "w", force_zip64=True) as member:
                    if name in self._small:
                        np.lib.format.write_array(member, self._small[name], allow_pickle=False)
                        continue
                    spill = self._spills[name]
                    np.lib.format.write_array_header_1_0(member, {
                        "descr": np.lib.format.dtype_to_descr(spill.dtype),
                        "fortran_order": False,
                        "shape": (self._rows, *spill.row_shape),
                    })
                    for block in spill.blocks(self._rows, WRITE_BYTES):
                        member.write(block.tobytes())
