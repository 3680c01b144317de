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

A run packs each footstep's cloud as soon as it is taken
(:class:`~curbside.localize.particle_recorder.CloudRecorder`) and puts it on disk a chunk at a time
(:mod:`curbside.localize.particle_spill`); :func:`write_particles` streams the chunks into
``particles.npz`` at the end. The file is the same as when runs held every cloud in memory: the recorder
and :func:`pack_particles` store each member with the same ``encode_*`` function.
"""

from __future__ import annotations

import logging
import zipfile
import zlib
from collections import Counter
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from curbside.errors import CurbsideInputError
from curbside.io import atomic_path
from curbside.localize.particle_spill import SpilledClouds

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
#: The members with a particle per column that a :class:`~curbside.localize.particle_recorder.CloudRecorder`
#: packs, and their types.
PARTICLE_MEMBERS = {"dx_dm": np.int16, "dy_dm": np.int16, "theta_ddeg": np.int16, "scale_e4": np.uint16,
                    "weight_u8": np.uint8}
#: The members with one value per footstep, and their types.
FOOTSTEP_MEMBERS = {"t": np.float64, "ref_x_m": np.float64, "ref_y_m": np.float64}
#: The members with a row per footstep, in either format that :func:`unpack_particles` reads.
_PER_FOOTSTEP = ("t", "ref_x_m", "ref_y_m", *PARTICLE_MEMBERS, "x", "y", "theta", "scale", "weight")


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


def encode_offset_dm(offset_m: np.ndarray, clipped: Counter[str], axis: str) -> np.ndarray:
    """Particle offsets from the estimate as stored (``dx_dm``, ``dy_dm``).

    Parameters
    ----------
    offset_m
        Offsets along ``axis``, metres.
    clipped
        Counts of clipped values, by what they are (:func:`warn_clipped`); this adds its own.
    axis
        ``"x"`` or ``"y"``.

    Returns
    -------
    numpy.ndarray
        int16 decimetres, clipped to the int16 range.
    """
    return _fixed(offset_m, OFFSET_UNIT_M, _INT16, clipped, f"particle {axis} offset")


def encode_theta_ddeg(theta_rad: np.ndarray, clipped: Counter[str]) -> np.ndarray:
    """Heading drift as stored (``theta_ddeg``): radians to int16 tenths of a degree in [-180, 180).

    Parameters
    ----------
    theta_rad
        Heading drift, radians (any turn: it is wrapped).
    clipped
        Counts of clipped values (:func:`warn_clipped`).

    Returns
    -------
    numpy.ndarray
    """
    wrapped = (np.degrees(np.asarray(theta_rad, np.float64)) + 180.0) % 360.0 - 180.0
    return _fixed(wrapped, THETA_UNIT_DEG, _INT16, clipped, "heading drift")


def encode_scale_e4(scale: np.ndarray, clipped: Counter[str]) -> np.ndarray:
    """Speed scale as stored (``scale_e4``): uint16 ten-thousandths, clipped to 0 .. 6.5.

    Parameters
    ----------
    scale
        Speed scale.
    clipped
        Counts of clipped values (:func:`warn_clipped`).

    Returns
    -------
    numpy.ndarray
    """
    return _fixed(scale, SCALE_UNIT, _UINT16, clipped, "speed scale")


def encode_weight_u8(weight: np.ndarray) -> np.ndarray:
    """Weights as stored (``weight_u8``): uint8, 255 for the largest of each footstep (the last axis).

    Parameters
    ----------
    weight
        ``(..., N)`` particle weights.

    Returns
    -------
    numpy.ndarray
    """
    w = np.asarray(weight, np.float64)
    peak = np.maximum(w.max(axis=-1, keepdims=True), np.finfo(float).tiny)
    return np.rint(255.0 * w / peak).astype(np.uint8)


def warn_clipped(clipped: Counter[str]) -> None:
    """Log a warning for each kind of value that was clipped to its stored range.

    Parameters
    ----------
    clipped
        Counts by what the values are, as the ``encode_*`` functions leave them.
    """
    for what, count in clipped.items():
        if count:
            log.warning("%d %s value(s) out of the stored range were clipped", count, what)


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
        encode_offset_dm(x - ref_x_m[:, None], clipped, "x"),
        encode_offset_dm(y - ref_y_m[:, None], clipped, "y"),
        None if theta_rad is None else encode_theta_ddeg(theta_rad, clipped),
        None if scale is None else encode_scale_e4(scale, clipped),
        None if weight is None else encode_weight_u8(weight),
    )
    warn_clipped(clipped)
    for name in ("theta_ddeg", "scale_e4", "weight_u8"):
        if name in packed and packed[name].shape != x.shape:
            raise ValueError(f"{name} has shape {packed[name].shape}, expected {x.shape}")
    return packed


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
    pack as they walk, with :class:`~curbside.localize.particle_recorder.CloudRecorder`, into the same bytes).

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
        The arrays of :func:`pack_particles`, or a
        :class:`~curbside.localize.particle_recorder.CloudRecorder`'s
        :class:`~curbside.localize.particle_spill.SpilledClouds` (streamed from disk,
        :data:`~curbside.localize.particle_spill.WRITE_BYTES` at a time).
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
