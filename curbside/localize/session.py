"""The session folder of SPEC.md: the one model every reader converts into.

A session is a folder of CSV files (``imu.csv``, ``velocity.csv``, ``steps.csv``, ``gnss.csv``,
``waypoints.csv``) and an optional ``meta.json``. :func:`read_session` validates what it reads and
raises :class:`~curbside.errors.CurbsideInputError` (one line, naming the file) on bad input;
:func:`write_session` writes a folder atomically, under the output-folder rules of :mod:`curbside.io`.
"""

from __future__ import annotations

import json
import logging
from collections.abc import Collection, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from curbside.errors import CurbsideInputError
from curbside.io import output_folder
from curbside.localize.live_input import MAX_ABS_T_S, LiveLimits

logger = logging.getLogger(__name__)

#: Required and optional columns per file, in SPEC order.
COLUMNS: dict[str, tuple[tuple[str, ...], tuple[str, ...]]] = {
    "imu": (("t", "ax", "ay", "az", "gx", "gy", "gz"), ("qx", "qy", "qz", "qw")),
    "velocity": (("t", "ve", "vn"), ()),
    "steps": (("t",), ()),
    "gnss": (("t", "lat", "lon", "accuracy_m"), ()),
    "waypoints": (("t", "lat", "lon"), ()),
}

#: Columns that may hold NaN without the file being rejected (a missing accuracy = invalid fix).
NULLABLE: dict[str, tuple[str, ...]] = {"gnss": ("accuracy_m",)}

#: Standard gravity (m/s^2), the factor between accelerometers logging in g and in m/s^2.
STANDARD_GRAVITY = 9.80665

#: Median interval between IMU rows (s) that reads as seconds: 0.5 ms (2 kHz) to 1 s (1 Hz). Phones log
#: at 50-500 Hz; in milliseconds the interval reads 2 to 20, in nanoseconds 2e6 to 2e7.
IMU_INTERVAL_RANGE_S = (5e-4, 1.0)

#: Largest rotation-rate component (rad/s): the live service's bound, the 2000 deg/s full scale of phone
#: gyroscopes. A walk logged in deg/s exceeds it at the first turn.
MAX_GYRO_RADS = LiveLimits().max_gyro_rads


@dataclass
class Session:
    """One recording: what a walker's phone logged, plus ground truth when there is some.

    Every table has a ``t`` column in seconds on the session's single clock, strictly increasing.

    Attributes
    ----------
    name
        Folder name or an identifier.
    source
        The session as the user gave it (a folder path, ``FILE.h5::TRIAL``, an export), for messages;
        default ``name``; keyword-only. See :meth:`file_source`.
    imu
        ``t,ax,ay,az,gx,gy,gz[,qx,qy,qz,qw]``: phone frame, m/s^2 with gravity, rad/s; ``q`` the
        device-to-world (game rotation vector) quaternion.
    velocity
        ``t,ve,vn``: world-frame horizontal velocity in m/s (e.g. RoNIN output).
    steps
        ``t``: footstep times.
    gnss
        ``t,lat,lon,accuracy_m``: fixes; accuracy <= 0 or NaN means invalid.
    waypoints
        ``t,lat,lon``: ground-truth taps.
    meta
        ``meta.json`` contents, e.g. ``{"start": {"lat":.., "lon":.., "heading_deg":..}}``.
    """

    name: str = "session"
    source: str = field(default="", kw_only=True)
    imu: pd.DataFrame | None = None
    velocity: pd.DataFrame | None = None
    steps: pd.DataFrame | None = None
    gnss: pd.DataFrame | None = None
    waypoints: pd.DataFrame | None = None
    meta: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.source = self.source or self.name

    def file_source(self, file_name: str) -> str:
        """How messages name one of the session's files: ``SOURCE/FILE`` for a session folder, else the
        session as given (an HDF5 trial, a Sensor Logger export, a GPX file, a session in memory)."""
        folder = Path(self.source)
        spec_folder = folder.is_dir() and any((folder / f"{kind}.csv").is_file() for kind in COLUMNS)
        return str(folder / file_name) if spec_folder else self.source

    def tables(self) -> dict[str, pd.DataFrame]:
        """The tables that are present, by file stem."""
        out = {}
        for key in COLUMNS:
            table = getattr(self, key)
            if table is not None:
                out[key] = table
        return out

    @property
    def simulated(self) -> bool:
        """Whether ``localize simulate`` made the session (``meta.json`` holds its ``simulation`` record)."""
        return "simulation" in self.meta

    @property
    def start_pose(self) -> dict[str, float] | None:
        """The known start pose ``{"lat", "lon", "heading_deg"}`` from ``meta.json``, if any."""
        start = self.meta.get("start")
        return start if isinstance(start, dict) else None

    def time_span(self) -> tuple[float, float]:
        """Earliest and latest ``t`` over all tables."""
        ts = [tab["t"].to_numpy() for tab in self.tables().values() if len(tab)]
        if not ts:
            raise ValueError(f"session {self.name!r} holds no data")
        return float(min(t[0] for t in ts)), float(max(t[-1] for t in ts))


