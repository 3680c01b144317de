"""The compact on-disk form of the particle clouds: ``particles.npz``.

``localize run --save-particles`` keeps the cloud at every footstep. Stored as float32 a 10-minute
walk at N = 500 takes 5.5 MB; stored here it takes about a third of that, and the replay viewer
(:mod:`curbside.localize.view`) reads it back. Each footstep's particles are kept as offsets from
that footstep's estimate, which are small, in fixed point:

========================  ===========  ===============================================================
member                    shape, type  meaning
========================  ===========  ===============================================================
``format``                ``()`` str   :data:`FORMAT`
``t``                     ``(K,)`` f8  footstep times, s
``ref_x_m``, ``ref_y_m``  ``(K,)`` f8  the estimate at each footstep (the offsets' origin), metres in ``crs``
``dx_dm``, ``dy_dm``      ``(K, N)``   particle offsets from the estimate, int16 decimetres (+-3.2 km)
``theta_ddeg``            ``(K, N)``   heading drift, int16 tenths of a degree in [-180, 180)
``scale_e4``              ``(K, N)``   speed scale, uint16 ten-thousandths (0 .. 6.5)
``weight_u8``             ``(K, N)``   only when the weights are not uniform: uint8, 255 = the step's largest
``crs``                   ``()`` str   WKT of the metric CRS of ``x``/``y``
========================  ===========  ===============================================================

The rounding errors are at most 5 cm, 0.05 degrees and 0.00005. An offset beyond the int16 range is
clipped (a particle more than 3.2 km from the estimate; a warning says how many). With the paper's
resampling at every footstep the weights are uniform and are not stored.

A run packs each footstep's cloud as soon as it is taken (:class:`CloudRecorder`), 9 bytes per particle
and footstep (18 kB at N = 2000), and puts it on disk a chunk of :data:`CHUNK_BYTES` at a time, so that
the memory it holds does not grow with the walk; :func:`write_particles` streams the chunks into
``particles.npz`` at the end. The file is the same as when runs held every cloud in memory.
"""

from __future__ import annotations

import logging
import os
import tempfile
import zipfile
import zlib
from collections import Counter
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO

import numpy as np

from curbside.errors import CurbsideInputError
from curbside.io import atomic_path

log = logging.getLogger(__name__)

#: Value of the ``format`` member.
FORMAT = "curbside-particles/2"
#: Metres per stored offset unit.
OFFSET_UNIT_M = 0.1
#: Degrees per stored heading unit.
THETA_UNIT_DEG = 0.1
#: Speed-scale units per stored unit.
SCALE_UNIT = 1e-4
_INT16 = np.iinfo(np.int16)
_UINT16 = np.iinfo(np.uint16)
#: The most a :class:`CloudRecorder` holds in memory (one chunk of footsteps; the others are on disk).
CHUNK_BYTES = 4 * 2**20
#: The most :func:`write_particles` reads from disk at once (zlib holds about twice that while it packs).
WRITE_BYTES = 2**20
#: The members with a particle per column that a :class:`CloudRecorder` packs, and their types.
_STORED = {"dx_dm": np.int16, "dy_dm": np.int16, "theta_ddeg": np.int16, "scale_e4": np.uint16,
           "weight_u8": np.uint8}
#: The members with one value per footstep, and their types.
_SCALARS = {"t": np.float64, "ref_x_m": np.float64, "ref_y_m": np.float64}
#: The members with a row per footstep, in either format that :func:`unpack_particles` reads.
_PER_FOOTSTEP = ("t", "ref_x_m", "ref_y_m", *_STORED, "x", "y", "theta", "scale", "weight")


@dataclass
class ParticleClouds:
    """The particle cloud at each footstep, unpacked.

    Attributes
    ----------
    t
        ``(K,)`` footstep times, s.
    x, y
        ``(K, N)`` particle positions, metres in ``crs``.
    theta_deg
        ``(K, N)`` heading drift, degrees, or ``None``.
    scale
        ``(K, N)`` speed scale, or ``None``.
    weight
        ``(K, N)`` weights normalised per footstep, or ``None`` for uniform weights.
    crs
        WKT of the metric CRS.
    """

    t: np.ndarray
    x: np.ndarray
    y: np.ndarray
    theta_deg: np.ndarray | None
    scale: np.ndarray | None
    weight: np.ndarray | None
    crs: str

    @property
    def n_particles(self) -> int:
        """Particles per footstep."""
        return int(self.x.shape[1])


