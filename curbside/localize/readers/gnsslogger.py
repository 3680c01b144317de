"""Google GnssLogger text logs (``gnss_log_*.txt``; GPSTest's file output has the same format).

What a log holds (the app's format description: github.com/google/gps-measurement-tools and GPSTest's
``LOGGING.md``; ``docs/sessions.md`` lists the real logs this reader was run on):

- ``#`` header lines. ``# Version: v3.0.6.4 Platform: 14 Manufacturer: Google Model: Pixel 7`` names the
  phone; each ``# TYPE,field,field,...`` line names the fields of the ``TYPE`` rows. Fields differ between
  app versions (``Fix`` gained ``NumberOfUsedSignals``...), so every value is read by its header name;
- data rows ``TYPE,value,...``. Read: ``Fix`` (``Provider``, ``LatitudeDegrees``, ``LongitudeDegrees``,
  ``AccuracyMeters``, ``elapsedRealtimeNanos``), ``Accel``/``UncalAccel`` (m/s^2, gravity included),
  ``Gyro``/``UncalGyro`` (rad/s), ``Mag``/``UncalMag`` (uT, only to check north) and ``OrientationDeg``
  (``yawDeg,rollDeg,pitchDeg``: ``SensorManager.getOrientation``'s azimuth, roll and pitch, from the
  rotation vector; older app versions log whole degrees). ``Raw``, ``Status``, ``Nav``, ``Agc``, ``NMEA``
  and any other row type are skipped unread;
- one clock: ``elapsedRealtimeNanos`` (time since boot, monotonic) in sensor and ``Fix`` rows alike;
  ``t = 0`` is the first sensor row or GPS/FLP fix. A ``Fix`` header without it (GnssLogger 2) is put on
  that clock through the offset between ``utcTimeMillis`` and ``elapsedRealtimeNanos`` of the sensor rows;
- the calibrated sensor rows are read; the uncalibrated ones, minus their logged bias (drift), only
  where the calibrated ones are missing (GPSTest logs only the uncalibrated ones when the phone has them);
- ``gnss.csv`` takes the ``GPS`` (chipset) fixes, or the ``FLP`` (fused) ones in a log without GPS fixes
  (the fused provider passes the chipset's fixes on: both would count one error twice); ``NLP`` (network:
  Wi-Fi and cell) positions are not GNSS and are dropped with a log line.

The device-to-East-North-Up quaternion is the exact inverse of ``getOrientation``:
``R = Rz(-azimuth) Rx(-pitch) Ry(roll)``. GPSTest writes getOrientation's pitch and roll in the other
order under the same header; the reader reads both ways and keeps the one that puts the accelerometer's
gravity on +z (refusing the log when neither does).
"""

from __future__ import annotations

import logging
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd
from scipy.spatial.transform import Rotation

from curbside.errors import CurbsideInputError
from curbside.localize.readers._export import check_same_clock
from curbside.localize.readers._platform import NORTH_TOLERANCE_DEG, magnetic_north_deg
from curbside.localize.readers._resample import interp_quaternions, merge_imu
from curbside.localize.readers._tidy import BLANK_CELLS, STANDARD_GRAVITY, accelerometer_ms2, tidy_table
from curbside.localize.session import Session

logger = logging.getLogger(__name__)