def warn_if_simulated_imu(session: Session, source: str, instead: str | None = None) -> bool:
    """Log a WARNING when RoNIN is to read a simulated session's ``imu.csv``, and say whether it is one.

    The simulator's phone IMU (``localize simulate --imu``) models what the footstep detector and PDR
    need (gait accelerations, the hand's orientation), not the signal a network trained on real phones
    reads: RoNIN's velocity on it is off by about 100 degrees at the median (docs/evaluate.md). The
    session's ``velocity.csv``, when the simulator wrote one, is its stand-in for RoNIN. Curbside knows
    an IMU it simulated by ``meta.json``'s ``simulation`` record, which ``localize simulate`` writes.

    Parameters
    ----------
    session
        The recording.
    source
        How the message names its ``imu.csv``.
    instead
        What the caller does instead of running RoNIN, said at the end of the warning (``None``: RoNIN
        runs, and the warning names what the session offers instead: its ``velocity.csv`` if it has one,
        and PDR).

    Returns
    -------
    bool
        Whether the session's IMU is simulated (and a warning was logged).
    """
    if not session.simulated:
        return False
    if instead is None and session.velocity is not None:
        instead = ("track with the session's velocity.csv, the simulator's stand-in for RoNIN (localize run "
                   "--velocity-source auto or file), or with PDR (--velocity-source pdr)")
    elif instead is None:
        instead = ("track with PDR (localize run --velocity-source auto or pdr), or simulate the stand-in "
                   "for RoNIN's velocity too (localize simulate without --no-velocity writes velocity.csv)")
    logger.warning("%s is simulated: its IMU is made for the footstep detector and PDR, and RoNIN's "
                   "velocity on it is far off (about 100 deg); %s", source, instead)
    return True


def acceleration_unit(xyz: np.ndarray, block: int = 25) -> tuple[str | None, float]:
    """The unit an accelerometer that includes gravity logs in, judged by its gravity level.

    Averaged over a fraction of a second, an accelerometer that includes gravity reads about 1 g
    whatever the phone does, while a gravity-free "user acceleration" stream averages to about 0
    (its instantaneous magnitude, about 1 m/s^2 when walking, would pass for 1 g). So the level is
    the median magnitude of the means of blocks of ``block`` samples (all samples when fewer).

    Parameters
    ----------
    xyz
        ``(N, 3)`` accelerations.
    block
        Samples per block mean (25 = 0.5 s at 50 Hz).

    Returns
    -------
    tuple
        ``("m/s^2" | "g" | None, level)``: ``"m/s^2"`` for a level within 20 % of 9.81, ``"g"`` within
        20 % of 1, else ``None`` (gravity removed, or another unit).
    """
    n_blocks = len(xyz) // block
    if n_blocks:
        means = xyz[: n_blocks * block].reshape(n_blocks, block, 3).mean(axis=1)
    else:
        means = xyz.mean(axis=0, keepdims=True)
    level = float(np.median(np.linalg.norm(means, axis=1)))
    if 0.8 * STANDARD_GRAVITY <= level <= 1.2 * STANDARD_GRAVITY:
        return "m/s^2", level
    return ("g" if 0.8 <= level <= 1.2 else None), level


