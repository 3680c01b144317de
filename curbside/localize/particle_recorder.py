"""A run's particle clouds packed as the walk goes: :class:`CloudRecorder` (``--save-particles``).

A run packs each footstep's cloud as soon as it is taken, into the form of ``particles.npz``
(:mod:`curbside.localize.particle_store`), 9 bytes per particle and footstep (18 kB at N = 2000), and
puts it on disk a chunk of :data:`CHUNK_BYTES` at a time (:mod:`curbside.localize.particle_spill`), so
that the memory it holds does not grow with the walk;
:func:`~curbside.localize.particle_store.write_particles` streams the chunks into ``particles.npz`` at the
end. The file is the same as when runs held every cloud in memory.
"""

from __future__ import annotations

from collections import Counter
from pathlib import Path

import numpy as np

from curbside.localize.particle_spill import SpilledClouds, SpillFile, spill_folder
from curbside.localize.particle_store import (
    FOOTSTEP_MEMBERS,
    FORMAT,
    PARTICLE_MEMBERS,
    encode_offset_dm,
    encode_scale_e4,
    encode_theta_ddeg,
    encode_weight_u8,
    warn_clipped,
)

#: The most a :class:`CloudRecorder` holds in memory (one chunk of footsteps; the others are on disk).
CHUNK_BYTES = 4 * 2**20


class CloudRecorder:
    """A run's particle clouds, each packed as soon as it is taken and written to disk a chunk at a time
    (``localize run --save-particles``).

    The clouds are packed into the int16/uint16/uint8 form of :mod:`~curbside.localize.particle_store`'s
    table, 9 bytes per particle and footstep, not floats, into a buffer of one chunk (at most
    ``chunk_bytes``); a full chunk is appended to unnamed temporary files in ``spill_dir``, so that the
    memory held stays that of one chunk however long the walk. :meth:`packed` gives the arrays of
    :func:`~curbside.localize.particle_store.pack_particles`, byte for byte those that
    :func:`~curbside.localize.particle_store.pack_snapshots` gives for the float32 snapshots (relative to
    the first estimate) that earlier versions held until the end of the walk.

    Parameters
    ----------
    crs
        WKT of the metric CRS of the particles.
    spill_dir
        Where the clouds go on disk: this folder, or its nearest existing parent (``localize run``
        gives its output folder); ``None``: the system's temporary folder. The files have no name
        there and go with the recorder (or the process).
    chunk_bytes
        The most the buffer holds (at least one footstep; default :data:`CHUNK_BYTES`).
    """

    def __init__(self, crs: str, spill_dir: str | Path | None = None, chunk_bytes: int | None = None) -> None:
        self.crs = str(crs)
        self.spill_dir = spill_dir
        self.chunk_bytes = CHUNK_BYTES if chunk_bytes is None else int(chunk_bytes)
        self._k = 0
        self._buffered = 0
        self._buffer: dict[str, np.ndarray] = {}
        self._spills: dict[str, SpillFile] = {}
        self._origin_m = (0.0, 0.0)
        self._uniform = True
        self._clipped: Counter[str] = Counter()

    def __len__(self) -> int:
        return self._k

    @property
    def buffer_bytes(self) -> int:
        """Bytes of the in-memory buffer (one chunk)."""
        return sum(values.nbytes for values in self._buffer.values())

    def add(
        self,
        t: float,
        ref_x_m: float,
        ref_y_m: float,
        x: np.ndarray,
        y: np.ndarray,
        theta_rad: np.ndarray,
        scale: np.ndarray,
        weight: np.ndarray,
    ) -> None:
        """Pack one footstep's cloud.

        Parameters
        ----------
        t
            Footstep time, s.
        ref_x_m, ref_y_m
            The estimate at this footstep (the offsets' origin), metres in ``crs``.
        x, y
            ``(N,)`` particle positions, metres in ``crs``.
        theta_rad, scale, weight
            ``(N,)`` heading drift (rad), speed scale and weights.

        Raises
        ------
        CurbsideInputError
            The spill folder cannot be written (full disk...).
        """
        if not self._k:
            self._origin_m = (float(ref_x_m), float(ref_y_m))
            self._start(len(x))
        i, rows, clipped = self._buffered, self._buffer, self._clipped
        (ox, oy), ref = self._origin_m, {"x": float(ref_x_m), "y": float(ref_y_m)}
        for axis, values, origin in (("x", x, ox), ("y", y, oy)):
            # Through float32 relative to the first estimate, as the snapshots were once held until the end
            # of the walk: the file keeps the bytes it had then.
            held = (np.asarray(values, np.float64) - origin).astype(np.float32)
            offset = held.astype(np.float64) + origin - ref[axis]
            rows[f"d{axis}_dm"][i] = encode_offset_dm(offset, clipped, axis)
        rows["theta_ddeg"][i] = encode_theta_ddeg(np.asarray(theta_rad, np.float32), clipped)
        rows["scale_e4"][i] = encode_scale_e4(np.asarray(scale, np.float32), clipped)
        w = np.asarray(weight, np.float64)
        self._uniform = self._uniform and bool(np.allclose(w, w[:1], rtol=0, atol=1e-12))
        rows["weight_u8"][i] = encode_weight_u8(w)
        rows["t"][i], rows["ref_x_m"][i], rows["ref_y_m"][i] = t, ref_x_m, ref_y_m
        self._k += 1
        self._buffered += 1
        if self._buffered == len(rows["t"]):
            self._spill()

    def _start(self, n: int) -> None:
        """The buffer, one chunk of footsteps of ``n`` particles, and the files its chunks go to."""
        folder = spill_folder(self.spill_dir)
        shapes = {name: (n,) for name in PARTICLE_MEMBERS} | {name: () for name in FOOTSTEP_MEMBERS}
        dtypes = PARTICLE_MEMBERS | FOOTSTEP_MEMBERS
        row_bytes = sum(np.dtype(dtypes[name]).itemsize * int(np.prod(shapes[name])) for name in dtypes)
        steps = max(1, self.chunk_bytes // row_bytes)
        self._buffer = {name: np.empty((steps, *shapes[name]), dtypes[name]) for name in dtypes}
        self._spills = {name: SpillFile(folder, dtypes[name], shapes[name]) for name in dtypes}

    def _spill(self) -> None:
        """Append the buffered footsteps to the files; the buffer is free again."""
        for name, values in self._buffer.items():
            self._spills[name].append(values[: self._buffered])
        self._buffered = 0

    def packed(self) -> SpilledClouds:
        """The arrays of :func:`~curbside.localize.particle_store.pack_particles` for the footsteps so far
        (later footsteps leave them as they are).

        Raises
        ------
        ValueError
            No footstep yet.
        CurbsideInputError
            The spill folder cannot be written.
        """
        if not self._k:
            raise ValueError("no particle cloud recorded")
        self._spill()
        warn_clipped(self._clipped)
        self._clipped.clear()
        stored = [name for name in PARTICLE_MEMBERS if name != "weight_u8" or not self._uniform]
        small = {"format": np.array(FORMAT), "crs": np.array(self.crs)}
        order = ["format", *FOOTSTEP_MEMBERS, "dx_dm", "dy_dm", "crs", *stored[2:]]
        return SpilledClouds(small, self._spills, self._k, order)