_CLOCK = "elapsedRealtimeNanos"
#: Sensor rows read: ``{type: (value fields, bias fields subtracted from them)}``.
_SENSORS = {
    "Accel": (("AccelXMps2", "AccelYMps2", "AccelZMps2"), ()),
    "UncalAccel": (("UncalAccelXMps2", "UncalAccelYMps2", "UncalAccelZMps2"),
                   ("BiasXMps2", "BiasYMps2", "BiasZMps2")),
    "Gyro": (("GyroXRadPerSec", "GyroYRadPerSec", "GyroZRadPerSec"), ()),
    "UncalGyro": (("UncalGyroXRadPerSec", "UncalGyroYRadPerSec", "UncalGyroZRadPerSec"),
                  ("DriftXRadPerSec", "DriftYRadPerSec", "DriftZRadPerSec")),
    "Mag": (("MagXMicroT", "MagYMicroT", "MagZMicroT"), ()),
    "UncalMag": (("UncalMagXMicroT", "UncalMagYMicroT", "UncalMagZMicroT"),
                 ("BiasXMicroT", "BiasYMicroT", "BiasZMicroT")),
}
_ORIENTATION = ("yawDeg", "rollDeg", "pitchDeg")
#: Row types read; every other type is skipped unread.
_READ = ("Fix", "OrientationDeg", *_SENSORS)
#: ``Fix`` fields by session column, the current name first (GnssLogger 2 used the short ones).
_FIX = {"lat": ("LatitudeDegrees", "Latitude"), "lon": ("LongitudeDegrees", "Longitude"),
        "accuracy_m": ("AccuracyMeters", "Accuracy")}
_FIX_UTC = ("UnixTimeMillis", "(UTC)TimeInMs")
#: Providers read (upper case), in the order of preference: the fixes of the first the log has are kept.
_GNSS_PROVIDERS = ("GPS", "FLP")
_NETWORK_PROVIDERS = ("NLP", "NETWORK")
_TYPE_NAME = re.compile(r"[A-Za-z][A-Za-z0-9]*")
_VERSION_LINE = re.compile(r"Version:\s*(?P<app>.*?)\s*Platform:\s*(?P<os>.*?)\s*"
                           r"Manufacturer:\s*(?P<maker>.*?)\s*Model:\s*(?P<model>.*?)\s*$")
_QUAT = ["qx", "qy", "qz", "qw"]


@dataclass
class _Log:
    """A parsed log: each read row type's cells as text (index: file line - 1) and the header facts."""

    path: Path
    headers: dict[str, list[str]] = field(default_factory=dict)
    header_lines: dict[str, int] = field(default_factory=dict)
    tables: dict[str, pd.DataFrame] = field(default_factory=dict)
    meta: dict = field(default_factory=dict)
    skipped: set[str] = field(default_factory=set)


def _header_line(body: str, number: int, log: _Log) -> None:
    """Record a ``# TYPE,fields`` or ``# Version: ...`` line (other comment lines say nothing)."""
    match = _VERSION_LINE.search(body)
    if match:
        found = {key: value for key, value in match.groupdict().items() if value and value != "null"}
        if found.get("app") and found["app"] != "Not Available":
            log.meta["app_version"] = found["app"]
        if found.get("os"):
            log.meta["android_version"] = found["os"]
        device = " ".join(found[k] for k in ("maker", "model") if k in found)
        if device:
            log.meta["device"] = device
        return
    name, *fields = [part.strip() for part in body.split(",")]
    if not fields or not _TYPE_NAME.fullmatch(name):
        return
    if name in log.headers and log.headers[name] != fields:
        raise CurbsideInputError(log.path, f"two different '# {name},...' header lines (lines "
                                 f"{log.header_lines[name]} and {number}): rows between them are ambiguous")
    log.headers[name] = fields
    log.header_lines[name] = number


def _table(log: _Log, kind: str, lines: list[str], numbers: list[int]) -> pd.DataFrame:
    """The cells of one row type, checked against its header's field count."""
    if kind not in log.headers:
        raise CurbsideInputError(log.path, f"line {numbers[0]}: {kind} rows, but no '# {kind},...' header "
                                 "line names their fields")
    names = log.headers[kind]
    cells = [line.split(",")[1:] for line in lines]
    counts = np.fromiter((len(c) for c in cells), int, len(cells))
    wrong = np.flatnonzero(counts != len(names))
    if len(wrong):
        i = wrong[0]
        raise CurbsideInputError(log.path, f"line {numbers[i]}: {kind} row with {counts[i]} fields where "
                                 f"its header (line {log.header_lines[kind]}) names {len(names)}")
    table = pd.DataFrame(cells, columns=names, index=np.asarray(numbers) - 1)
    return table.where(~table.isin(BLANK_CELLS))


