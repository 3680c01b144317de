"""GetSensorData logs of the IPIN 2023 competition (Track 3), as packed in one HDF5 file.

The file (``../shared/data/ipin2023/ipin2023-t3.h5``, see its README) holds one group per trial with
``acce``, ``gyro``, ``rotvec`` (Android rotation vector, device-to-ENU quaternion ``qx,qy,qz,qw``),
``gnss`` and ``posi`` (surveyed waypoints) on one clock ``t_s``. A trial becomes a
:class:`~curbside.localize.session.Session`:

- ``imu``: accelerometer samples, with the gyroscope (100 Hz on the Galaxy A5) and the quaternion
  interpolated onto them (:func:`~curbside.localize.readers._resample.merge_imu`);
- ``gnss``: fixes without the network (cell) locations, which the logger marks with ``alt == 0``;
  ``accuracy_m`` is Android's ``getAccuracy()``;
- ``waypoints``: the POSI lines (``t,lat,lon``); their floors go to ``meta["waypoint_floors"]``;
- ``meta``: ``start`` = the first POSI, heading towards the second, and its time ``t``; the device,
  the floors visited and the source.

``gnss`` and ``posi`` may be missing or empty (a trial logged without surveyed points): the session
then has no ``gnss.csv`` or no ``waypoints.csv`` and start pose, with a warning. The IMU datasets
are required.

A trial is addressed as ``FILE.h5::TRIAL`` (see :func:`curbside.localize.readers.read_any`);
``TRIAL`` is the group name or the part after ``IPIN2023_T3_``, e.g. ``TrainingTrial01_repetition01``.

The other HDF5 file of the shared data, ``ms-indoor-2020.h5`` (``/<site>/<floor>/<path>/``, no GNSS,
waypoints in metres on a floor plan), makes no session: listing and reading it both refuse it with a
message that says what it is for (RoNIN training and evaluation).
"""

from __future__ import annotations

import logging
import shlex
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import h5py
import numpy as np
import pandas as pd
import pyproj

from curbside.errors import CurbsideInputError
from curbside.io import open_h5
from curbside.localize.readers._resample import merge_imu
from curbside.localize.readers._tidy import accelerometer_ms2, tidy_table
from curbside.localize.session import Session

logger = logging.getLogger(__name__)

_GEOD = pyproj.Geod(ellps="WGS84")
_REQUIRED = ("acce", "gyro", "rotvec")
_OPTIONAL = ("gnss", "posi")
#: How each dataset's ``columns`` attribute names the session columns (the others it names alike), for errors.
_OWN_NAMES = {
    "acce": {"t": "t_s", "ax": "x", "ay": "y", "az": "z"},
    "gyro": {"t": "t_s", "gx": "x", "gy": "y", "gz": "z"},
    **{dataset: {"t": "t_s"} for dataset in ("rotvec", "gnss", "posi")},
}
#: The datasets of a path of the MS-indoor file (``/<site>/<floor>/<path>/``).
_MS_INDOOR = frozenset({"acce", "gyro", "rotvec", "waypoints"})


def _refuse_ms_indoor(f: h5py.File, path: str | Path) -> None:
    """Raise when ``f`` is the MS-indoor file: its first ``/<site>/<floor>/<path>`` holds its datasets."""
    levels: h5py.Group = f
    for _ in range(3):
        groups = [g for g in levels.values() if isinstance(g, h5py.Group)]
        if not groups:
            return
        levels = groups[0]
    if set(levels) >= _MS_INDOOR:
        file = shlex.quote(str(path))
        raise CurbsideInputError(
            path, "is an MS-indoor file (Indoor Location Competition 2.0), not IPIN 2023 trials: its "
            "paths have no GNSS and their waypoints are metres on a floor plan, not latitude and longitude, "
            "so they make no session; it is RoNIN data: give it to localize train-ronin or ronin-eval as "
            f"--ms-indoor {file}",
        )  # fmt: skip


def list_trials(path: str | Path) -> list[str]:
    """Names of the trial groups in an IPIN HDF5 file, in file order.

    Parameters
    ----------
    path
        The ``.h5`` file.

    Returns
    -------
    list of str
        Group names, e.g. ``IPIN2023_T3_TrainingTrial01_repetition01``.

    Raises
    ------
    CurbsideInputError
        Missing or unreadable file, or no group holding the IPIN datasets (the MS-indoor file says so).
    """
    with open_h5(path) as f:
        names = [n for n, g in f.items() if isinstance(g, h5py.Group) and all(k in g for k in _REQUIRED)]
        if not names:
            _refuse_ms_indoor(f, path)
    if not names:
        raise CurbsideInputError(path, f"no trial groups with datasets {list(_REQUIRED)} (and optionally "
                                 f"{list(_OPTIONAL)})")
    return names


