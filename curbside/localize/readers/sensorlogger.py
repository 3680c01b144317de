"""Sensor Logger exports (the iOS/Android app by Kelvin Choi): a ``.zip`` or a folder of CSV files.

What the export holds (the app's references ``UNITS.md``, ``COORDINATES.md``, ``CROSSPLATFORM.md``
and ``ORIENTATION.md`` in github.com/tszheichoi/awesome-sensor-logger; ``docs/sessions.md`` quotes
them and lists the real exports this reader was run on):

- clocks: ``time`` (ns since the UNIX epoch) in every CSV; ``seconds_elapsed`` (s since the start
  tap) from export format 3 on. ``t`` is ``seconds_elapsed``, or for format-2 exports ``time``
  minus a common start; streams must overlap on ``time`` (see :mod:`._export`), ``time`` must be in
  ns and ``seconds_elapsed`` in s, and a block of rows set back in time (the phone's clock stepped
  back) is refused, in ``Location.csv`` warned about (see :mod:`._clock`);
- ``Accelerometer.csv`` (``x,y,z``, m/s^2) is acceleration **without** gravity on both platforms;
  ``TotalAcceleration.csv`` (Android) includes it; ``Gravity.csv`` is the gravity vector. ``imu.csv``
  needs gravity included: TotalAcceleration, else Accelerometer + Gravity, else Accelerometer +
  gravity restored from the orientation, else an Accelerometer that in fact reads ~1 g;
- iOS reports acceleration and gravity with the opposite sign of Android on all three axes unless
  "Standardise Units & Frames" is on (``standardisation`` in ``Metadata.csv``). With an orientation
  the sign is not taken on trust: the reader picks the sign (and the quaternion's direction) under
  which the orientation rotates the measured acceleration onto +9.8 m/s^2 up (for gravity restored
  from the orientation, measured on ``AccelerometerUncalibrated.csv`` when there is one); without one
  it follows the metadata;
- ``Gyroscope.csv``: rad/s, the same sign on both platforms;
- ``AccelerometerUncalibrated.csv`` and ``GyroscopeUncalibrated.csv`` (raw, gravity included; the
  gyroscope keeps its bias) stand in, with a warning, only for calibrated files the export lacks;
- ``Orientation.csv``: ``qx,qy,qz,qw`` (column order varies between versions). Android's is the
  rotation vector in East-North-Up; iOS's is CoreMotion's attitude in the x-true-north, z-up frame
  (North-West-Up), turned 90 degrees about the vertical into ENU. The turn was verified on a real
  iOS export against the magnetic field (docs/sessions.md); with ``Magnetometer.csv`` present the
  reader repeats that check on every export (``meta["magnetic_north_deg"]``) and, for standardised
  iOS exports, whose world frame is undocumented, follows it;
- the platform (and with it the sign and the world frame) comes from ``Metadata.csv``. An export
  without it (users re-zip only the CSVs they think matter) is not taken for Android: the reader
  infers the platform from, strongest first, the accelerometer sign found against the orientation
  (iOS's, or Android's, which a standardised iOS export shares), ``TotalAcceleration.csv`` (Android
  only), an ``AccelerometerUncalibrated.csv`` in g (iOS), magnetic north in the orientation's frame
  (near 0: ENU; near +90 deg: NWU, which with Android's sign means a standardised iOS export) and the
  iOS 1.10-1.11 ``Orientation.csv`` column order (:mod:`._platform`), logs what it found and what
  disagreed, and records it in ``meta["platform_inferred_from"]``. Without any cue it assumes
  Android frames (warning) and records no platform. Where the data cannot decide, the user can:
  ``platform=`` (``--platform``) replaces what ``Metadata.csv`` says;
- ``Location.csv``: ``latitude,longitude,horizontalAccuracy`` (m, ~1 sigma) -> ``gnss.csv``;
  (0, 0) fixes are dropped;
- ``Annotation.csv``: taps. A tap is a waypoint when its text is ``"lat,lon"``, or when a route file
  gives the surveyed positions of the taps in order; other taps go to ``meta["annotations"]``. A
  position farther than 5 km from every fix is not a waypoint (warning; a route file of nothing but
  such points is refused).

An empty file (0 bytes or a header only: the app writes ``Annotation.csv`` when annotations are on
but never tapped) counts as absent, so an export with an empty ``Location.csv`` is an IMU-only
session and one without motion files a GNSS-only session.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import pandas as pd
from scipy.spatial.transform import Rotation

from curbside.errors import CurbsideInputError
from curbside.localize.readers._clock import (
    check_clock_steps,
    check_elapsed,
    check_time_unit,
    clock_column,
    refuse_clock_text,
)
from curbside.localize.readers._export import Export, check_same_clock, find_recordings, open_export
from curbside.localize.readers._platform import (
    NORTH_TOLERANCE_DEG,
    Device,
    device_from_metadata,
    device_from_option,
    magnetic_north_deg,
    metadata_sign,
    north_quarter,
    settle_device,
)
from curbside.localize.readers._resample import MAX_SILENT_CUT_S, interp_quaternions, merge_imu, report_gaps
from curbside.localize.readers._tidy import (
    BLANK_CELLS,
    MAX_WAYPOINT_DISTANCE_M,
    STANDARD_GRAVITY,
    accelerometer_ms2,
    drop_far_waypoints,
    far_from_fixes,
    refuse_text,
    tidy_table,
)
from curbside.localize.session import Session

logger = logging.getLogger(__name__)

#: iOS world frame (x north, y west, z up) to East-North-Up: +90 degrees about the vertical.
NWU_TO_ENU = Rotation.from_euler("z", 90.0, degrees=True)

_MOTION_FILES = ("TotalAcceleration.csv", "Accelerometer.csv", "Gravity.csv", "Gyroscope.csv",
                 "Orientation.csv", "Magnetometer.csv")
#: Raw sensors, read only in place of missing calibrated ones: ``{file: the calibrated files it replaces}``.
_UNCALIBRATED = {"AccelerometerUncalibrated.csv": ("TotalAcceleration.csv", "Accelerometer.csv"),
                 "GyroscopeUncalibrated.csv": ("Gyroscope.csv",)}
#: Where the accelerometer (gravity included, or restorable) and the gyroscope come from, by preference.
_ACCELEROMETERS = ("TotalAcceleration.csv", "Accelerometer.csv", "AccelerometerUncalibrated.csv")
_GYROSCOPES = ("Gyroscope.csv", "GyroscopeUncalibrated.csv")
_QUAT = ["qx", "qy", "qz", "qw"]
_ACC = ("ax", "ay", "az")
#: ``Location.csv`` columns read, and their session names.
_LOCATION = {"latitude": "lat", "longitude": "lon", "horizontalAccuracy": "accuracy_m"}


def _read_streams(export) -> dict[str, pd.DataFrame]:
    streams: dict[str, pd.DataFrame] = {}
    for name in (*_MOTION_FILES, "Location.csv", "Annotation.csv", *_UNCALIBRATED):
        if name in _UNCALIBRATED and any(n in streams for n in _UNCALIBRATED[name]):
            continue
        table = export.read(name)
        if table is None:
            continue
        if table.empty:
            level = logging.INFO if name == "Annotation.csv" else logging.WARNING
            logger.log(level, "%s: no rows (empty file); ignored", export.source(name))
            continue
        streams[name] = table
    return streams


def _one_clock(streams: dict[str, pd.DataFrame], export, metadata: pd.DataFrame | None, meta: dict) -> None:
    """Add ``t`` (s) to every table in place; record the epoch of ``t = 0`` in ``meta``."""
    preferred = (*_ACCELEROMETERS, *_GYROSCOPES, "Location.csv")
    reference = next((n for n in preferred if n in streams), next(iter(streams)))
    for name, table in streams.items():
        refuse_clock_text(table, export.source(name))
        check_time_unit(table, export.source(name))
    check_same_clock(streams, reference, export.label)
    ref = streams[reference]
    for name, table in streams.items():
        check_elapsed(table, export.source(name))
    t0_ns = None
    if "time" in ref.columns and "seconds_elapsed" in ref.columns:
        offsets = _numbers(pd.to_numeric(ref["time"], errors="coerce") - 1e9 * pd.to_numeric(
            ref["seconds_elapsed"], errors="coerce"))
        t0_ns = float(np.median(offsets)) if len(offsets) else None
    elif metadata is not None and len(_numbers(metadata.get("recording epoch time", pd.Series()))):
        t0_ns = float(_numbers(metadata["recording epoch time"])[0]) * 1e6  # ms
    elif len(_numbers(ref.get("time", pd.Series()))):
        t0_ns = float(_numbers(ref["time"]).min())
    for name, table in streams.items():
        table["t"] = _time_s(table, t0_ns, export.source(name))
        if name != "Annotation.csv":  # taps: no sampling interval to judge a step by
            check_clock_steps(table, export.source(name), warn_only=name == "Location.csv")
    if t0_ns is not None:
        meta["t0_unix_s"] = t0_ns / 1e9


def _numbers(column: pd.Series) -> np.ndarray:
    """The finite numbers of a column (text and blanks left out)."""
    values = pd.to_numeric(column, errors="coerce").to_numpy(float)
    return values[np.isfinite(values)]


def _time_s(table: pd.DataFrame, t0_ns: float | None, source: str) -> pd.Series:
    """``t`` (s) of a table: ``seconds_elapsed``, else ``time`` (ns) since ``t0_ns``."""
    if "seconds_elapsed" in table.columns:
        return pd.to_numeric(table["seconds_elapsed"], errors="coerce")
    if "time" not in table.columns:
        raise CurbsideInputError(source, "no time column ('seconds_elapsed' or 'time')")
    if t0_ns is None:
        raise CurbsideInputError(source, "no 'seconds_elapsed', and the 'time' clock has no start (no number "
                                 "in the reference stream's 'time' column)")
    ns = pd.to_numeric(table["time"], errors="coerce")
    return (ns - int(t0_ns)) / 1e9  # difference first: float64 cannot hold ns epochs exactly


def _xyz(table: pd.DataFrame, source: str, cols: tuple[str, str, str]) -> pd.DataFrame:
    """The ``x,y,z`` of a motion file as the session columns ``cols``; errors name ``x,y,z``."""
    names = {"t": clock_column(table), **dict(zip(cols, ("x", "y", "z"), strict=True))}
    table = table.rename(columns={own: col for col, own in names.items() if col != "t"})
    return tidy_table(table, source, ["t", *cols], names=names)


def _orientation(streams, export: Export) -> pd.DataFrame | None:
    """The quaternions as exported (normalised); the iOS world frame is turned later, in :func:`_imu`."""
    table = streams.get("Orientation.csv")
    if table is None:
        return None
    source = export.source("Orientation.csv")
    quat = tidy_table(table, source, ["t", *_QUAT], names={"t": clock_column(table)})
    norm = np.linalg.norm(quat[_QUAT].to_numpy(), axis=1)
    if np.abs(norm - 1.0).max() > 0.05:
        as_read = np.linalg.norm(table[_QUAT].apply(pd.to_numeric).to_numpy(float), axis=1)
        row = int(np.argmax(np.abs(as_read - 1.0) > 0.05))  # NaN rows compare False
        raise CurbsideInputError(source, f"qx,qy,qz,qw are not unit quaternions: norm {as_read[row]:.2f} at "
                                 f"data row {row + 1} (norms {norm.min():.2f}-{norm.max():.2f})")
    quat[_QUAT] = quat[_QUAT].to_numpy() / norm[:, None]
    return quat


def _includes_gravity(acce: pd.DataFrame, source: str) -> bool:
    try:
        accelerometer_ms2(acce, source)
    except CurbsideInputError:
        return False
    return True


def _specific_force(streams, export: Export) -> tuple[pd.DataFrame, bool]:
    """The accelerometer, and whether it includes gravity (else gravity is still to be restored)."""
    for name in ("TotalAcceleration.csv", "AccelerometerUncalibrated.csv"):
        if name in streams:  # both include gravity; the raw one is read only when the others are absent
            return _xyz(streams[name], export.source(name), _ACC), True
    source = export.source("Accelerometer.csv")
    user = _xyz(streams["Accelerometer.csv"], source, _ACC)
    t = user["t"].to_numpy()
    if "Gravity.csv" in streams:
        gravity = _xyz(streams["Gravity.csv"], export.source("Gravity.csv"), _ACC)
        g_t = gravity["t"].to_numpy()
        report_gaps(g_t, export.source("Gravity.csv"), "filled by interpolation in imu.csv")
        inside = (t >= g_t[0]) & (t <= g_t[-1])  # gravity is not extrapolated: the phone may have turned
        lost_s = float(max(g_t[0] - t[0], 0.0) + max(t[-1] - g_t[-1], 0.0))
        if lost_s > MAX_SILENT_CUT_S:
            logger.warning("%s/Gravity.csv covers t=%.1f-%.1f s of the accelerometer's %.1f-%.1f s: imu.csv "
                           "cut to it (%.1f s lost)", export.label, g_t[0], g_t[-1], t[0], t[-1], lost_s)
        user = user[inside].reset_index(drop=True)
        for col in _ACC:
            user[col] = user[col] + np.interp(t[inside], g_t, gravity[col].to_numpy())
        return user, True
    return user, _includes_gravity(user, source)


def _raw_convention(export, quat: pd.DataFrame, meta: dict) -> tuple[float, bool] | None:
    """:func:`_gravity_convention` of ``AccelerometerUncalibrated.csv`` (gravity included), read beside a
    gravity-free Accelerometer.csv only to measure the export's sign; ``None`` when it cannot tell."""
    source = export.source("AccelerometerUncalibrated.csv")
    t0_s = meta.get("t0_unix_s")
    try:
        table = export.read("AccelerometerUncalibrated.csv")
        if table is None or table.empty:
            return None
        table["t"] = _time_s(table, None if t0_s is None else t0_s * 1e9, source)
        raw = accelerometer_ms2(_xyz(table, source, _ACC), source)
        t = raw["t"].to_numpy()
        inside = (t >= quat["t"].iat[0]) & (t <= quat["t"].iat[-1])
        if inside.sum() < 2:
            return None
        raw = raw[inside].reset_index(drop=True)
        raw[_QUAT] = interp_quaternions(raw["t"].to_numpy(), quat["t"].to_numpy(), quat[_QUAT].to_numpy())
        return _gravity_convention(raw, source)
    except CurbsideInputError as exc:  # only a cue: a file the reader does not need must not stop it
        logger.info("%s (its sign not used)", exc)
        return None


