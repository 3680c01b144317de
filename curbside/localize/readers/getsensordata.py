"""GetSensorData text logfiles (LOPSI, CAR-CSIC): the smartphone format of the IPIN competitions (Track 3).

A logfile (``docs/sessions.md`` lists the real ones this reader was run on) holds:

- ``%`` comment lines: ``% LogFile created by the 'GetSensorData' App for Android.``, the app version
  (``% Version 2.21 July 2021``), the phone (``% Manufacturer:``, ``% Model:``, ``% API Android version:``)
  and one format line per row type, e.g. ``% Accelerometer data: 'ACCE;AppTimestamp(s);SensorTimestamp(s);
  Acc_X(m/s^2);...'``. Fields are read by the names these lines give (app 2.0 calls the rotation vector
  ``RotVecX()``, 2.21 ``Quat(2)``); a logfile without them is read in the 2.21 layout;
- ``;``-separated rows by type. Read: ``ACCE`` (m/s^2, gravity included), ``GYRO`` (rad/s), ``AHRS``
  (the Android rotation vector's x, y, z: a device-to-East-North-Up quaternion whose ``w`` is not logged
  and is taken as ``sqrt(1 - x^2 - y^2 - z^2)``), ``GNSS`` (Android ``Location``: every fix is written
  twice; lines whose fix time, position, altitude, bearing, accuracy and speed read alike are one fix,
  the first kept) and ``POSI`` (surveyed ground truth: ``t,lat,lon,floor``). ``MAGN``, ``PRES``, ``WIFI``,
  ``BLE4``, ``SOUN`` and every other type are skipped unread.

One clock, ``AppTimestamp`` (seconds since logging started; ``Timestamp`` in POSI rows), serves every row
type. The streams then become a session exactly as an HDF5 trial of the same logfile does
(:func:`~curbside.localize.readers.ipin.build_session`): network fixes (``alt == 0``) dropped, the start
pose from the first POSI, floors in ``meta``.
"""

from __future__ import annotations

import logging
import re
from pathlib import Path

import numpy as np
import pandas as pd

from curbside.errors import CurbsideInputError
from curbside.localize.readers.ipin import Layout, build_session
from curbside.localize.session import Session

logger = logging.getLogger(__name__)

#: Each read row type's fields in the 2.21 layout, for a logfile without format lines.
_DEFAULT_FIELDS = {
    "ACCE": ["AppTimestamp(s)", "SensorTimestamp(s)", "Acc_X(m/s^2)", "Acc_Y(m/s^2)", "Acc_Z(m/s^2)",
             "Accuracy(integer)"],
    "GYRO": ["AppTimestamp(s)", "SensorTimestamp(s)", "Gyr_X(rad/s)", "Gyr_Y(rad/s)", "Gyr_Z(rad/s)",
             "Accuracy(integer)"],
    "AHRS": ["AppTimestamp(s)", "SensorTimestamp(s)", "PitchX(deg)", "RollY(deg)", "YawZ(deg)", "Quat(2)",
             "Quat(3)", "Quat(4)", "Accuracy(int)"],
    "GNSS": ["AppTimestamp(s)", "SensorTimeStamp(s)", "Latit(deg)", "Long(deg)", "Altitude(m)",
             "Bearing(deg)", "Accuracy(m)", "Speed(m/s)", "SatInView", "SatInUse"],
    "POSI": ["Timestamp(s)", "Counter", "Latitude(degrees)", "Longitude(degrees)", "floor ID(0,1,2..4)",
             "Building ID(0,1,2..3)"],
}
#: The fields read, by session column: the keys (:func:`_key`) their names may have.
_WANTED = {
    "ACCE": {"t": ("apptimestamp",), "ax": ("acc_x",), "ay": ("acc_y",), "az": ("acc_z",)},
    "GYRO": {"t": ("apptimestamp",), "gx": ("gyr_x",), "gy": ("gyr_y",), "gz": ("gyr_z",)},
    "AHRS": {"t": ("apptimestamp",), "qx": ("quat(2)", "rotvecx"), "qy": ("quat(3)", "rotvecy"),
             "qz": ("quat(4)", "rotvecz")},
    "GNSS": {"t": ("apptimestamp",), "fix_time": ("sensortimestamp",), "lat": ("latit", "latitude"),
             "lon": ("long", "longitude"), "alt": ("altitude",), "bearing": ("bearing",),
             "accuracy_m": ("accuracy",), "speed": ("speed",)},
    "POSI": {"t": ("timestamp", "apptimestamp"), "lat": ("latitude",), "lon": ("longitude",),
             "floor": ("floorid",)},
}
#: The IPIN stream each row type becomes (:func:`~curbside.localize.readers.ipin.build_session`).
_STREAMS = {"ACCE": "acce", "GYRO": "gyro", "AHRS": "rotvec", "GNSS": "gnss", "POSI": "posi"}
_IMU = ("ACCE", "GYRO", "AHRS")
#: GNSS fields whose text, alike on two lines, makes them one fix written twice.
_FIX_FIELDS = ("fix_time", "lat", "lon", "alt", "bearing", "accuracy_m", "speed")
_FORMAT_LINE = re.compile(r"'(?P<kind>[A-Z][A-Z0-9]{3});(?P<fields>[^']*)")
_PHONE = {"manufacturer": "Manufacturer", "model": "Model", "android_api": "API Android version",
          "android_version": "Android version Release"}