def _unit_hint(interval_s: float) -> str:
    """What a median row interval outside :data:`IMU_INTERVAL_RANGE_S` suggests ``t`` is in."""
    low, high = IMU_INTERVAL_RANGE_S
    for factor, unit in ((1e-3, "milliseconds"), (1e-6, "microseconds"), (1e-9, "nanoseconds")):
        if low <= interval_s * factor <= high:
            return f"{unit}?"
    return "another unit?"


def _check_imu_interval(t: np.ndarray, source: str | Path) -> None:
    """Raise unless the median interval between IMU rows reads as seconds (:data:`IMU_INTERVAL_RANGE_S`)."""
    steps = np.diff(t)
    if not len(steps):
        return
    interval_s = float(np.median(steps))
    low, high = IMU_INTERVAL_RANGE_S
    if not low <= interval_s <= high:
        # 1-10 s between rows could be a 100-1000 Hz IMU in ms, or a genuinely slow log in seconds
        slow = ", or the IMU was logged too slowly to track (20 Hz or more)" if interval_s < 10 * high else ""
        raise CurbsideInputError(
            source, f"t is not in seconds: its rows come every {interval_s:.3g} s (median), an IMU logs "
            f"every {low * 1e3:g} ms to {high:g} s ({_unit_hint(interval_s)}){slow}"
        )


def _check_time_unit(kind: str, t: np.ndarray, source: str | Path) -> None:
    huge = np.abs(t) >= MAX_ABS_T_S
    if huge.any():
        i = int(np.argmax(huge))
        bound = f"{MAX_ABS_T_S:.0e}".replace("e+", "e")
        raise CurbsideInputError(
            source, f"t is not in seconds (nanoseconds or milliseconds since an epoch?): "
            f"t={float(t[i])!r} at data row {i + 1}, and |t| must be under {bound} s"
        )
    if kind == "imu":
        _check_imu_interval(t, source)


def _check_imu_units(imu: pd.DataFrame, source: str | Path) -> None:
    """SPEC units: m/s^2 with gravity (:func:`acceleration_unit`), rad/s (:data:`MAX_GYRO_RADS`)."""
    unit, level = acceleration_unit(imu[["ax", "ay", "az"]].to_numpy())
    if unit == "g":
        raise CurbsideInputError(source, f"ax,ay,az are in g (gravity level {level:.2f}), not m/s^2; "
                                 f"multiply them by {STANDARD_GRAVITY}")
    if unit is None:
        raise CurbsideInputError(source, f"ax,ay,az gravity level {level:.2f} is neither ~9.8 m/s^2 nor ~1 g "
                                 "(m/s^2 with gravity included, as SPEC imu.csv says)")
    gyro = imu[["gx", "gy", "gz"]].abs().to_numpy()
    if (gyro > MAX_GYRO_RADS).any():
        row, col = np.argwhere(gyro > MAX_GYRO_RADS)[0]
        name = ("gx", "gy", "gz")[col]
        raise CurbsideInputError(source, f"|{name}| = {gyro[row, col]:.3g} at data row {row + 1} exceeds "
                                 f"{MAX_GYRO_RADS:g} rad/s: rotation rates must be in rad/s (deg/s?)")


def _is_number(value: Any) -> bool:
    try:
        pd.to_numeric([value])
    except (ValueError, TypeError):
        return False
    return True