def _parse(path: Path) -> _Log:
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise CurbsideInputError(path, f"cannot read ({exc.strerror})") from None
    except UnicodeDecodeError as exc:
        raise CurbsideInputError(path, f"not a GnssLogger log (not UTF-8 text: {exc.reason} at byte "
                                 f"{exc.start})") from None
    log = _Log(path)
    rows: dict[str, tuple[list[str], list[int]]] = {kind: ([], []) for kind in _READ}
    for number, line in enumerate(text.splitlines(), 1):
        line = line.strip()
        if line.startswith("#"):
            _header_line(line[1:].strip(), number, log)
            continue
        kind = line.partition(",")[0]
        if kind in rows:
            rows[kind][0].append(line)
            rows[kind][1].append(number)
        elif kind:
            log.skipped.add(kind)
    if not log.headers:
        raise CurbsideInputError(path, "not a GnssLogger log: no '# TYPE,field,...' header lines (a "
                                 "GnssLogger or GPSTest .txt starts with them)")
    for kind, (lines, numbers) in rows.items():
        if lines:
            log.tables[kind] = _table(log, kind, lines, numbers)
    return log


def _refuse_text(table: pd.DataFrame, fields: list[str], log: _Log, kind: str) -> None:
    """Raise at the first cell of ``fields`` (in file order) that holds text, not a number."""
    bad = pd.DataFrame({f: pd.to_numeric(table[f], errors="coerce").isna() & table[f].notna()
                        for f in fields})
    if bad.to_numpy().any():
        row, col = np.argwhere(bad.to_numpy())[0]
        name, index = fields[col], table.index[row]
        raise CurbsideInputError(log.path, f"non-numeric value {table.at[index, name]!r} in field {name!r} "
                                 f"of the {kind} row at line {index + 1}")


def _fields(log: _Log, kind: str, wanted: tuple[str, ...] | list[str]) -> None:
    """Raise unless the header of ``kind`` names every field of ``wanted``."""
    missing = [f for f in wanted if f not in log.headers[kind]]
    if missing:
        raise CurbsideInputError(log.path, f"the '# {kind},...' header (line {log.header_lines[kind]}) names "
                                 f"no {', '.join(missing)}")


def _elapsed_ns(log: _Log, kind: str) -> pd.Series:
    """The ``elapsedRealtimeNanos`` of a row type's rows (NaN where blank), text refused."""
    _fields(log, kind, (_CLOCK,))
    table = log.tables[kind]
    _refuse_text(table, [_CLOCK], log, kind)
    return pd.to_numeric(table[_CLOCK])


def _numbers(log: _Log, kind: str, fields: list[str], t0_ns: int) -> pd.DataFrame:
    """``elapsedRealtimeNanos`` as written, ``t`` (s since ``t0_ns``) and ``fields`` as numbers."""
    _fields(log, kind, fields)
    table = log.tables[kind]
    _refuse_text(table, fields, log, kind)
    out = table[fields].apply(pd.to_numeric)
    out.insert(0, "t", (_elapsed_ns(log, kind) - t0_ns) / 1e9)  # difference first: ns since boot are large
    out.insert(0, _CLOCK, table[_CLOCK])
    return out


def _sensor(log: _Log, kind: str, columns: tuple[str, str, str], t0_ns: int) -> pd.DataFrame:
    """A sensor's three axes as ``columns``, less the logged bias of an uncalibrated sensor."""
    values, bias = _SENSORS[kind]
    table = _numbers(log, kind, [*values, *bias], t0_ns)
    for col, own, minus in zip(columns, values, bias or (None,) * 3, strict=True):
        table[col] = table[own] - (table[minus].fillna(0.0) if minus else 0.0)
    names = {"t": _CLOCK, **dict(zip(columns, values, strict=True))}
    return tidy_table(table, log.path, ["t", *columns], names=names, rows="line")