def _gravity_from_orientation(
    acce: pd.DataFrame, quat: pd.DataFrame, streams, export, device: Device, mag: pd.DataFrame | None,
    meta: dict,
) -> tuple[pd.DataFrame, pd.DataFrame, Device]:
    """Android-signed acceleration with gravity restored from the orientation; the orientation (inverted
    when found world-to-device) and the settled device.

    The sign (and the quaternion's direction) is measured as with gravity included, on the raw
    accelerometer when the export has one; else it follows the platform.
    """
    measured = _raw_convention(export, quat, meta)
    if measured is not None and measured[1]:
        logger.info("%s: orientation is world-to-device (against AccelerometerUncalibrated.csv); inverted",
                    export.label)
        quat = quat.copy()
        quat[_QUAT] = Rotation.from_quat(quat[_QUAT].to_numpy()).inv().as_quat()
    sign = None if measured is None else measured[0]
    device = settle_device(device, streams, export, quat, sign, mag, meta)
    acce = _restore_gravity(acce, quat, metadata_sign(device) if sign is None else sign, export.label)
    return acce, quat, device


def _restore_gravity(user: pd.DataFrame, quat: pd.DataFrame, sign: float, label: str) -> pd.DataFrame:
    """Android-signed acceleration: ``sign`` times the gravity-free ``user``, plus gravity from ``quat``."""
    # "Up" in the device frame is g along the world z axis seen from the phone.
    q = interp_quaternions(user["t"].to_numpy(), quat["t"].to_numpy(), quat[_QUAT].to_numpy())
    up = Rotation.from_quat(q).inv().apply([0.0, 0.0, STANDARD_GRAVITY])
    user[list(_ACC)] = sign * user[list(_ACC)].to_numpy() + up
    logger.warning("%s: no Gravity.csv; gravity restored from Orientation.csv", label)
    return user


