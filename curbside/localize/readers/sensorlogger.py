"""Sensor Logger exports (the iOS/Android app by Kelvin Choi): a ``.zip`` or a folder of CSV files.

What the export holds (the app's own references, `UNITS.md`, `COORDINATES.md`, `CROSSPLATFORM.md`
and `ORIENTATION.md` in github.com/tszheichoi/awesome-sensor-logger; ``docs/sessions.md`` quotes them):

- every CSV has ``time`` (ns since the UNIX epoch, UTC) and ``seconds_elapsed`` (s since the start
  tap, possibly negative for buffered samples). ``t`` here is ``seconds_elapsed``; the epoch of
  ``t = 0`` goes to ``meta["t0_unix_s"]``;
- ``Accelerometer.csv`` (``x,y,z``, m/s^2) is acceleration **without** gravity on both platforms;
  ``TotalAcceleration.csv`` (Android only) includes gravity; ``Gravity.csv`` is the gravity vector.
  ``imu.csv`` needs gravity included, so ``ax,ay,az`` = TotalAcceleration when present, else
  Accelerometer + Gravity (Gravity interpolated onto the accelerometer clock). An Accelerometer
  alone is accepted only when it is in fact about 1 g in magnitude (checked, g converted);
- iOS reports acceleration and gravity with the opposite sign of Android on all three axes (unless
  the app's "Standardise Units & Frames" is on), so the sign is not taken on trust: the reader
  picks the sign (and the quaternion's direction, device-to-world or world-to-device) under which
  the orientation rotates the measured acceleration onto +9.8 m/s^2 up, the Android/SPEC convention;
- ``Gyroscope.csv``: rad/s, the same sign on both platforms;
- ``Orientation.csv``: ``qx,qy,qz,qw`` (plus ``roll,pitch,yaw``). Android's is the rotation vector
  (East-North-Up world frame); iOS's is CoreMotion's attitude in the x-true-north, z-up frame, so its
  world frame is North-West-Up and is turned 90 degrees about the vertical into ENU. The platform is
  read from ``Metadata.csv`` (``platform``: iOS or Android); without it Android is assumed (logged);
- ``Location.csv``: ``latitude,longitude,horizontalAccuracy`` (m, about one standard deviation,
  negative = invalid) -> ``gnss.csv``;
- ``Annotation.csv``: taps (``text``, ``millisecond_press_duration``). A tap is a waypoint when its
  text is ``"lat,lon"``, or when a route file gives the surveyed positions of the taps in order
  (``route=``: a CSV with ``lat,lon`` columns, one row per tap). Other taps are kept in
  ``meta["annotations"]``.
"""

from __future__ import annotations

import io
import logging
import zipfile
from pathlib import Path

import numpy as np
import pandas as pd
from scipy.spatial.transform import Rotation

from curbside.errors import CurbsideInputError
from curbside.localize.readers._resample import merge_imu
from curbside.localize.readers._tidy import STANDARD_GRAVITY, accelerometer_ms2, tidy_table
from curbside.localize.session import Session

logger = logging.getLogger(__name__)

#: Files whose presence marks a folder as a Sensor Logger export (lower-case names).
MARKERS = ("accelerometer.csv", "totalacceleration.csv", "gyroscope.csv", "location.csv", "orientation.csv")

#: iOS world frame (x north, y west, z up) to East-North-Up: +90 degrees about the vertical.
NWU_TO_ENU = Rotation.from_euler("z", 90.0, degrees=True)


class _Export:
    """The CSV files of one export, by lower-case base name, from a folder or a zip."""

    def __init__(self, src: Path) -> None:
        self.src = src
        self._files: dict[str, bytes | Path] = {}
        if src.is_dir():
            for path in src.rglob("*.csv"):
                self._files.setdefault(path.name.lower(), path)
        elif src.is_file():
            try:
                with zipfile.ZipFile(src) as zf:
                    for info in zf.infolist():
                        name = Path(info.filename).name.lower()
                        if name.endswith(".csv") and not info.is_dir():
                            self._files.setdefault(name, zf.read(info))
            except (zipfile.BadZipFile, OSError) as exc:
                raise CurbsideInputError(src, f"unreadable zip ({exc})") from None
        else:
            raise CurbsideInputError(src, "no such file or folder")

    def has(self, name: str) -> bool:
        return name.lower() in self._files

    def read(self, name: str, timed: bool = True) -> pd.DataFrame | None:
        item = self._files.get(name.lower())
        if item is None:
            return None
        source = f"{self.src}/{name}"
        try:
            table = pd.read_csv(io.BytesIO(item) if isinstance(item, bytes) else item, skipinitialspace=True)
        except (pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError) as exc:
            raise CurbsideInputError(source, f"malformed CSV ({str(exc).splitlines()[0]})") from None
        table.columns = [str(c).strip() for c in table.columns]
        if not timed:
            return table
        if "seconds_elapsed" not in table.columns:
            raise CurbsideInputError(source, "missing column 'seconds_elapsed'")
        return table.rename(columns={"seconds_elapsed": "t"})