def _key(field: str) -> str:
    """A field name as :data:`_WANTED` knows it: lower case, no spaces, no unit (``Latit(deg)`` -> ``latit``);
    a number in parentheses is kept (``Quat(2)``)."""
    return re.sub(r"\((?!\d+\))[^)]*\)", "", field.lower().replace(" ", ""))


def _default_names(kind: str) -> dict[str, str]:
    """The 2.21 layout's name of each field read from ``kind`` rows: ``{column: field name}``."""
    return {column: next(f for f in _DEFAULT_FIELDS[kind] if _key(f) in aliases)
            for column, aliases in _WANTED[kind].items()}


def _header(line: str, number: int, formats: dict[str, tuple[list[str], int]], facts: dict) -> None:
    """Record a ``%`` line: a row type's format line, the phone or the app version."""
    match = _FORMAT_LINE.search(line)
    if match:
        fields = [f.strip() for f in match["fields"].split(";") if f.strip()]
        formats.setdefault(match["kind"], (fields, number))
        return
    body = line.lstrip("%").strip()
    for key, label in _PHONE.items():
        if body.startswith(label + ":"):
            facts.setdefault(key, body.split(":", 1)[1].strip())
    if body.startswith("Version "):
        facts.setdefault("app_version", body.removeprefix("Version ").strip())
    elif body.startswith("Date of creation:"):
        facts.setdefault("created", body.split(":", 1)[1].strip())


def _read_lines(path: Path) -> tuple[dict[str, tuple[list[str], list[int]]], dict, dict]:
    """The rows of each read type (text and line numbers), the format lines and the header facts."""
    try:
        text = path.read_bytes().decode("utf-8", errors="replace")
    except OSError as exc:
        raise CurbsideInputError(path, f"cannot read ({exc.strerror})") from None
    rows: dict[str, tuple[list[str], list[int]]] = {kind: ([], []) for kind in _STREAMS}
    formats: dict[str, tuple[list[str], int]] = {}
    facts: dict = {}
    for number, line in enumerate(text.splitlines(), 1):
        line = line.strip()
        if line.startswith("%"):
            _header(line, number, formats, facts)
        elif line[:4] in rows and line[4:5] == ";":
            rows[line[:4]][0].append(line)
            rows[line[:4]][1].append(number)
    return rows, formats, facts


def _cells(path: Path, kind: str, lines: list[str], numbers: list[int],
           formats: dict[str, tuple[list[str], int]]) -> pd.DataFrame:
    """The cells of one row type as text, named by its format line and checked against its field count."""
    names, at = formats.get(kind, (_DEFAULT_FIELDS[kind], None))
    cells = [line.rstrip(";").split(";")[1:] for line in lines]
    counts = np.fromiter((len(c) for c in cells), int, len(cells))
    wrong = np.flatnonzero(counts != len(names))
    if len(wrong):
        i = wrong[0]
        layout = f"its format line (line {at})" if at else "the GetSensorData 2.21 layout"
        raise CurbsideInputError(path, f"line {numbers[i]}: {kind} row with {counts[i]} fields where "
                                 f"{layout} names {len(names)}")
    table = pd.DataFrame(cells, columns=names, index=np.asarray(numbers) - 1)
    return table.where(table != "")


def _columns(path: Path, kind: str, table: pd.DataFrame) -> dict[str, str]:
    """The field read for each session column of ``kind``: ``{column: field name}``."""
    keys = {_key(name): name for name in reversed(table.columns)}  # the first of two alike
    found, missing = {}, []
    for column, aliases in _WANTED[kind].items():
        field = next((keys[a] for a in aliases if a in keys), None)
        if field is None:
            missing.append(_default_names(kind)[column])
        found[column] = field
    if missing:
        raise CurbsideInputError(path, f"the format line of the {kind} rows names no "
                                 f"{', '.join(missing)} field")
    return found