def _gravity_convention(imu: pd.DataFrame, source: str) -> tuple[float, bool]:
    """Accelerometer sign and quaternion direction that put gravity on +z (up) in the world frame.

    Returns ``(sign, invert)``. With the phone flat, inverting the quaternion changes nothing
    vertically; the documented direction (device-to-world) is kept unless inverting is clearly better.
    """
    acc = imu[list(_ACC)].to_numpy(dtype=float, copy=True)
    rot = Rotation.from_quat(imu[_QUAT].to_numpy())
    up_direct = float(np.mean(rot.apply(acc)[:, 2]))
    up_inverse = float(np.mean(rot.inv().apply(acc)[:, 2]))
    invert = abs(up_inverse) > abs(up_direct) + 0.1 * STANDARD_GRAVITY
    up = up_inverse if invert else up_direct
    if abs(up) < 0.8 * STANDARD_GRAVITY:
        raise CurbsideInputError(
            source, f"orientation and accelerometer disagree on gravity (mean vertical {up:.1f} m/s^2)"
        )
    return (1.0 if up > 0 else -1.0), invert


def _check_north(imu: pd.DataFrame, mag: pd.DataFrame | None, label: str, device: Device,
                 meta: dict) -> None:
    """Compare the world frame's north with magnetic north; for standardised iOS exports, follow it."""
    if mag is None:
        if device.platform == "ios" and device.standardised:
            logger.warning("%s: standardised iOS export without Magnetometer.csv; orientation assumed in "
                           "CoreMotion's x-north frame (unverified for standardised exports; one already in "
                           "East-North-Up reads right with --platform android)", label)
        return
    north = magnetic_north_deg(imu, mag)
    if north is None:
        return
    snapped = north_quarter(north)
    if device.platform == "ios" and device.standardised and snapped:
        # A world frame turned by +phi about up shows north at -phi: turning by the azimuth undoes it.
        turn = Rotation.from_euler("z", snapped, degrees=True)
        imu[_QUAT] = (turn * Rotation.from_quat(imu[_QUAT].to_numpy())).as_quat()
        logger.warning("%s: standardised iOS export: after the NWU->ENU turn magnetic north lies at %.0f deg;"
                       " world frame turned %+.0f deg about the vertical to match it", label, north, snapped)
        north = north - snapped
    meta["magnetic_north_deg"] = round(north, 1) + 0.0  # + 0.0: no "-0.0"
    if abs(north) > NORTH_TOLERANCE_DEG:
        logger.warning("%s: magnetic north lies at %.0f deg in the world frame (expected within %.0f deg "
                       "of 0): magnetic disturbance, or a wrong frame", label, north, NORTH_TOLERANCE_DEG)
    else:
        logger.info("%s: magnetic north at %.1f deg in the world frame", label, north)