def looks_like_export(folder: str | Path) -> bool:
    """Whether ``folder`` holds any of the Sensor Logger CSV files."""
    folder = Path(folder)
    return any(p.name.lower() in MARKERS for p in folder.glob("*.csv"))


def _xyz(export: _Export, name: str, cols: tuple[str, str, str]) -> pd.DataFrame | None:
    table = export.read(name)
    if table is None:
        return None
    table = table.rename(columns=dict(zip(("x", "y", "z"), cols, strict=True)))
    return tidy_table(table, f"{export.src}/{name}", ["t", *cols])


def _total_acceleration(export: _Export) -> pd.DataFrame:
    total = _xyz(export, "TotalAcceleration.csv", ("ax", "ay", "az"))
    if total is not None:
        return total
    user = _xyz(export, "Accelerometer.csv", ("ax", "ay", "az"))
    if user is None:
        raise CurbsideInputError(export.src, "no Accelerometer.csv or TotalAcceleration.csv")
    gravity = _xyz(export, "Gravity.csv", ("ax", "ay", "az"))
    if gravity is None:
        return user
    t = user["t"].to_numpy()
    for col in ("ax", "ay", "az"):
        user[col] = user[col] + np.interp(t, gravity["t"].to_numpy(), gravity[col].to_numpy())
    return user


def _platform(export: _Export) -> str:
    meta = export.read("Metadata.csv", timed=False) if export.has("Metadata.csv") else None
    if meta is not None and "platform" in meta.columns and len(meta):
        return str(meta["platform"].iat[0]).strip().lower()
    logger.warning("%s: no Metadata.csv platform; assuming Android frames", export.src)
    return "android"


def _gravity_convention(imu: pd.DataFrame, source: Path) -> tuple[float, bool]:
    """Accelerometer sign and quaternion direction that put gravity on +z (up) in the world frame.

    Returns ``(sign, invert)``. With the phone flat, inverting the quaternion changes nothing
    vertically; the documented direction (device-to-world) is kept unless inverting is clearly better.
    """
    acc = imu[["ax", "ay", "az"]].to_numpy(dtype=float, copy=True)
    rot = Rotation.from_quat(imu[["qx", "qy", "qz", "qw"]].to_numpy())
    up_direct = float(np.mean(rot.apply(acc)[:, 2]))
    up_inverse = float(np.mean(rot.inv().apply(acc)[:, 2]))
    invert = abs(up_inverse) > abs(up_direct) + 0.1 * STANDARD_GRAVITY
    up = up_inverse if invert else up_direct
    if abs(up) < 0.8 * STANDARD_GRAVITY:
        raise CurbsideInputError(
            source, f"orientation and accelerometer disagree on gravity (mean vertical {up:.1f} m/s^2)"
        )
    return (1.0 if up > 0 else -1.0), invert


def _waypoints(
    export: _Export, route: str | Path | None, meta: dict
) -> pd.DataFrame | None:
    taps = export.read("Annotation.csv")
    if taps is None or taps.empty:
        if route is not None:
            raise CurbsideInputError(route, "a route was given but the export has no Annotation.csv taps")
        return None
    taps = taps.sort_values("t").reset_index(drop=True)
    text = taps["text"].astype(str) if "text" in taps.columns else pd.Series([""] * len(taps))
    if route is not None:
        route = Path(route)
        try:
            points = pd.read_csv(route, skipinitialspace=True)
        except (OSError, pd.errors.ParserError, pd.errors.EmptyDataError) as exc:
            raise CurbsideInputError(route, f"unreadable route CSV ({exc})") from None
        if not {"lat", "lon"} <= set(points.columns):
            raise CurbsideInputError(route, "route needs columns lat,lon (one row per tap)")
        if len(points) != len(taps):
            raise CurbsideInputError(route, f"{len(points)} route points for {len(taps)} taps")
        table = pd.DataFrame(
            {"t": taps["t"], "lat": points["lat"].to_numpy(), "lon": points["lon"].to_numpy()}
        )
        return tidy_table(table, route, ["t", "lat", "lon"])
    parts = text.str.split(",", n=1, expand=True).reindex(columns=[0, 1])
    lat = pd.to_numeric(parts[0], errors="coerce")
    lon = pd.to_numeric(parts[1], errors="coerce")
    located = lat.notna() & lon.notna()
    others = taps.loc[~located]
    if len(others):
        meta["annotations"] = [
            {"t": float(t), "text": s} for t, s in zip(others["t"], text[~located], strict=True)
        ]
        logger.info("%s: %d tap(s) without 'lat,lon' text kept in meta['annotations'] (use a route file)",
                    export.src, len(others))
    if not located.any():
        return None
    table = pd.DataFrame({"t": taps.loc[located, "t"], "lat": lat[located], "lon": lon[located]})
    return tidy_table(table, f"{export.src}/Annotation.csv", ["t", "lat", "lon"])