def non_numeric_value(table: pd.DataFrame, columns: Sequence[str]) -> str:
    """Say which value made :func:`pandas.to_numeric` refuse ``columns`` of ``table``, for an error.

    Parameters
    ----------
    table
        The table; an integer index numbers its rows from 0 (a CSV file's rows, less any dropped), any
        other index is replaced by the row positions.
    columns
        The columns that were converted.

    Returns
    -------
    str
        ``non-numeric value 'abc' in column 'lon' at data row 2`` for the first such value, row by row
        and column by column, rows counted from 1 after the header, as :func:`validate_table` counts
        those holding NaN.
    """
    rows = table.index.to_numpy() if pd.api.types.is_integer_dtype(table.index) else np.arange(len(table))
    found = []
    for column in columns:
        values = table[column]
        suspects = pd.to_numeric(values, errors="coerce").isna().to_numpy() & values.notna().to_numpy()
        position = next((i for i in np.flatnonzero(suspects) if not _is_number(values.iat[i])), None)
        if position is not None:
            found.append((position, column, str(values.iat[position])))
    if not found:  # what failed was the conversion to float, not one value
        return "non-numeric value"
    position, column, text = min(found, key=lambda f: f[0])  # min keeps the first column of a row
    text = text if len(text) <= 40 else f"{text[:37]}..."
    return f"non-numeric value {text!r} in column {column!r} at data row {rows[position] + 1}"


def validate_table(kind: str, table: pd.DataFrame, source: str | Path) -> pd.DataFrame:
    """Check one table against the schema and return it with float columns in SPEC order.

    Parameters
    ----------
    kind
        File stem: ``imu``, ``velocity``, ``steps``, ``gnss`` or ``waypoints``.
    table
        The table read from ``source``.
    source
        File name used in error messages.

    Raises
    ------
    CurbsideInputError
        Missing columns, non-numeric values, NaN/inf where not allowed, empty table, ``t`` not
        strictly increasing (duplicated or out-of-order timestamps) or not in seconds (``|t|`` from
        1e10, or IMU rows closer than 0.5 ms or further apart than 1 s at the median), lat/lon out of
        range; for ``imu``, accelerations not in m/s^2 with gravity (in g, say) or rotation rates
        above 35 rad/s (in deg/s).
    """
    required, optional = COLUMNS[kind]
    table = table.rename(columns=lambda c: str(c).strip())
    missing = [c for c in required if c not in table.columns]
    if missing:
        raise CurbsideInputError(source, f"missing column(s) {missing}; expected {list(required)}")
    present_optional = [c for c in optional if c in table.columns]
    if present_optional and len(present_optional) != len(optional):
        raise CurbsideInputError(source, f"partial quaternion columns {present_optional}")
    cols = list(required) + present_optional
    if len(table) == 0:
        raise CurbsideInputError(source, "no rows")
    try:
        out = table[cols].apply(pd.to_numeric, errors="raise").astype(float)
    except (ValueError, TypeError):
        raise CurbsideInputError(source, non_numeric_value(table, cols)) from None
    strict = [c for c in cols if c not in NULLABLE.get(kind, ())]
    values = out[strict].to_numpy()
    if not np.isfinite(values).all():
        row, col = np.argwhere(~np.isfinite(values))[0]
        raise CurbsideInputError(
            source, f"NaN or infinite {strict[col]!r} at data row {row + 1}"
        )
    dt = np.diff(out["t"].to_numpy())
    if (dt <= 0).any():
        i = int(np.argmax(dt <= 0))
        what = "duplicated" if dt[i] == 0 else "out-of-order"
        raise CurbsideInputError(
            source, f"{what} timestamp t={float(out['t'].iat[i + 1])!r} at data row {i + 2}"
        )
    _check_time_unit(kind, out["t"].to_numpy(), source)
    if kind == "imu":
        _check_imu_units(out, source)
    if "lat" in out and not ((out["lat"].abs() <= 90).all() and (out["lon"].abs() <= 180).all()):
        raise CurbsideInputError(source, "lat/lon outside WGS84 degree ranges")
    return out.reset_index(drop=True)