def _report_uncalibrated(streams, label: str) -> None:
    """Warn that raw (uncalibrated) sensors stand in for calibrated ones the export lacks."""
    raw = [n for n in _UNCALIBRATED if n in streams]
    if not raw:
        return
    missing = ", no ".join("/".join(_UNCALIBRATED[n]) for n in raw)
    bias = " (the uncalibrated gyroscope keeps its bias: the heading drifts)" \
        if "GyroscopeUncalibrated.csv" in raw else ""
    logger.warning("%s: no %s: imu.csv made from %s instead%s; enable the calibrated sensors (Accelerometer, "
                   "Gravity, Gyroscope, Orientation) in Sensor Logger", label, missing, ", ".join(raw), bias)


def _imu(streams, export, device: Device, meta: dict) -> pd.DataFrame | None:
    label = export.label
    acc_name = next((n for n in _ACCELEROMETERS if n in streams), None)
    gyro_name = next((n for n in _GYROSCOPES if n in streams), None)
    if acc_name is None or gyro_name is None:
        present = [n for n in (*_MOTION_FILES, *_UNCALIBRATED) if n in streams]
        if present:
            logger.warning("%s: no imu.csv (needs an accelerometer and Gyroscope.csv; has %s)",
                           label, ", ".join(present))
        return None
    _report_uncalibrated(streams, label)
    quat = _orientation(streams, export)
    mag = None
    if quat is not None and "Magnetometer.csv" in streams:  # of use only against an orientation
        mag = _xyz(streams["Magnetometer.csv"], export.source("Magnetometer.csv"), ("mx", "my", "mz"))
    acce, with_gravity = _specific_force(streams, export)
    if not with_gravity:
        if quat is None:
            raise CurbsideInputError(export.source("Accelerometer.csv"), "acceleration without gravity, and "
                                     "no TotalAcceleration.csv, Gravity.csv or Orientation.csv to restore it")
        acce, quat, device = _gravity_from_orientation(acce, quat, streams, export, device, mag, meta)
    acce = accelerometer_ms2(acce, export.source(acc_name))
    gyro = _xyz(streams[gyro_name], export.source(gyro_name), ("gx", "gy", "gz"))
    names = (export.source(acc_name), export.source(gyro_name), export.source("Orientation.csv"))
    imu = merge_imu(acce, gyro, quat, label, names)
    sign = None
    if quat is not None and with_gravity:
        sign, invert = _gravity_convention(imu, label)
        if invert:
            logger.info("%s: orientation is world-to-device; inverted", label)
            imu[_QUAT] = Rotation.from_quat(imu[_QUAT].to_numpy()).inv().as_quat()
    device = settle_device(device, streams, export, None if quat is None else imu, sign, mag, meta)
    if sign is None and with_gravity:
        sign = metadata_sign(device)
    if sign is not None and sign < 0:
        logger.info("%s: acceleration in the iOS sign convention; negated", label)
        imu[list(_ACC)] *= -1.0
    if quat is None:
        logger.warning("%s: no Orientation.csv; imu.csv has no quaternion (heading from it is unavailable)",
                       label)
        return imu
    if device.platform == "ios":  # the world frame turned, after any inversion: NWU -> ENU
        imu[_QUAT] = (NWU_TO_ENU * Rotation.from_quat(imu[_QUAT].to_numpy())).as_quat()
    _check_north(imu, mag, label, device, meta)
    return imu