def _imu(export: _Export, platform: str, meta: dict) -> pd.DataFrame:
    src = export.src
    acce = _total_acceleration(export)
    accel_file = "TotalAcceleration.csv" if export.has("TotalAcceleration.csv") else "Accelerometer.csv"
    stamps = export.read(accel_file)
    if "time" in stamps.columns:
        epoch = stamps["time"].to_numpy(float) / 1e9 - stamps["t"].to_numpy(float)
        meta["t0_unix_s"] = float(np.median(epoch))
    acce = accelerometer_ms2(acce, f"{src}/Accelerometer.csv")
    gyro = _xyz(export, "Gyroscope.csv", ("gx", "gy", "gz"))
    quat_cols = ["qx", "qy", "qz", "qw"]
    quat = tidy_table(export.read("Orientation.csv"), f"{src}/Orientation.csv", ["t", *quat_cols])
    if platform == "ios":
        quat[quat_cols] = (NWU_TO_ENU * Rotation.from_quat(quat[quat_cols].to_numpy())).as_quat()
    imu = merge_imu(acce, gyro, quat, str(src))
    sign, invert = _gravity_convention(imu, src)
    if sign < 0:
        logger.info("%s: acceleration in the iOS sign convention; negated", src)
        imu[["ax", "ay", "az"]] *= -1.0
    if invert:
        logger.info("%s: orientation is world-to-device; inverted", src)
        imu[quat_cols] = Rotation.from_quat(imu[quat_cols].to_numpy()).inv().as_quat()
    return imu


def read_sensorlogger(src: str | Path, route: str | Path | None = None) -> Session:
    """Read a Sensor Logger export (zip or folder) as a session.

    Parameters
    ----------
    src
        The ``.zip`` export or the folder it unpacks to.
    route
        Optional CSV of the surveyed positions (``lat,lon``) of the ``Annotation.csv`` taps, in tap
        order; without it, taps whose text is ``"lat,lon"`` are the waypoints.

    Returns
    -------
    Session
        ``imu`` (when accelerometer, gyroscope and orientation are present), ``gnss``, ``waypoints``
        and ``meta`` (source, platform, ``t0_unix_s``).

    Raises
    ------
    CurbsideInputError
        Unreadable zip or CSV, missing columns, an accelerometer without gravity and no Gravity.csv,
        streams that do not overlap, an orientation inconsistent with gravity, a bad route file.
    """
    src = Path(src)
    export = _Export(src)
    if not any(export.has(m) for m in MARKERS):
        raise CurbsideInputError(src, "not a Sensor Logger export (no Accelerometer/Location/... CSV)")
    platform = _platform(export)
    meta: dict = {"source": {"format": "sensorlogger", "file": src.name}, "platform": platform}

    imu = None
    if export.has("Gyroscope.csv") and export.has("Orientation.csv"):
        imu = _imu(export, platform, meta)
    elif export.has("Accelerometer.csv") or export.has("TotalAcceleration.csv"):
        logger.warning("%s: no Gyroscope.csv/Orientation.csv; imu.csv not written", src)

    gnss = None
    location = export.read("Location.csv")
    if location is not None:
        location = location.rename(
            columns={"latitude": "lat", "longitude": "lon", "horizontalAccuracy": "accuracy_m"}
        )
        gnss = tidy_table(location, f"{src}/Location.csv", ["t", "lat", "lon", "accuracy_m"],
                          nullable=("accuracy_m",))
    waypoints = _waypoints(export, route, meta)
    if imu is None and gnss is None:
        raise CurbsideInputError(src, "export has neither a usable IMU (accelerometer+gyroscope+orientation) "
                                 "nor Location.csv")
    name = src.stem if src.is_file() else src.name
    return Session(name=name, imu=imu, gnss=gnss, waypoints=waypoints, meta=meta)