def _read_csv(path: Path) -> pd.DataFrame:
    try:
        return pd.read_csv(path, skipinitialspace=True)
    except (pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError) as exc:
        raise CurbsideInputError(path, f"malformed CSV ({str(exc).splitlines()[0]})") from None


def read_session(folder: str | Path, kinds: Collection[str] | None = None) -> Session:
    """Read and validate a SPEC session folder.

    Parameters
    ----------
    folder
        Directory holding any of ``imu.csv``, ``velocity.csv``, ``steps.csv``, ``gnss.csv``,
        ``waypoints.csv``, ``meta.json``.
    kinds
        Read only these tables (file stems, e.g. ``("gnss", "waypoints")``; ``meta.json`` is always
        read); default all of them.

    Returns
    -------
    Session
        Named by the folder's name; its ``source`` is the folder's path, for messages.

    Raises
    ------
    CurbsideInputError
        The folder is missing or holds none of the files; any file is malformed.
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise CurbsideInputError(folder, "no such session folder")
    session = Session(name=folder.name, source=str(folder))
    for kind in COLUMNS:
        path = folder / f"{kind}.csv"
        if path.is_file() and (kinds is None or kind in kinds):
            setattr(session, kind, validate_table(kind, _read_csv(path), path))
    meta_path = folder / "meta.json"
    if meta_path.is_file():
        try:
            meta = json.loads(meta_path.read_text(encoding="utf-8-sig"))  # a BOM, as in the CSVs, is fine
        except (json.JSONDecodeError, UnicodeDecodeError) as exc:
            raise CurbsideInputError(meta_path, f"malformed JSON ({exc})") from None
        if not isinstance(meta, dict):
            raise CurbsideInputError(meta_path, "expected a JSON object")
        session.meta = meta
        start = meta.get("start")
        if start is not None:
            keys = ("lat", "lon", "heading_deg")
            if not isinstance(start, dict) or not all(
                isinstance(start.get(k), int | float) and np.isfinite(start.get(k)) for k in keys
            ):
                raise CurbsideInputError(
                    meta_path, "'start' must be {\"lat\": .., \"lon\": .., \"heading_deg\": ..}"
                )
    if not any((folder / f"{kind}.csv").is_file() for kind in COLUMNS):
        raise CurbsideInputError(
            folder, "not a session folder: none of imu.csv, velocity.csv, gnss.csv, steps.csv"
        )
    return session


def write_session(
    session: Session, folder: str | Path, *, overwrite: bool = False, command: str = "curbside"
) -> Path:
    """Write ``session`` as a SPEC folder, atomically (nothing is left behind on failure).

    Parameters
    ----------
    session
        The session; each present table is validated before anything is written.
    folder
        Destination directory: absent, empty, a previous curbside output, or (with ``overwrite``)
        any folder; see :func:`curbside.io.output_folder`. Files curbside did not write are kept.
    overwrite
        Allow a non-empty folder that curbside did not write.
    command
        Recorded in the folder's ``.curbside-output`` marker.

    Returns
    -------
    pathlib.Path
        ``folder``.

    Raises
    ------
    CurbsideInputError
        A table fails validation, or the folder may not or cannot be written.
    """
    folder = Path(folder)
    tables = {k: validate_table(k, t, f"{session.name}/{k}.csv") for k, t in session.tables().items()}
    with output_folder(folder, command, overwrite=overwrite) as tmp:
        for kind, table in tables.items():
            # No float_format: pandas writes each float's shortest repr, which reads back bit for bit,
            # so a written session tracks exactly as its source does.
            table.to_csv(tmp / f"{kind}.csv", index=False)
        if session.meta:
            (tmp / "meta.json").write_text(json.dumps(session.meta, indent=2), encoding="utf-8")
    return folder