def _gnss(streams, export: Export) -> pd.DataFrame | None:
    table = streams.get("Location.csv")
    if table is None:
        return None
    source = export.source("Location.csv")
    missing = [c for c in ("latitude", "longitude") if c not in table.columns]
    if missing:
        raise CurbsideInputError(source, f"missing column(s) {missing}")
    refuse_text(table, list(_LOCATION), source)  # blanks are dropped below, text is not a position
    names = {"t": clock_column(table), **{col: own for own, col in _LOCATION.items()}}
    table = table.rename(columns=_LOCATION)
    if "accuracy_m" not in table.columns:
        logger.warning("%s: no horizontalAccuracy column; every fix has unknown accuracy (invalid)", source)
        table["accuracy_m"] = np.nan
    elif not (pd.to_numeric(table["accuracy_m"], errors="coerce") > 0).any():  # iOS: -1 for invalid
        logger.warning("%s: no horizontalAccuracy above 0; every fix has unknown accuracy (invalid)", source)
    lat = pd.to_numeric(table["lat"], errors="coerce")
    lon = pd.to_numeric(table["lon"], errors="coerce")
    null_island = (lat == 0) & (lon == 0)
    if null_island.any():
        logger.info("%s: dropped %d fix(es) at (0, 0) (no position yet)", source, int(null_island.sum()))
    table = table[~null_island & lat.notna() & lon.notna()]
    if table.empty:
        logger.warning("%s: no usable fix; the session has no gnss.csv", source)
        return None
    return tidy_table(table, source, ["t", "lat", "lon", "accuracy_m"], nullable=("accuracy_m",), names=names)