def _pick(log: _Log, calibrated: str) -> str | None:
    """The calibrated row type when the log has it, else the uncalibrated one (with a warning), else None."""
    if calibrated in log.tables:
        return calibrated
    raw = f"Uncal{calibrated}"
    if raw in log.tables:
        logger.warning("%s: no %s rows; %s rows less their logged %s used instead", log.path, calibrated, raw,
                       "drift" if calibrated == "Gyro" else "bias")
        return raw
    return None


def _quaternions(yaw_deg: np.ndarray, pitch_deg: np.ndarray, roll_deg: np.ndarray) -> np.ndarray:
    """Device-to-ENU quaternions (x, y, z, w) whose ``SensorManager.getOrientation`` angles are those given.

    getOrientation reads azimuth = atan2(R01, R11), pitch = asin(-R21), roll = atan2(-R20, R22) off the
    device-to-world matrix ``R``; ``R = Rz(-azimuth) Rx(-pitch) Ry(roll)`` gives back exactly those.
    """
    angles = np.column_stack([-yaw_deg, -pitch_deg, roll_deg])
    return Rotation.from_euler("ZXY", angles, degrees=True).as_quat()


def _vertical_ms2(acce: pd.DataFrame, t: np.ndarray, quat: np.ndarray) -> float:
    """Mean world-vertical component (m/s^2) of the acceleration, turned by ``quat`` sampled at ``t``."""
    inside = (acce["t"] >= t[0]) & (acce["t"] <= t[-1])
    acc = acce.loc[inside, ["ax", "ay", "az"]].to_numpy(dtype=float, copy=True)
    if not len(acc):
        return float("nan")
    q = interp_quaternions(acce.loc[inside, "t"].to_numpy(), t, quat)
    return float(np.mean(Rotation.from_quat(q).apply(acc)[:, 2]))


def _orientation(log: _Log, acce: pd.DataFrame, t0_ns: int, meta: dict) -> pd.DataFrame:
    """The ``OrientationDeg`` rows as quaternions, their pitch and roll columns read as gravity says."""
    kind = "OrientationDeg"
    table = _numbers(log, kind, list(_ORIENTATION), t0_ns)
    names = {"t": _CLOCK, "yaw": "yawDeg", "roll": "rollDeg", "pitch": "pitchDeg"}
    table = table.rename(columns={own: col for col, own in names.items() if col != "t"})
    angles = tidy_table(table, log.path, ["t", "yaw", "roll", "pitch"], names=names, rows="line")
    if np.all(np.mod(angles[["yaw", "roll", "pitch"]].to_numpy(), 1.0) == 0):
        logger.info("%s: OrientationDeg in whole degrees (older GnssLogger): attitude quantised to 1 deg",
                    log.path)
    t = angles["t"].to_numpy()
    yaw, roll, pitch = (angles[c].to_numpy() for c in ("yaw", "roll", "pitch"))
    labelled, swapped = _quaternions(yaw, pitch, roll), _quaternions(yaw, roll, pitch)
    up, up_swapped = _vertical_ms2(acce, t, labelled), _vertical_ms2(acce, t, swapped)
    if np.isnan(up):
        raise CurbsideInputError(log.path, "OrientationDeg and accelerometer rows do not overlap in time")
    swap = up_swapped > max(up + 0.1 * STANDARD_GRAVITY, 0.8 * STANDARD_GRAVITY)
    if not swap and up < 0.8 * STANDARD_GRAVITY:
        raise CurbsideInputError(log.path, f"OrientationDeg and the accelerometer disagree on gravity (mean "
                                 f"vertical {up:.1f} m/s^2 in East-North-Up, {up_swapped:.1f} with rollDeg "
                                 f"and pitchDeg swapped; expected +{STANDARD_GRAVITY:.1f})")
    if swap:
        logger.warning("%s: OrientationDeg's rollDeg and pitchDeg hold pitch and roll (GPSTest's order): "
                       "read so (mean vertical acceleration %.1f m/s^2, %.1f as labelled)", log.path,
                       up_swapped, up)
    meta["orientation_columns"] = "yawDeg,pitch,roll (GPSTest)" if swap else "yawDeg,rollDeg,pitchDeg"
    return pd.DataFrame(np.column_stack([t, swapped if swap else labelled]), columns=["t", *_QUAT])