def _resolve(f: h5py.File, path: str | Path, trial: str) -> str:
    if trial in f:
        return trial
    matches = [n for n in f if n.endswith("_" + trial)]
    if len(matches) == 1:
        return matches[0]
    raise CurbsideInputError(f"{path}::{trial}", "no such trial (see `localize convert FILE.h5 --list`)")


def _table(g: h5py.Group, name: str, columns: list[str], source: str) -> pd.DataFrame | None:
    if name not in g:
        return None
    data = g[name][:]
    # float32 -> float64 through the shortest decimal repr, so 0.0679 stays 0.0679 in the CSV.
    data = data.astype(str).astype(float) if data.dtype == np.float32 else np.asarray(data, dtype=float)
    if data.size == 0:
        return pd.DataFrame(columns=columns, dtype=float)
    if data.ndim != 2 or data.shape[1] < len(columns):
        raise CurbsideInputError(
            source, f"dataset {name!r} has shape {data.shape}, expected (N, >={len(columns)})"
        )
    return pd.DataFrame(data[:, : len(columns)], columns=columns)


def read_trial(path: str | Path, trial: str) -> Session:
    """Read one IPIN trial as a session.

    Parameters
    ----------
    path
        The ``.h5`` file.
    trial
        Group name, or its suffix after ``IPIN2023_T3_``.

    Returns
    -------
    Session
        ``imu``, ``gnss``, ``waypoints`` and ``meta`` (start pose, device, floors, source).

    Raises
    ------
    CurbsideInputError
        Missing/unreadable file, the MS-indoor file, unknown trial, missing or malformed datasets, no
        usable rows.
    """
    with open_h5(path) as f:
        _refuse_ms_indoor(f, path)
        name = _resolve(f, path, trial)
        source = f"{Path(path).name}::{name}"
        g = f[name]
        missing = [k for k in _REQUIRED if k not in g]
        if missing:
            raise CurbsideInputError(source, f"missing dataset(s) {missing}")
        acce = _table(g, "acce", ["t", "ax", "ay", "az"], source)
        gyro = _table(g, "gyro", ["t", "gx", "gy", "gz"], source)
        quat = _table(g, "rotvec", ["t", "qx", "qy", "qz", "qw"], source)
        gnss = _table(g, "gnss", ["t", "lat", "lon", "alt", "bearing", "accuracy_m"], source)
        posi = _table(g, "posi", ["t", "lat", "lon", "floor"], source)
        attrs = dict(g.attrs)

    floors = attrs.get("floors")
    meta: dict = {
        "source": {"format": "ipin2023-h5", "file": Path(path).name, "trial": name},
        "device": f"{attrs.get('device_manufacturer', '')} {attrs.get('device_model', '')}".strip(),
    }
    tables = {"acce": acce, "gyro": gyro, "rotvec": quat, "gnss": gnss, "posi": posi}
    return build_session(name.removeprefix("IPIN2023_T3_"), tables, meta, Layout(source), floors)


@dataclass(frozen=True)
class Layout:
    """How messages name a source of IPIN/GetSensorData streams (an HDF5 trial or a text logfile).

    Attributes
    ----------
    source
        The source as messages name it (``FILE.h5::TRIAL``, ``LOG.txt``).
    streams
        What each stream (``acce``, ``gyro``, ``rotvec``, ``gnss``, ``posi``) is called in errors;
        ``SOURCE/acce`` (the dataset) by default.
    kinds
        What warnings call a stream when it is missing or empty (``'gnss' dataset`` by default).
    names
        The source's own name of each session column, per stream.
    rows
        What the source's rows are called (``row`` of a dataset, ``line`` of a text file).
    """

    source: str
    streams: Mapping[str, str] | None = None
    kinds: Mapping[str, str] | None = None
    names: Mapping[str, Mapping[str, str]] = field(default_factory=lambda: _OWN_NAMES)
    rows: str = "row"

    def stream(self, dataset: str) -> str:
        """What errors call ``dataset``."""
        return (self.streams or {}).get(dataset, f"{self.source}/{dataset}")

    def kind(self, dataset: str) -> str:
        """What warnings call ``dataset``."""
        return (self.kinds or {}).get(dataset, f"{dataset!r} dataset")

    def tidy(self, table: pd.DataFrame, dataset: str, columns: list[str] | None = None,
             nullable: tuple[str, ...] = ()) -> pd.DataFrame:
        """:func:`~._tidy.tidy_table` of one stream (all its columns by default); errors name its rows and
        columns as the source does (``gyro``'s ``y`` at row 5)."""
        return tidy_table(table, self.stream(dataset), list(table.columns) if columns is None else columns,
                          nullable, names=self.names[dataset], rows=self.rows)