def _route_waypoints(taps: pd.DataFrame, route: Path, gnss: pd.DataFrame | None) -> pd.DataFrame:
    try:
        points = pd.read_csv(route, skipinitialspace=True, keep_default_na=False, na_values=list(BLANK_CELLS))
    except (OSError, pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError) as exc:
        raise CurbsideInputError(route, f"unreadable route CSV ({str(exc).splitlines()[0]})") from None
    if not {"lat", "lon"} <= set(points.columns):
        raise CurbsideInputError(route, "route needs columns lat,lon (one row per tap)")
    if len(points) != len(taps):
        raise CurbsideInputError(route, f"{len(points)} route points for {len(taps)} taps")
    table = pd.DataFrame({"t": taps["t"].to_numpy(), "lat": points["lat"].to_numpy(),
                          "lon": points["lon"].to_numpy()})  # one row per tap, in the route's order
    table = tidy_table(table, route, ["t", "lat", "lon"])
    far = far_from_fixes(table, gnss)
    if far.all():
        km = MAX_WAYPOINT_DISTANCE_M / 1000
        raise CurbsideInputError(route, f"none of its {len(table)} point(s) lies within {km:.0f} km of a "
                                 "GNSS fix (the route of another walk?)")
    return drop_far_waypoints(table, gnss, route, "point(s)", "GNSS fix")