def _check_north(log: _Log, imu: pd.DataFrame, t0_ns: int, meta: dict) -> None:
    """Record (and warn when it is far off) where magnetic north lies in the world frame."""
    kind = "Mag" if "Mag" in log.tables else "UncalMag" if "UncalMag" in log.tables else None
    if kind is None:
        return
    try:
        mag = _sensor(log, kind, ("mx", "my", "mz"), t0_ns)
    except CurbsideInputError as exc:  # only a check: a sensor the session does not need must not stop it
        logger.info("%s (north not checked)", exc)
        return
    north = magnetic_north_deg(imu, mag)
    if north is None:
        return
    meta["magnetic_north_deg"] = round(north, 1) + 0.0  # + 0.0: no "-0.0"
    if abs(north) > NORTH_TOLERANCE_DEG:
        logger.warning("%s: magnetic north lies at %.0f deg in the world frame (expected within %.0f deg of "
                       "0): magnetic disturbance, a landscape screen (GnssLogger adds its rotation to "
                       "yawDeg), or a wrong frame", log.path, north, NORTH_TOLERANCE_DEG)


def _imu(log: _Log, t0_ns: int, meta: dict) -> pd.DataFrame | None:
    acc_kind, gyro_kind = _pick(log, "Accel"), _pick(log, "Gyro")
    if acc_kind is None or gyro_kind is None:
        present = sorted(set(log.tables) - {"Fix"})
        if present:
            logger.warning("%s: no imu.csv (needs accelerometer and gyroscope rows; has %s)", log.path,
                           ", ".join(present))
        return None
    acce = accelerometer_ms2(_sensor(log, acc_kind, ("ax", "ay", "az"), t0_ns), log.path)
    gyro = _sensor(log, gyro_kind, ("gx", "gy", "gz"), t0_ns)
    if min(len(acce), len(gyro)) < 2:
        logger.warning("%s: no imu.csv (%d %s and %d %s row(s): too few to sample)", log.path, len(acce),
                       acc_kind, len(gyro), gyro_kind)
        return None
    quat = None
    if "OrientationDeg" in log.tables:
        quat = _orientation(log, acce, t0_ns, meta)
    else:
        logger.warning("%s: no OrientationDeg rows; imu.csv has no quaternion (heading from it is "
                       "unavailable)", log.path)
    names = (f"{log.path} {acc_kind} rows", f"{log.path} {gyro_kind} rows", f"{log.path} OrientationDeg rows")
    imu = merge_imu(acce, gyro, quat, str(log.path), names)
    if quat is not None:
        _check_north(log, imu, t0_ns, meta)
    return imu


def _fix_ns(log: _Log, offset_ms: float | None) -> pd.Series:
    """The fixes' ``elapsedRealtimeNanos``; from their UTC time where the header has no such field."""
    if _CLOCK in log.headers["Fix"]:
        return _elapsed_ns(log, "Fix")
    utc = next((f for f in _FIX_UTC if f in log.headers["Fix"]), None)
    if utc is None:
        raise CurbsideInputError(log.path, f"the '# Fix,...' header (line {log.header_lines['Fix']}) names "
                                 f"no {_CLOCK} nor {_FIX_UTC[0]}")
    _refuse_text(log.tables["Fix"], [utc], log, "Fix")
    utc_ms = pd.to_numeric(log.tables["Fix"][utc])
    if offset_ms is None:
        return utc_ms * 1e6  # no sensor rows: the fixes' own clock is the session's
    logger.info("%s: Fix rows without %s: put on it through the sensor rows' utcTimeMillis", log.path, _CLOCK)
    return (utc_ms - offset_ms) * 1e6


