"""Training data for RoNIN: recordings from three HDF5 layouts, weak labels, splits and windows.

Every source becomes a list of :class:`Recording`: the world-frame IMU (gyroscope and accelerometer
rotated with the phone's orientation, :mod:`curbside.localize.imu`) at its own sample times, plus
ground-truth positions ``(t, x, y)`` in metres **in the same world frame as the IMU** (labels and
inputs must share their yaw). Positions between two ground-truth points are linear in time, so the
label of a one-second window is the displacement of that piecewise-linear path over the window
divided by its duration: exact for dense ground truth (RoNIN), and the paper's "straight line at
constant speed" assumption for sparse waypoints.

Sources
-------
``ms-indoor-2020.h5`` (Indoor Location Competition 2.0, MIT)
    Waypoints are in a floor-plan frame with an unknown rotation to north. For every waypoint
    segment the heading of the phone's forward axis (held flat in front of the walker) is compared
    with the segment's direction in the plan; the length-weighted circular mean of these
    differences over a path rotates its waypoints into the rotation vector's East-North-Up frame.
    When a path's differences disagree (resultant length below ``min_heading_consistency``), the
    circular mean of its floor (over consistent paths) is used instead. This also absorbs the
    magnetic heading bias of that path indoors.
``ipin2023-t3.h5`` (IPIN 2023 Track 3)
    Surveyed waypoints in lat/lon, projected onto a local azimuthal-equidistant plane around the
    first waypoint (true north up). The rotation vector's north is magnetic and disturbed indoors
    (by -6 to +23 degrees per route here), so training and validation trials get the same
    forward-axis rotation as MS paths (when consistent); held-out test trials keep true north, so
    that the figures measure what a user gets.
RoNIN HDF5 layout (one folder per sequence holding ``data.hdf5``)
    ``synced/time`` (N,) s, ``synced/gyro`` (N,3) rad/s, ``synced/acce`` (N,3) m/s^2,
    ``synced/game_rv`` (N,4) quaternion **w,x,y,z**, ``pose/tango_pos`` (N,3) m and
    ``pose/tango_ori`` (N,4) w,x,y,z, all on the 200 Hz ``synced`` clock. The game rotation vector's
    yaw differs from Tango's by a constant: it is estimated as the circular mean over the sequence of
    the yaw of ``tango_ori * game_rv^-1``, and the Tango positions are rotated into the game frame.

Splits are by recording, never by window (:func:`split_of`).
"""

from __future__ import annotations

import hashlib
import json
import logging
import zipfile
import zlib
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

import h5py
import numpy as np
import pandas as pd
from scipy.spatial.transform import Rotation
from tqdm.auto import tqdm

from curbside.errors import CurbsideInputError
from curbside.io import atomic_path, open_h5
from curbside.localize.imu import world_frame_segments
from curbside.localize.pdr import forward_heading_vectors
from curbside.localize.ronin.provenance import check_prepared_sources, ronin_sequence_files, source_records

logger = logging.getLogger(__name__)

#: Share of MS paths held out for the test figures and for validation (by a seeded hash of the id).
MS_TEST_FRACTION = 0.15
MS_VAL_FRACTION = 0.07
#: IPIN trials held out for testing: every ``repetition04``.
IPIN_TEST_MARK = "repetition04"
#: Salt of the split hash; changing it changes which recordings are held out.
SPLIT_SALT = "curbside-ronin-split-v1"