def _waypoints(streams, export: Export, route: str | Path | None, meta: dict,
               gnss: pd.DataFrame | None) -> pd.DataFrame | None:
    taps = streams.get("Annotation.csv")
    if taps is None:
        if route is not None:
            raise CurbsideInputError(route, "a route was given but the export has no Annotation.csv taps")
        return None
    taps = taps.sort_values("t", kind="stable")  # the index still numbers the file's rows, for errors
    if route is not None:
        return _route_waypoints(taps, Path(route), gnss)
    text = taps["text"].fillna("").astype(str) if "text" in taps.columns else pd.Series("", index=taps.index)
    parts = text.str.split(",", n=1, expand=True).reindex(columns=[0, 1])
    lat = pd.to_numeric(parts[0], errors="coerce")
    lon = pd.to_numeric(parts[1], errors="coerce")
    located = (lat.notna() & lon.notna()).to_numpy()
    far = np.zeros(len(taps), bool)
    far[located] = far_from_fixes(pd.DataFrame({"lat": lat[located], "lon": lon[located]}), gnss)
    if far.any():
        listed = ", ".join(f"{s!r} at t={t:.1f} s" for s, t in zip(text[far], taps["t"][far], strict=True))
        logger.warning("%s/Annotation.csv: %d tap(s) read as 'lat,lon' lie more than %.0f km from every GNSS "
                       "fix (%s): not waypoints, kept in meta['annotations']", export.label, int(far.sum()),
                       MAX_WAYPOINT_DISTANCE_M / 1000, listed)
        located = located & ~far
    others = taps.loc[~located]
    if len(others):
        meta["annotations"] = [
            {"t": float(t), "text": s} for t, s in zip(others["t"], text[~located], strict=True)
        ]
        logger.info("%s: %d tap(s) without 'lat,lon' text kept in meta['annotations'] (use a route file)",
                    export.label, len(others))
    if not located.any():
        return None
    table = pd.DataFrame({"t": taps.loc[located, "t"], "lat": lat[located], "lon": lon[located]})
    names = {"t": clock_column(taps), "lat": "text", "lon": "text"}
    return tidy_table(table, export.source("Annotation.csv"), ["t", "lat", "lon"], names=names)