def _fixed(values: np.ndarray, unit: float, info: np.iinfo, clipped: Counter[str], what: str) -> np.ndarray:
    """``values`` in ``unit`` steps as ``info.dtype``, clipped to its range (counted in ``clipped[what]``)."""
    scaled = np.rint(np.asarray(values, np.float64) / unit)
    clipped[what] += int(np.count_nonzero((scaled < info.min) | (scaled > info.max)))
    return np.clip(scaled, info.min, info.max).astype(info.dtype)


def pack_particles(
    t: np.ndarray,
    x: np.ndarray,
    y: np.ndarray,
    ref_x_m: np.ndarray,
    ref_y_m: np.ndarray,
    crs: str,
    *,
    theta_rad: np.ndarray | None = None,
    scale: np.ndarray | None = None,
    weight: np.ndarray | None = None,
) -> dict[str, np.ndarray]:
    """The compact arrays of the module's table, ready for :func:`numpy.savez_compressed`.

    Parameters
    ----------
    t
        ``(K,)`` footstep times, s.
    x, y
        ``(K, N)`` particle positions, metres in ``crs``.
    ref_x_m, ref_y_m
        ``(K,)`` the estimate at each footstep (any point near the cloud will do), metres in ``crs``.
    crs
        WKT (or any string pyproj reads) of the metric CRS.
    theta_rad
        ``(K, N)`` heading drift, radians (wrapped to [-pi, pi)).
    scale
        ``(K, N)`` speed scale.
    weight
        ``(K, N)`` particle weights; ``None`` when uniform (after resampling).

    Returns
    -------
    dict of numpy.ndarray

    Raises
    ------
    ValueError
        Shapes that do not agree.
    """
    t = np.asarray(t, np.float64)
    x, y = np.atleast_2d(x), np.atleast_2d(y)
    ref_x_m, ref_y_m = np.asarray(ref_x_m, np.float64), np.asarray(ref_y_m, np.float64)
    if x.shape != y.shape or x.shape[0] != len(t) or ref_x_m.shape != t.shape or ref_y_m.shape != t.shape:
        raise ValueError(f"shapes disagree: t {t.shape}, x {x.shape}, y {y.shape}, ref {ref_x_m.shape}")
    clipped: Counter[str] = Counter()
    packed = _assemble(
        t,
        ref_x_m,
        ref_y_m,
        crs,
        _fixed(x - ref_x_m[:, None], OFFSET_UNIT_M, _INT16, clipped, "particle x offset"),
        _fixed(y - ref_y_m[:, None], OFFSET_UNIT_M, _INT16, clipped, "particle y offset"),
        None if theta_rad is None else _fixed_theta(theta_rad, clipped),
        None if scale is None else _fixed(scale, SCALE_UNIT, _UINT16, clipped, "speed scale"),
        None if weight is None else _weight_u8(weight),
    )
    _warn_clipped(clipped)
    for name in ("theta_ddeg", "scale_e4", "weight_u8"):
        if name in packed and packed[name].shape != x.shape:
            raise ValueError(f"{name} has shape {packed[name].shape}, expected {x.shape}")
    return packed


def _fixed_theta(theta_rad: np.ndarray, clipped: Counter[str]) -> np.ndarray:
    wrapped = (np.degrees(np.asarray(theta_rad, np.float64)) + 180.0) % 360.0 - 180.0
    return _fixed(wrapped, THETA_UNIT_DEG, _INT16, clipped, "heading drift")


def _weight_u8(weight: np.ndarray) -> np.ndarray:
    w = np.asarray(weight, np.float64)
    peak = np.maximum(w.max(axis=-1, keepdims=True), np.finfo(float).tiny)
    return np.rint(255.0 * w / peak).astype(np.uint8)