def _numbers(path: Path, kind: str, table: pd.DataFrame, fields: dict[str, str]) -> pd.DataFrame:
    """``fields`` as numbers, named by session column; text in any is refused with its line."""
    own = table[list(fields.values())]
    numbers = own.apply(pd.to_numeric, errors="coerce")
    text = (numbers.isna() & own.notna()).to_numpy()
    if text.any():
        row, col = np.argwhere(text)[0]
        field = own.columns[col]
        raise CurbsideInputError(path, f"line {table.index[row] + 1}: non-numeric value "
                                 f"{own.iat[row, col]!r} in field {field!r} of a {kind} row")
    numbers.columns = list(fields)
    return numbers.astype(float)


def _stream(path: Path, kind: str, table: pd.DataFrame, fields: dict[str, str]) -> pd.DataFrame:
    """One row type as the IPIN stream it becomes (``t,qx,qy,qz,qw`` of AHRS, merged GNSS fixes)."""
    if kind == "GNSS":
        twice = table[[fields[f] for f in _FIX_FIELDS]].duplicated(keep="first")
        logger.info("%s: %d GNSS line(s) make %d fix(es)", path, len(table), int((~twice).sum()))
        table = table[~twice]
        fields = {k: v for k, v in fields.items() if k not in ("fix_time", "speed")}
    out = _numbers(path, kind, table, fields)
    if kind == "AHRS":
        out["qw"] = np.sqrt(np.clip(1.0 - (out[["qx", "qy", "qz"]] ** 2).sum(axis=1), 0.0, None))
    return out


def _tables(path: Path) -> tuple[dict[str, pd.DataFrame | None], dict[str, dict[str, str]], dict]:
    """The IPIN streams of a logfile (``None`` where it has no rows of the type), their field names and
    the header facts."""
    rows, formats, facts = _read_lines(path)
    tables: dict[str, pd.DataFrame | None] = {}
    names: dict[str, dict[str, str]] = {}
    for kind, (lines, numbers) in rows.items():
        stream = _STREAMS[kind]
        tables[stream] = None
        names[stream] = _default_names(kind)
        if lines:
            cells = _cells(path, kind, lines, numbers, formats)
            fields = _columns(path, kind, cells)
            names[stream] = fields
            tables[stream] = _stream(path, kind, cells, fields)
    if not formats:
        logger.info("%s: no format lines in the header; read in the GetSensorData 2.21 layout", path)
    return tables, names, facts


def read_getsensordata(path: str | Path) -> Session:
    """Read a GetSensorData text logfile (IPIN competitions, Track 3) as a session.

    Parameters
    ----------
    path
        The ``.txt`` logfile.

    Returns
    -------
    Session
        ``imu`` (accelerometer clock, gyroscope and rotation vector interpolated onto it), ``gnss``
        (satellite fixes), ``waypoints`` (POSI), and ``meta``: ``start`` (the first POSI, heading towards
        the second), ``floors``, ``waypoint_floors``, ``device`` and ``source`` (app version, creation
        date). The name is the file's, less an ``IPINyyyy_Tn_`` prefix.

    Raises
    ------
    CurbsideInputError
        Unreadable file, a row with the wrong field count or text in a number field (the message gives
        its line), a format line without a field the reader needs, a stream with no usable rows, or
        neither IMU rows (ACCE and GYRO) nor GNSS fixes.
    """
    path = Path(path)
    tables, names, facts = _tables(path)
    missing = [kind for kind in ("ACCE", "GYRO") if tables[_STREAMS[kind]] is None]
    if missing:
        if tables["gnss"] is None:
            raise CurbsideInputError(path, f"no {'/'.join(missing)} rows and no GNSS rows: nothing to make a "
                                     "session of (is it a GetSensorData logfile?)")
        logger.warning("%s: no %s rows; the session has no imu.csv (GNSS only)", path, "/".join(missing))
        tables.update({_STREAMS[kind]: None for kind in _IMU})
    elif tables["rotvec"] is None:
        logger.warning("%s: no AHRS rows: the IMU has no orientation (qx,qy,qz,qw); --pdr and the RoNIN "
                       "velocity need it", path)
    meta: dict = {
        "source": {"format": "getsensordata-txt", "file": path.name,
                   **{k: facts[k] for k in ("app_version", "created", "android_api", "android_version")
                      if k in facts}},
        "device": " ".join(facts[k] for k in ("manufacturer", "model") if facts.get(k)),
    }
    posi = tables["posi"]
    floors = None if posi is None else np.unique(posi["floor"].dropna()).astype(int)
    layout = Layout(str(path), streams={s: f"{path} ({k} rows)" for k, s in _STREAMS.items()},
                    kinds={s: f"{k} rows" for k, s in _STREAMS.items()}, names=names, rows="line")
    name = re.sub(r"^IPIN\d{4}_T\d+_", "", path.stem)
    session = build_session(name, tables, meta, layout, floors)
    if session.imu is None and session.gnss is None:
        raise CurbsideInputError(path, "no IMU rows (ACCE, GYRO) and no satellite GNSS fixes: nothing to "
                                 "make a session of")
    return session