def _provider_names(provider: pd.Series) -> pd.Series:
    """Provider names in upper case, Android's ``fused`` as ``FLP``."""
    return provider.fillna("").str.strip().str.upper().replace("FUSED", "FLP")


def _providers(table: pd.DataFrame, log: _Log) -> pd.DataFrame:
    """One provider's fixes: GPS where the log has any, else FLP; network and unknown providers dropped.

    A fused (FLP) fix passes the chipset's GNSS fix on, smoothed or as it is: kept beside the GPS fixes it
    would be the same error counted twice.
    """
    if "Provider" not in table.columns:
        logger.warning("%s: Fix rows name no Provider; every fix kept", log.path)
        return table
    provider = _provider_names(table["Provider"])
    network = provider.isin(_NETWORK_PROVIDERS)
    if network.any():
        logger.info("%s: dropped %d network (NLP) fix(es): Wi-Fi/cell positions, not GNSS", log.path,
                    int(network.sum()))
    other = ~provider.isin(_GNSS_PROVIDERS) & ~network
    if other.any():
        logger.warning("%s: dropped %d fix(es) of provider(s) %s (only GPS and FLP are read)", log.path,
                       int(other.sum()), ", ".join(sorted(set(provider[other]))))
    chosen = next((name for name in _GNSS_PROVIDERS if (provider == name).any()), None)
    fused = provider == "FLP"
    if chosen == "GPS" and fused.any():
        logger.info("%s: kept the %d GPS fixes and dropped %d FLP fix(es): the fused provider passes the "
                    "same GNSS on", log.path, int((provider == "GPS").sum()), int(fused.sum()))
    return table[provider == chosen]


def _gnss(log: _Log, t0_ns: float, fix_ns: pd.Series | None) -> pd.DataFrame | None:
    if "Fix" not in log.tables:
        logger.warning("%s: no Fix rows; the session has no gnss.csv", log.path)
        return None
    header = log.headers["Fix"]
    own = {col: next((f for f in names if f in header), names[0]) for col, names in _FIX.items()}
    _fields(log, "Fix", [own["lat"], own["lon"]])
    table = log.tables["Fix"]
    present = [f for f in own.values() if f in header]
    _refuse_text(table, present, log, "Fix")
    fixes = table[present].apply(pd.to_numeric).rename(columns={f: col for col, f in own.items()})
    if "accuracy_m" not in fixes.columns:
        logger.warning("%s: Fix rows have no AccuracyMeters; every fix has unknown accuracy (invalid)",
                       log.path)
        fixes["accuracy_m"] = np.nan
    fixes["t"] = (fix_ns - t0_ns) / 1e9
    if "Provider" in table.columns:
        fixes["Provider"] = table["Provider"]
    fixes = _providers(fixes, log)
    null_island = (fixes["lat"] == 0) & (fixes["lon"] == 0)
    if null_island.any():
        logger.info("%s: dropped %d fix(es) at (0, 0)", log.path, int(null_island.sum()))
    fixes = fixes[~null_island]
    if fixes.empty:
        logger.warning("%s: no GPS or FLP fix; the session has no gnss.csv", log.path)
        return None
    names = {"t": _CLOCK, **own}
    return tidy_table(fixes, log.path, ["t", "lat", "lon", "accuracy_m"], nullable=("accuracy_m",),
                      names=names, rows="line")