@dataclass
class Recording:
    """One continuous recording with ground truth, in one world frame.

    Attributes
    ----------
    name
        Unique id, e.g. ``ms/site1/B1/5dda1497...`` or ``ipin/TrainingTrial01_repetition01``.
    source
        ``"ms"``, ``"ipin"`` or ``"ronin"``.
    t
        ``(N,)`` IMU sample times (s), increasing, no gap longer than the interpolation limit.
    features
        ``(N, 6)`` float32 world-frame gyroscope (rad/s) and accelerometer (m/s^2, gravity kept).
    positions
        ``(M, 3)`` ground truth ``t, x, y`` (s, m, m) in the IMU's world frame (x east-like).
    split
        ``"train"``, ``"val"`` or ``"test"``.
    imu
        The raw ``imu.csv`` table, kept only when asked for (baselines such as PDR need it); not
        stored by :func:`save_recordings`.
    """

    name: str
    source: str
    t: np.ndarray
    features: np.ndarray
    positions: np.ndarray
    split: str = "train"
    imu: pd.DataFrame | None = None

    def on_grid(self, rate_hz: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Features and label positions on a uniform clock over the ground-truth span.

        Returns
        -------
        t, features, xy
            ``(n,)`` times, ``(n, 6)`` float32 features (linearly interpolated), ``(n, 2)`` float64
            positions on the piecewise-linear ground-truth path.
        """
        t0 = max(self.t[0], self.positions[0, 0])
        t1 = min(self.t[-1], self.positions[-1, 0])
        if t1 <= t0:
            return np.zeros(0), np.zeros((0, 6), np.float32), np.zeros((0, 2))
        t = t0 + np.arange(int(np.floor((t1 - t0) * rate_hz)) + 1) / rate_hz
        feats = np.column_stack([np.interp(t, self.t, self.features[:, k]) for k in range(6)])
        feats = feats.astype(np.float32)
        xy = np.column_stack([np.interp(t, self.positions[:, 0], self.positions[:, k]) for k in (1, 2)])
        return t, feats, xy


def _hash_fraction(name: str) -> float:
    digest = hashlib.sha1(f"{SPLIT_SALT}:{name}".encode()).hexdigest()
    return int(digest[:12], 16) / float(16**12)


def split_of(name: str, source: str) -> str:
    """The split of a recording: ``"test"``, ``"val"`` or ``"train"``.

    MS paths and RoNIN sequences: a hash of the path id (sequence folder name) puts 15 % in test and
    7 % in validation. IPIN trials: every ``repetition04`` is test, the rest train (no validation).
    """
    if source == "ipin":
        return "test" if IPIN_TEST_MARK in name else "train"
    u = _hash_fraction(name.rsplit("/", 1)[-1])
    if u < MS_TEST_FRACTION:
        return "test"
    if u < MS_TEST_FRACTION + MS_VAL_FRACTION:
        return "val"
    return "train"


def _circular_mean(angles: np.ndarray, weights: np.ndarray | None = None) -> tuple[float, float]:
    """Mean angle (rad) and resultant length (0..1)."""
    w = np.ones_like(angles) if weights is None else weights
    z = np.sum(w * np.exp(1j * angles)) / max(np.sum(w), 1e-12)
    return float(np.angle(z)), float(np.abs(z))


def _rotate_xy(xy: np.ndarray, angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return xy @ np.array([[c, s], [-s, c]])


def plan_rotation(t: np.ndarray, forward_xy: np.ndarray, waypoints: np.ndarray,
                  min_segment_m: float = 2.0) -> tuple[float, float]:
    """Rotation (rad, counter-clockwise) taking a path's plan-frame waypoints into the IMU world frame.

    Parameters
    ----------
    t
        ``(N,)`` IMU times.
    forward_xy
        ``(N, 2)`` forward-axis unit vectors in the world frame
        (:func:`curbside.localize.pdr.forward_heading_vectors`).
    waypoints
        ``(M, 3)`` ``t, x, y`` in the plan frame.
    min_segment_m
        Shorter segments say little about direction and are ignored.

    Returns
    -------
    angle, consistency
        The length-weighted circular mean of (phone heading - segment direction) and its resultant
        length (1: every segment agrees). ``(0, 0)`` when no segment qualifies.
    """
    seg = np.diff(waypoints[:, 1:], axis=0)
    length = np.linalg.norm(seg, axis=1)
    cum = np.vstack([np.zeros((1, 2)), np.cumsum(forward_xy, axis=0)])
    lo = np.searchsorted(t, waypoints[:-1, 0])
    hi = np.searchsorted(t, waypoints[1:, 0])
    ok = (length >= min_segment_m) & (hi - lo >= 5)
    if not ok.any():
        return 0.0, 0.0
    heading = cum[hi[ok]] - cum[lo[ok]]
    diff = np.arctan2(heading[:, 1], heading[:, 0]) - np.arctan2(seg[ok, 1], seg[ok, 0])
    return _circular_mean(diff, length[ok])


def _finite_positions(positions: np.ndarray, src: str) -> np.ndarray:
    """Ground-truth rows whose time and position are finite (a NaN would make every label it touches
    NaN, and the training loss with them), with a warning when some are not."""
    finite = np.isfinite(positions).all(axis=1)
    if not finite.all():
        logger.warning("%s: %d ground-truth row(s) with NaN or infinite values dropped", src,
                       int((~finite).sum()))
    return positions[finite]


def _recordings_from_imu(name: str, source: str, imu: pd.DataFrame, positions: np.ndarray,
                         src: str, keep_imu: Iterable[str] = ()) -> list[Recording]:
    positions = _finite_positions(positions, src)
    if len(positions) < 2:
        logger.warning("%s: skipped (fewer than 2 finite ground-truth positions)", src)
        return []
    out = []
    split = split_of(name, source)
    for k, seg in enumerate(world_frame_segments(imu, src, min_duration_s=2.0)):
        feats = seg[["wgx", "wgy", "wgz", "wax", "way", "waz"]].to_numpy(np.float32)
        rec_name = name if k == 0 else f"{name}#{k}"
        t = seg["t"].to_numpy()
        raw = None
        if split in keep_imu:
            raw = imu[(imu["t"] >= t[0]) & (imu["t"] <= t[-1])].reset_index(drop=True)
        out.append(Recording(rec_name, source, t, feats, positions, split, raw))
    return out


def read_ms_indoor(path: str | Path, min_heading_consistency: float = 0.8, progress: bool = True,
                   keep_imu: Iterable[str] = ()) -> list[Recording]:
    """Recordings of ``ms-indoor-2020.h5`` with waypoints rotated into the rotation vector's frame.

    Parameters
    ----------
    path
        The HDF5 file (layout ``/<site>/<floor>/<path_id>/{acce,gyro,rotvec,waypoints}``).
    min_heading_consistency
        Paths whose per-segment rotation estimates agree less than this use their floor's
        circular mean.
    progress
        Show a progress bar.
    keep_imu
        Splits whose recordings keep their raw ``imu`` table (e.g. ``("test",)`` for baselines).

    Returns
    -------
    list of Recording

    Raises
    ------
    CurbsideInputError
        Missing/unreadable file or no path group in the expected layout.
    """
    raw = []
    with open_h5(path) as f:
        keys = [f"{s}/{fl}/{p}" for s in f for fl in f[s] if isinstance(f[s][fl], h5py.Group)
                for p in f[s][fl]]
        needed = {"acce", "gyro", "rotvec", "waypoints"}
        keys = [k for k in keys if isinstance(f[k], h5py.Group) and needed <= set(f[k])]
        if not keys:
            raise CurbsideInputError(path, "no /<site>/<floor>/<path>/{acce,gyro,rotvec,waypoints} groups")
        for key in tqdm(keys, desc="ms-indoor", disable=None if progress else True):
            g = f[key]
            acce, gyro, rv, wp = (g[n][...] for n in ("acce", "gyro", "rotvec", "waypoints"))
            n = min(len(acce), len(gyro), len(rv))
            if n < 100 or len(wp) < 2 or not np.allclose(acce[:n, 0], gyro[:n, 0]):
                logger.info("%s::%s skipped (too short or unsynchronised)", path, key)
                continue
            imu = pd.DataFrame(np.hstack([acce[:n], gyro[:n, 1:], rv[:n, 1:5]]),
                               columns=["t", "ax", "ay", "az", "gx", "gy", "gz", "qx", "qy", "qz", "qw"])
            angle, consistency = plan_rotation(imu["t"].to_numpy(), forward_heading_vectors(imu), wp)
            raw.append((key, imu, wp, angle, consistency))
    floors: dict[str, list[float]] = {}
    for key, _, _, angle, consistency in raw:
        if consistency >= min_heading_consistency:
            floors.setdefault(key.rsplit("/", 1)[0], []).append(angle)
    floor_angle = {fl: _circular_mean(np.array(a))[0] for fl, a in floors.items()}
    recordings = []
    n_fallback = 0
    for key, imu, wp, angle, consistency in raw:
        floor = key.rsplit("/", 1)[0]
        if consistency < min_heading_consistency:
            if floor not in floor_angle:
                continue
            angle = floor_angle[floor]
            n_fallback += 1
        positions = np.column_stack([wp[:, 0], _rotate_xy(wp[:, 1:], angle)])
        recordings += _recordings_from_imu(f"ms/{key}", "ms", imu, positions, f"{Path(path).name}::{key}",
                                           keep_imu)
    logger.info("ms-indoor: %d recordings, %d with their floor's rotation", len(recordings), n_fallback)
    return recordings


def read_ipin(path: str | Path, min_heading_consistency: float = 0.8, progress: bool = True,
              keep_imu: Iterable[str] = ()) -> list[Recording]:
    """Recordings of ``ipin2023-t3.h5`` with waypoints on a local true-north plane.

    Parameters
    ----------
    path
        The IPIN 2023 Track 3 HDF5 file.
    min_heading_consistency
        Training trials whose segments disagree more than this keep true north.
    progress
        Show a progress bar.
    keep_imu
        Splits whose recordings keep their raw ``imu`` table.

    Returns
    -------
    list of Recording
    """
    import pyproj

    from curbside.localize.readers.ipin import list_trials, read_trial

    recordings = []
    for trial in tqdm(list_trials(path), desc="ipin2023", disable=None if progress else True):
        session = read_trial(path, trial)
        wp = session.waypoints
        if wp is None or len(wp) < 2:
            continue
        lat0, lon0 = float(wp["lat"].iat[0]), float(wp["lon"].iat[0])
        plane = pyproj.Proj(proj="aeqd", lat_0=lat0, lon_0=lon0, ellps="WGS84")
        x, y = plane(wp["lon"].to_numpy(), wp["lat"].to_numpy())
        positions = np.column_stack([wp["t"].to_numpy(), x, y])
        name = f"ipin/{session.name}"
        if split_of(name, "ipin") != "test":
            forward = forward_heading_vectors(session.imu)
            angle, consistency = plan_rotation(session.imu["t"].to_numpy(), forward, positions)
            if consistency >= min_heading_consistency:
                positions[:, 1:] = _rotate_xy(positions[:, 1:], angle)
        source = f"{Path(path).name}::{trial}"
        recordings += _recordings_from_imu(name, "ipin", session.imu, positions, source, keep_imu)
    return recordings


def read_ronin_sequence(folder: str | Path) -> list[Recording]:
    """One sequence of the official RoNIN dataset layout (``folder/data.hdf5``), see the module docstring:
    a recording per gap-free stretch of its IMU (the second and later named ``NAME#1``..., as for the
    MS-indoor paths).

    Raises
    ------
    CurbsideInputError
        Missing file or datasets, or mismatched lengths.
    """
    folder = Path(folder)
    path = folder / "data.hdf5" if folder.is_dir() else folder
    needed = ("synced/time", "synced/gyro", "synced/acce", "synced/game_rv", "pose/tango_pos",
              "pose/tango_ori")
    with open_h5(path) as f:
        missing = [k for k in needed if k not in f]
        if missing:
            raise CurbsideInputError(path, f"missing dataset(s) {missing} (RoNIN layout)")
        t, gyro, acce, game_wxyz, pos, tango_wxyz = (np.asarray(f[k][...], float) for k in needed)
    n = len(t)
    if not all(len(a) == n for a in (gyro, acce, game_wxyz, pos, tango_wxyz)) or n < 2:
        raise CurbsideInputError(path, "synced/* and pose/* datasets differ in length")
    game = Rotation.from_quat(game_wxyz[:, [1, 2, 3, 0]])
    tango = Rotation.from_quat(tango_wxyz[:, [1, 2, 3, 0]])
    delta = (tango * game.inv()).apply([1.0, 0.0, 0.0])
    yaw, _ = _circular_mean(np.arctan2(delta[:, 1], delta[:, 0]))
    positions = np.column_stack([t, _rotate_xy(pos[:, :2], -yaw)])
    imu = pd.DataFrame(np.column_stack([t, acce, gyro, game_wxyz[:, [1, 2, 3, 0]]]),
                       columns=["t", "ax", "ay", "az", "gx", "gy", "gz", "qx", "qy", "qz", "qw"])
    name = f"ronin/{(folder if folder.is_dir() else folder.parent).name}"
    recs = _recordings_from_imu(name, "ronin", imu, positions, str(path))
    if not recs:
        raise CurbsideInputError(path, "fewer than 2 finite pose/tango_pos rows")
    return recs


def read_ronin_dir(root: str | Path, progress: bool = True) -> list[Recording]:
    """Every RoNIN-layout sequence under ``root`` (folders holding ``data.hdf5``).

    Raises
    ------
    CurbsideInputError
        See :func:`~curbside.localize.ronin.provenance.ronin_sequence_files` and
        :func:`read_ronin_sequence`.
    """
    folders = [p.parent for p in ronin_sequence_files(root)]
    disable = None if progress else True
    return [rec for f in tqdm(folders, desc="ronin", disable=disable) for rec in read_ronin_sequence(f)]


def save_recordings(recordings: Iterable[Recording], path: str | Path,
                    sources: list[dict] | None = None) -> Path:
    """Store prepared recordings in one compressed ``.npz`` (atomically), for re-use and transport,
    with the :func:`~curbside.localize.ronin.provenance.source_records` they were read from."""
    recordings = list(recordings)
    index = [{"name": r.name, "source": r.source, "split": r.split, "n": len(r.t), "m": len(r.positions)}
             for r in recordings]
    arrays = {
        "t": np.concatenate([r.t for r in recordings]),
        "features": np.concatenate([r.features for r in recordings]).astype(np.float32),
        "positions": np.concatenate([r.positions for r in recordings]),
        "index": np.frombuffer(json.dumps(index).encode(), dtype=np.uint8),
        "sources": np.frombuffer(json.dumps(sources or []).encode(), dtype=np.uint8),
    }
    with atomic_path(path) as tmp, open(tmp, "wb") as fh:
        np.savez_compressed(fh, **arrays)
    return Path(path)


#: What np.load and the reads after it raise for a file that is not a :func:`save_recordings` archive:
#: ValueError (pickled or text data), EOFError (empty), BadZipFile or zlib.error (truncated, corrupt),
#: KeyError (another .npz),
#: TypeError or AttributeError (a single .npy array).
_NOT_NPZ = (KeyError, ValueError, TypeError, AttributeError, EOFError, zipfile.BadZipFile, zlib.error)


def _not_prepared(path: str | Path) -> CurbsideInputError:
    return CurbsideInputError(path, "not a prepared RoNIN dataset (an .npz that --prepared wrote): delete it "
                                    "or give another --prepared")


def load_recordings(path: str | Path) -> list[Recording]:
    """Inverse of :func:`save_recordings`.

    Raises
    ------
    CurbsideInputError
        ``path`` cannot be read, or is not a file :func:`save_recordings` wrote (another format, empty,
        truncated).
    """
    try:
        with np.load(path) as z:
            index = json.loads(z["index"].tobytes().decode())
            t, feats, pos = z["t"], z["features"], z["positions"]
    except OSError as exc:
        raise CurbsideInputError(path, f"cannot read the prepared RoNIN dataset ({exc})") from None
    except _NOT_NPZ:
        raise _not_prepared(path) from None
    out, i, j = [], 0, 0
    for e in index:
        out.append(Recording(e["name"], e["source"], t[i : i + e["n"]], feats[i : i + e["n"]],
                             pos[j : j + e["m"]], e["split"]))
        i += e["n"]
        j += e["m"]
    return out


def prepared_sources(path: str | Path) -> list[dict] | None:
    """The sources a :func:`save_recordings` file records (``None``: an older file without them)."""
    try:
        with np.load(path) as z:
            return json.loads(z["sources"].tobytes().decode()) if "sources" in z.files else None
    except OSError as exc:
        raise CurbsideInputError(path, f"cannot read the prepared RoNIN dataset ({exc})") from None
    except _NOT_NPZ:
        raise _not_prepared(path) from None


@dataclass
class WindowSet:
    """All recordings of a split on one uniform clock, with every labelled window's start and target.

    Attributes
    ----------
    features
        ``(N, 6)`` float32, recordings concatenated.
    starts
        ``(W,)`` first-sample index of each window (windows never straddle two recordings).
    targets
        ``(W, 2)`` float32 mean velocity over each window (m/s).
    recording
        ``(W,)`` index into ``names`` of each window's recording.
    names
        Recording names.
    window, rate_hz
        Window length (samples) and clock.
    """

    features: np.ndarray
    starts: np.ndarray
    targets: np.ndarray
    recording: np.ndarray
    names: list[str]
    window: int
    rate_hz: float

    @classmethod
    def build(cls, recordings: Iterable[Recording], window: int, stride: int, rate_hz: float) -> WindowSet:
        """Resample every recording and list its windows every ``stride`` samples."""
        feats, starts, targets, rec_ids, names = [], [], [], [], []
        offset = 0
        duration = (window - 1) / rate_hz
        for rec in recordings:
            _, f, xy = rec.on_grid(rate_hz)
            if len(f) < window:
                continue
            s = np.arange(0, len(f) - window + 1, stride)
            targets.append(((xy[s + window - 1] - xy[s]) / duration).astype(np.float32))
            starts.append(s + offset)
            rec_ids.append(np.full(len(s), len(names)))
            feats.append(f)
            names.append(rec.name)
            offset += len(f)
        if not feats:
            return cls(np.zeros((0, 6), np.float32), np.zeros(0, np.int64), np.zeros((0, 2), np.float32),
                       np.zeros(0, np.int64), [], window, rate_hz)
        return cls(np.concatenate(feats), np.concatenate(starts), np.concatenate(targets),
                   np.concatenate(rec_ids), names, window, rate_hz)

    def __len__(self) -> int:
        return len(self.starts)


def prepare_recordings(ms_indoor: str | Path | None = None, ipin: str | Path | None = None,
                       ronin_dir: str | Path | None = None, prepared: str | Path | None = None,
                       progress: bool = True, keep_imu: Iterable[str] = (),
                       sources: list[dict] | None = None) -> list[Recording]:
    """Read every given source, or a previously prepared ``.npz`` when ``prepared`` exists.

    Parameters
    ----------
    ms_indoor, ipin, ronin_dir
        Sources (see the module docstring); any may be ``None``.
    prepared
        Cache of :func:`save_recordings`: loaded when it exists (and was made from the sources
        given, if any), written after reading otherwise.
    progress
        Show progress bars.
    keep_imu
        Splits whose recordings keep their raw ``imu`` table (ignores ``prepared``, which holds none).
    sources
        :func:`~curbside.localize.ronin.provenance.source_records` of the given sources, when the
        caller has them already (computed otherwise).

    Returns
    -------
    list of Recording

    Raises
    ------
    CurbsideInputError
        No source given and no prepared file; a prepared file made from other sources; a source is
        missing or malformed.
    """
    keep_imu = tuple(keep_imu)
    if prepared is not None and Path(prepared).is_dir():
        raise CurbsideInputError(prepared, "is a folder; --prepared takes a file (.npz)")
    if sources is None:
        sources = source_records(ms_indoor, ipin, ronin_dir)
    if prepared is not None and Path(prepared).is_file() and not keep_imu:
        check_prepared_sources(prepared, prepared_sources(prepared), sources)
        logger.info("using prepared recordings %s", prepared)
        return load_recordings(prepared)
    recordings: list[Recording] = []
    if ms_indoor is not None:
        recordings += read_ms_indoor(ms_indoor, progress=progress, keep_imu=keep_imu)
    if ipin is not None:
        recordings += read_ipin(ipin, progress=progress, keep_imu=keep_imu)
    if ronin_dir is not None:
        recordings += read_ronin_dir(ronin_dir, progress=progress)
    if not recordings:
        raise CurbsideInputError(
            "--ms-indoor/--ipin/--ronin-h5", "no recordings given (nor a --prepared file)"
        )
    if prepared is not None and not Path(prepared).is_file():
        save_recordings(recordings, prepared, sources)
    return recordings