def build_session(name: str, tables: Mapping[str, pd.DataFrame | None], meta: dict, layout: Layout,
                  floors: Sequence[int] | np.ndarray | None = None) -> Session:
    """Make a session of IPIN/GetSensorData streams, as read from an HDF5 trial or a text logfile.

    Parameters
    ----------
    name
        The session's name.
    tables
        ``acce`` (``t,ax,ay,az``), ``gyro`` (``t,gx,gy,gz``), ``rotvec`` (``t,qx,qy,qz,qw``), ``gnss``
        (``t,lat,lon,alt,bearing,accuracy_m``, duplicates already merged) and ``posi`` (``t,lat,lon,floor``)
        as numbers, their index numbering the source's rows from 0; any may be ``None`` (missing). Without
        ``acce`` and ``gyro`` the session has no ``imu``; without ``rotvec`` its ``imu`` has no quaternion.
    meta
        ``source`` and ``device``; ``floors``, ``waypoint_floors`` and ``start`` are added.
    layout
        How messages name the source, its streams, columns and rows.
    floors
        The floors visited; the POSI floors when ``None``.

    Returns
    -------
    Session
        ``imu``, ``gnss`` (satellite fixes: the network ones, ``alt == 0``, dropped), ``waypoints`` and
        ``meta`` (start pose = the first POSI, heading towards the second).

    Raises
    ------
    CurbsideInputError
        A stream with no usable rows, text or conflicting rows (see :func:`~._tidy.tidy_table`).
    """
    imu = None
    if tables.get("acce") is not None and tables.get("gyro") is not None:
        acce = accelerometer_ms2(layout.tidy(tables["acce"], "acce"), layout.stream("acce"))
        gyro = layout.tidy(tables["gyro"], "gyro")
        quat = None if tables.get("rotvec") is None else layout.tidy(tables["rotvec"], "rotvec")
        imu = merge_imu(acce, gyro, quat, layout.source, tuple(layout.stream(k) for k in _REQUIRED))
    gnss = _fixes(tables.get("gnss"), layout)
    posi = _surveyed(tables.get("posi"), layout)

    if floors is None:
        floors = [] if posi is None else posi["floor"].unique()
    meta["floors"] = [int(x) for x in np.atleast_1d(floors)]
    if posi is None:
        return Session(name=name, imu=imu, gnss=gnss, meta=meta)
    meta["waypoint_floors"] = [int(x) for x in posi["floor"]]
    if len(posi) >= 2:
        lon, lat = posi["lon"].to_numpy(), posi["lat"].to_numpy()
        heading, _, _ = _GEOD.inv(lon[0], lat[0], lon[1], lat[1])
        meta["start"] = {
            "lat": float(posi["lat"].iat[0]),
            "lon": float(posi["lon"].iat[0]),
            "heading_deg": float(heading % 360.0),
            "t": float(posi["t"].iat[0]),
        }
    return Session(name=name, imu=imu, gnss=gnss, waypoints=posi[["t", "lat", "lon"]], meta=meta)


def _fixes(gnss: pd.DataFrame | None, layout: Layout) -> pd.DataFrame | None:
    """The satellite fixes of the ``gnss`` stream, or ``None`` (with a warning) when there are none."""
    source = layout.source
    if gnss is None or gnss.empty:
        logger.warning("%s: no GNSS fixes (%s %s); the session has no gnss.csv", source, layout.kind("gnss"),
                       "missing" if gnss is None else "empty")
        return None
    network = gnss["alt"] == 0
    if network.all():
        logger.warning("%s: all %d GNSS fixes are network (alt == 0) locations; the session has no gnss.csv",
                       source, len(gnss))
        return None
    if network.any():
        logger.info("%s: dropped %d network (alt == 0) fix(es)", source, int(network.sum()))
    columns = ["t", "lat", "lon", "accuracy_m"]
    return layout.tidy(gnss[~network], "gnss", columns, nullable=("accuracy_m",))


def _surveyed(posi: pd.DataFrame | None, layout: Layout) -> pd.DataFrame | None:
    """The surveyed points (``posi``), or ``None`` (with a warning) when the source has none."""
    if posi is None or posi.empty:
        logger.warning("%s: no surveyed waypoints (%s %s); the session has no waypoints.csv and no start "
                       "pose", layout.source, layout.kind("posi"), "missing" if posi is None else "empty")
        return None
    return layout.tidy(posi, "posi", ["t", "lat", "lon", "floor"])