def _warn_clipped(clipped: Counter[str]) -> None:
    for what, count in clipped.items():
        if count:
            log.warning("%d %s value(s) out of the stored range were clipped", count, what)


def _assemble(
    t: np.ndarray,
    ref_x_m: np.ndarray,
    ref_y_m: np.ndarray,
    crs: str,
    dx_dm: np.ndarray,
    dy_dm: np.ndarray,
    theta_ddeg: np.ndarray | None,
    scale_e4: np.ndarray | None,
    weight_u8: np.ndarray | None,
) -> dict[str, np.ndarray]:
    """The members in the order they are written (the order is part of the file's bytes)."""
    packed = {
        "format": np.array(FORMAT),
        "t": np.asarray(t, np.float64),
        "ref_x_m": np.asarray(ref_x_m, np.float64),
        "ref_y_m": np.asarray(ref_y_m, np.float64),
        "dx_dm": dx_dm,
        "dy_dm": dy_dm,
        "crs": np.array(str(crs)),
    }
    optional = {"theta_ddeg": theta_ddeg, "scale_e4": scale_e4, "weight_u8": weight_u8}
    return packed | {name: values for name, values in optional.items() if values is not None}


def pack_snapshots(snapshots: dict[str, np.ndarray], ref_x_m: np.ndarray, ref_y_m: np.ndarray) -> dict:
    """Pack float32 snapshots: the ``particles.npz`` of curbside versions before :data:`FORMAT` (runs now
    pack as they walk, with :class:`CloudRecorder`, into the same bytes).

    Parameters
    ----------
    snapshots
        ``t``, ``x``, ``y`` (relative to ``origin``), ``theta``, ``scale``, ``origin``, ``crs``, and
        optionally ``weight``.
    ref_x_m, ref_y_m
        The estimate at each footstep (``track.csv``'s ``x_m``, ``y_m``), absolute metres.

    Returns
    -------
    dict of numpy.ndarray
        See :func:`pack_particles`.
    """
    ox, oy = np.asarray(snapshots["origin"], np.float64)
    return pack_particles(
        snapshots["t"],
        np.asarray(snapshots["x"], np.float64) + ox,
        np.asarray(snapshots["y"], np.float64) + oy,
        ref_x_m,
        ref_y_m,
        str(snapshots["crs"]),
        theta_rad=snapshots.get("theta"),
        scale=snapshots.get("scale"),
        weight=snapshots.get("weight"),
    )


class _Spill:
    """One member's rows on disk, appended a chunk at a time, in an unnamed temporary file: it has no name
    in ``folder``, and goes when it is closed or the process ends, however it ends."""

    def __init__(self, folder: Path, dtype: np.dtype, row_shape: tuple[int, ...]) -> None:
        self.folder, self.dtype, self.row_shape = folder, np.dtype(dtype), row_shape
        self.row_bytes = self.dtype.itemsize * int(np.prod(row_shape))
        try:
            self.file = tempfile.TemporaryFile(dir=folder)  # noqa: SIM115 (open for the recorder's life)
        except OSError as exc:
            raise _cannot_spill(folder, exc) from None

    def append(self, rows: np.ndarray) -> None:
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


def _spill_folder(near: str | Path | None) -> Path:
    """``near`` if it is a folder, else its nearest existing parent (``None``: the temporary folder)."""
    if near is None:
        return Path(tempfile.gettempdir())
    folder = Path(os.path.abspath(near))
    while not folder.is_dir() and folder != folder.parent:
        folder = folder.parent
    return folder