def _clock(log: _Log) -> tuple[int, float | None, pd.Series | None]:
    """``t0`` (the first ``elapsedRealtimeNanos`` of a sensor row or a kept fix), the boot time (UTC ms) and
    the fixes' ``elapsedRealtimeNanos`` (:func:`_fix_ns`; ``None`` without ``Fix`` rows).

    Raises when the sensor and ``Fix`` rows lie apart in time: not one clock (or not one recording).
    """
    spans = {f"{kind} rows": pd.DataFrame({"time": _elapsed_ns(log, kind)}) for kind in log.tables
             if kind != "Fix"}
    offsets = [pd.to_numeric(log.tables[k]["utcTimeMillis"], errors="coerce")
               - spans[f"{k} rows"]["time"] / 1e6
               for k in log.tables if k != "Fix" and "utcTimeMillis" in log.headers[k]]
    offset = pd.concat(offsets).dropna() if offsets else pd.Series(dtype=float)
    offset_ms = float(offset.median()) if len(offset) else None
    fix_ns = None
    if "Fix" in log.tables:
        fix_ns = _fix_ns(log, offset_ms)
        provider = log.tables["Fix"].get("Provider", pd.Series("GPS", index=fix_ns.index))
        kept = _provider_names(provider).isin(_GNSS_PROVIDERS)
        spans["Fix rows"] = pd.DataFrame({"time": fix_ns[kept]})
        if offset_ms is None and {_CLOCK, _FIX_UTC[0]} <= set(log.headers["Fix"]):  # for t0_unix_s only
            fix_offset = (pd.to_numeric(log.tables["Fix"][_FIX_UTC[0]], errors="coerce")
                          - fix_ns / 1e6).dropna()
            offset_ms = float(fix_offset.median()) if len(fix_offset) else None
    firsts = [s["time"].min() for s in spans.values() if s["time"].notna().any()]
    if not firsts:
        raise CurbsideInputError(log.path, f"no row has an {_CLOCK} time")
    reference = next((f"{k} rows" for k in ("Accel", "UncalAccel", "Gyro", "UncalGyro") if k in log.tables),
                     next(iter(spans)))
    check_same_clock({name: s.assign(time=s["time"] - min(firsts)) for name, s in spans.items()}, reference,
                     str(log.path))
    return int(min(firsts)), offset_ms, fix_ns


def read_gnsslogger(path: str | Path) -> Session:
    """Read a GnssLogger (or GPSTest) ``.txt`` log as a session.

    Parameters
    ----------
    path
        The log file.

    Returns
    -------
    Session
        ``imu`` (accelerometer + gyroscope, with the device-to-ENU quaternion when the log has
        ``OrientationDeg`` rows), ``gnss`` (GPS and FLP fixes) and ``meta`` (platform ``android``, device,
        app and Android version from the ``# Version:`` line, ``t0_unix_s``, ``magnetic_north_deg``).

    Raises
    ------
    CurbsideInputError
        Unreadable file, no header lines, a row type without a header or with another field count than
        its header's, text in a number field, sensor and ``Fix`` rows on different clocks, an orientation
        inconsistent with gravity, or neither a usable IMU nor a GPS/FLP fix.
    """
    path = Path(path)
    log = _parse(path)
    if not log.tables:
        skipped = f" (it has {', '.join(sorted(log.skipped))} rows, which this reader does not use)" \
            if log.skipped else ""
        raise CurbsideInputError(path, f"no Fix and no sensor (Accel, Gyro, OrientationDeg...) rows{skipped}")
    t0_ns, offset_ms, fix_ns = _clock(log)
    meta: dict = {"source": {"format": "gnsslogger", "file": path.name}, "platform": "android", **log.meta}
    if offset_ms is not None:
        meta["t0_unix_s"] = (offset_ms + t0_ns / 1e6) / 1e3
    imu = _imu(log, t0_ns, meta)
    gnss = _gnss(log, t0_ns, fix_ns)
    if imu is None and gnss is None:
        raise CurbsideInputError(path, "neither a usable IMU (accelerometer and gyroscope rows) nor a GPS or "
                                 "FLP Fix row")
    return Session(name=path.stem, imu=imu, gnss=gnss, meta=meta)


__all__ = ["read_gnsslogger"]