def read_sensorlogger(
    src: str | Path, route: str | Path | None = None, platform: str | None = None
) -> Session:
    """Read a Sensor Logger export (zip or folder, optionally ``SRC::RECORDING``) as a session.

    Parameters
    ----------
    src
        The ``.zip`` export or the folder it unpacks to. When it holds several recordings (a zip or
        folder tree of several exports), name one: ``exports.zip::2024-02-11_15-02-01`` (the
        folder's path inside ``src``, or its last part when that is unique).
    route
        Optional CSV of the surveyed positions (``lat,lon``) of the ``Annotation.csv`` taps, in tap
        order; without it, taps whose text is ``"lat,lon"`` are the waypoints.
    platform
        ``"android"``, ``"ios"`` or ``"ios-standardised"`` ("Standardise Units & Frames" on): read
        the export as that platform's, whatever ``Metadata.csv`` says or when it is missing (the data
        cannot always tell: a standardised iOS export without it and without a magnetometer, for one).

    Returns
    -------
    Session
        ``imu`` (accelerometer + gyroscope, with the quaternion when there is an orientation),
        ``gnss``, ``waypoints`` and ``meta`` (source; platform and standardisation, when
        ``Metadata.csv`` names them or the data shows them; device, app and export version,
        ``t0_unix_s``, ``magnetic_north_deg``, annotations).

    Raises
    ------
    CurbsideInputError
        Unreadable zip or CSV, several recordings and none chosen, streams on different clocks,
        missing columns, acceleration without gravity and no way to restore it, an orientation
        inconsistent with gravity, a bad route file, an unknown ``platform``, or neither IMU nor GNSS
        data.
    """
    export = open_export(src)
    label = export.label
    try:
        metadata = export.read("Metadata.csv")
    except CurbsideInputError as exc:  # the data can still be read; the platform is inferred from it
        logger.warning("%s (ignored)", exc)
        metadata = None
    device = device_from_metadata(metadata, label)
    if platform is not None:
        device = device_from_option(platform, device, label)
    meta: dict = {"source": {"format": "sensorlogger", "file": export.src.name}, **device.meta}
    if export.folder != ".":
        meta["source"]["recording"] = export.folder
    streams = _read_streams(export)
    if not streams:
        raise CurbsideInputError(label, "export has no data: every motion and location file is empty")
    _one_clock(streams, export, metadata, meta)
    imu = _imu(streams, export, device, meta)
    gnss = _gnss(streams, export)
    waypoints = _waypoints(streams, export, route, meta, gnss)
    if imu is None and gnss is None:
        raise CurbsideInputError(label, "export has neither a usable IMU (accelerometer + gyroscope) "
                                 "nor Location.csv fixes")
    return Session(name=export.name, imu=imu, gnss=gnss, waypoints=waypoints, meta=meta)


def looks_like_export(folder: str | Path) -> bool:
    """Whether ``folder`` (or a folder below it) holds Sensor Logger CSV files."""
    return bool(find_recordings(Path(folder)))


__all__ = ["NWU_TO_ENU", "looks_like_export", "magnetic_north_deg", "read_sensorlogger"]