class SpilledClouds(Mapping[str, np.ndarray]):
    """The arrays of :func:`pack_particles` for a :class:`CloudRecorder`'s footsteps, their rows on disk.

    A member with a row per footstep reads as a read-only :class:`numpy.memmap` (indexing a few rows
    reads only them: :func:`select_footsteps`); :func:`write_particles` streams each member into
    ``particles.npz`` a block at a time.
    """

    def __init__(self, small: dict[str, np.ndarray], spills: dict[str, _Spill], rows: int,
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


class CloudRecorder:
    """A run's particle clouds, each packed as soon as it is taken and written to disk a chunk at a time
    (``localize run --save-particles``).

    The clouds are packed into the int16/uint16/uint8 form of the module's table, 9 bytes per particle
    and footstep, not floats, into a buffer of one chunk (at most ``chunk_bytes``); a full chunk is
    appended to unnamed temporary files in ``spill_dir``, so that the memory held stays that of one
    chunk however long the walk. :meth:`packed` gives the arrays of :func:`pack_particles`, byte for byte
    those that :func:`pack_snapshots` gives for the float32 snapshots (relative to the first estimate)
    that earlier versions held until the end of the walk.

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
        self._spills: dict[str, _Spill] = {}
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
            what = f"particle {axis} offset"
            rows[f"d{axis}_dm"][i] = _fixed(offset, OFFSET_UNIT_M, _INT16, clipped, what)
        rows["theta_ddeg"][i] = _fixed_theta(np.asarray(theta_rad, np.float32), clipped)
        held_scale = np.asarray(scale, np.float32)
        rows["scale_e4"][i] = _fixed(held_scale, SCALE_UNIT, _UINT16, clipped, "speed scale")
        w = np.asarray(weight, np.float64)
        self._uniform = self._uniform and bool(np.allclose(w, w[:1], rtol=0, atol=1e-12))
        rows["weight_u8"][i] = _weight_u8(w)
        rows["t"][i], rows["ref_x_m"][i], rows["ref_y_m"][i] = t, ref_x_m, ref_y_m
        self._k += 1
        self._buffered += 1
        if self._buffered == len(rows["t"]):
            self._spill()

    def _start(self, n: int) -> None:
        """The buffer, one chunk of footsteps of ``n`` particles, and the files its chunks go to."""
        folder = _spill_folder(self.spill_dir)
        shapes = {name: (n,) for name in _STORED} | {name: () for name in _SCALARS}
        dtypes = _STORED | _SCALARS
        row_bytes = sum(np.dtype(dtypes[name]).itemsize * int(np.prod(shapes[name])) for name in dtypes)
        steps = max(1, self.chunk_bytes // row_bytes)
        self._buffer = {name: np.empty((steps, *shapes[name]), dtypes[name]) for name in dtypes}
        self._spills = {name: _Spill(folder, dtypes[name], shapes[name]) for name in dtypes}

    def _spill(self) -> None:
        """Append the buffered footsteps to the files; the buffer is free again."""
        for name, values in self._buffer.items():
            self._spills[name].append(values[: self._buffered])
        self._buffered = 0

    def packed(self) -> SpilledClouds:
        """The arrays of :func:`pack_particles` for the footsteps so far (later footsteps leave them as
        they are).

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
        _warn_clipped(self._clipped)
        self._clipped.clear()
        stored = [name for name in _STORED if name != "weight_u8" or not self._uniform]
        small = {"format": np.array(FORMAT), "crs": np.array(self.crs)}
        order = ["format", *_SCALARS, "dx_dm", "dy_dm", "crs", *stored[2:]]
        return SpilledClouds(small, self._spills, self._k, order)


def select_footsteps(packed: Mapping[str, np.ndarray], rows: np.ndarray | list[int]) -> dict[str, np.ndarray]:
    """The footsteps ``rows`` of packed clouds, still packed, so that only they are unpacked.

    ``unpack_particles(select_footsteps(packed, rows))`` is ``unpack_particles(packed)`` at ``rows``, for
    both formats that :func:`unpack_particles` reads, without turning the other footsteps into floats.

    Parameters
    ----------
    packed
        The arrays of :func:`pack_particles` (or the float32 snapshots of earlier versions).
    rows
        Footstep indices, in any order, repeats allowed.

    Returns
    -------
    dict of numpy.ndarray
        The same members, those with a row per footstep cut to ``rows``.

    Raises
    ------
    IndexError
        A row beyond the footsteps.
    """
    rows = np.asarray(rows, np.intp)
    return {name: values[rows] if name in _PER_FOOTSTEP else values for name, values in packed.items()}


def unpack_particles(packed: Mapping[str, np.ndarray], source: str = "particles") -> ParticleClouds:
    """The clouds back from :func:`pack_particles`'s arrays.

    The float32 snapshots of earlier curbside versions (``x``, ``y`` relative to ``origin``) are read
    too: they are packed first, around each footstep's particle mean.

    Raises
    ------
    CurbsideInputError
        Neither format, or arrays of the wrong shape or type.
    """
    try:
        names = set(packed)
        if "format" not in names and {"x", "y", "origin", "t", "crs"} <= names:
            ox, oy = np.asarray(packed["origin"], np.float64)
            x, y = np.asarray(packed["x"], np.float64), np.asarray(packed["y"], np.float64)
            packed = pack_snapshots(dict(packed), x.mean(axis=1) + ox, y.mean(axis=1) + oy)
            names = set(packed)
        fmt = str(packed["format"]) if "format" in names else None
        if fmt != FORMAT:
            raise CurbsideInputError(
                source,
                f"not a {FORMAT} particle store (format {fmt!r}); re-run `localize run --save-particles`",
            )
        return _clouds(packed)
    except (KeyError, ValueError, IndexError, TypeError) as exc:
        detail = (str(exc).splitlines() or [type(exc).__name__])[0].strip()
        raise CurbsideInputError(
            source, f"not a readable {FORMAT} particle store (an array is missing or malformed: {detail})"
        ) from None


def _clouds(packed: Mapping[str, np.ndarray]) -> ParticleClouds:
    """:func:`unpack_particles` for arrays in the current format."""
    names = set(packed)
    ref_x, ref_y = packed["ref_x_m"], packed["ref_y_m"]
    weight = None
    if "weight_u8" in names:
        w = packed["weight_u8"].astype(np.float64)
        weight = w / np.maximum(w.sum(axis=1, keepdims=True), 1.0)
    return ParticleClouds(
        t=np.asarray(packed["t"], np.float64),
        x=ref_x[:, None] + packed["dx_dm"] * OFFSET_UNIT_M,
        y=ref_y[:, None] + packed["dy_dm"] * OFFSET_UNIT_M,
        theta_deg=packed["theta_ddeg"] * THETA_UNIT_DEG if "theta_ddeg" in names else None,
        scale=packed["scale_e4"] * SCALE_UNIT if "scale_e4" in names else None,
        weight=weight,
        crs=str(packed["crs"]),
    )


def write_particles(packed: Mapping[str, np.ndarray], path: str | Path) -> Path:
    """Write packed clouds as a compressed ``.npz`` (atomically: nothing is left at ``path``, or beside
    it, when this fails or is interrupted).

    Parameters
    ----------
    packed
        The arrays of :func:`pack_particles`, or a :class:`CloudRecorder`'s :class:`SpilledClouds`
        (streamed from disk, :data:`WRITE_BYTES` at a time).
    path
        The ``.npz`` to write.

    Returns
    -------
    pathlib.Path
        ``path``.
    """
    path = Path(path)
    with atomic_path(path) as tmp, open(tmp, "wb") as fh:
        if isinstance(packed, SpilledClouds):
            packed.write_npz(fh)
        else:
            np.savez_compressed(fh, **packed)
    return path


def read_particles(path: str | Path) -> ParticleClouds:
    """Read a ``particles.npz`` written by :func:`write_particles`.

    Raises
    ------
    CurbsideInputError
        Missing or unreadable file, or another format.
    """
    path = Path(path)
    try:
        with np.load(path, allow_pickle=False) as npz:
            packed = {k: npz[k] for k in npz.files}
    except FileNotFoundError:
        raise CurbsideInputError(path, "no such file") from None
    except OSError as exc:
        raise CurbsideInputError(path, f"cannot read ({exc.strerror or exc})") from None
    except (ValueError, EOFError, zipfile.BadZipFile, zlib.error, NotImplementedError):
        raise CurbsideInputError(
            path, "not a readable particle store (not an .npz, or a corrupt or truncated one); "
            "re-run `localize run --save-particles`"
        ) from None
    return unpack_particles(packed, str(path))
