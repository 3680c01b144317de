"""The phone platform of a Sensor Logger export, and with it the acceleration sign and the world frame.

``Metadata.csv`` names the platform and whether "Standardise Units & Frames" was on. An export
without it (users re-zip only the CSVs they think matter) is not taken for Android: the platform is
inferred from the data (:func:`settle_device`; the cues and their ranking are in ``docs/sessions.md``).
The magnetic-north measure lives here too: it is both a cue and the reader's frame check.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np
import pandas as pd
from scipy.spatial.transform import Rotation

from curbside.errors import CurbsideInputError
from curbside.localize.platforms import PLATFORM_OPTIONS
from curbside.localize.session import acceleration_unit

#: The reader's logger: these are its messages, filtered with it.
logger = logging.getLogger("curbside.localize.readers.sensorlogger")

#: Largest angle (deg) between magnetic north in the world frame and the frame's north still taken as
#: agreement: declination (up to ~20 deg in populated places) plus indoor disturbance.
NORTH_TOLERANCE_DEG = 35.0

_QUAT = ["qx", "qy", "qz", "qw"]
#: ``Orientation.csv`` columns, and their order in iOS 1.10 and 1.11 (Android: ``qz,qy,qx,qw,roll,...``).
_ORIENTATION_COLUMNS = frozenset({*_QUAT, "roll", "pitch", "yaw"})
_IOS_1_1X_ORIENTATION = ("yaw", "qx", "qz", "roll", "qw", "qy", "pitch")

#: The readings a cue can allow, ``{name: (platform, standardised)}``, in the order that breaks a tie
#: (Android first: its frames are the ones assumed without any cue).
_READINGS = {"android": ("android", False), "ios": ("ios", False), "standardised ios": ("ios", True)}
_FRAMES = {"android": "orientation in ENU", "ios": "orientation North-West-Up, turned into ENU",
           "standardised ios": "orientation North-West-Up, turned into ENU, then checked against "
                               "magnetic north"}
_OPTION_OF = {reading: option for option, reading in PLATFORM_OPTIONS.items()}


@dataclass
class Device:
    """What ``Metadata.csv`` says about the phone and the export; ``known`` is False when it names no
    platform, which is then inferred from the data (:func:`settle_device`)."""

    platform: str = "android"
    standardised: bool = False
    meta: dict = field(default_factory=dict)
    known: bool = True


def device_from_metadata(table: pd.DataFrame | None, label: str) -> Device:
    """The :class:`Device` that ``Metadata.csv`` (``None`` when absent) describes."""
    if table is None or table.empty or "platform" not in table.columns:
        return Device(known=False)
    row = table.iloc[0]
    columns = {"export_version": "version", "app_version": "appVersion", "device": "device name"}
    meta = {key: str(row[col]).strip() for key, col in columns.items()
            if col in table.columns and pd.notna(row[col])}
    platform = str(row["platform"]).strip().lower()
    if platform not in ("android", "ios"):
        logger.warning("%s: Metadata.csv platform %r unknown; inferred from the data", label, platform)
        return Device(meta=meta, known=False)
    standardised = str(row.get("standardisation", "false")).strip().lower() in ("true", "1", "yes")
    return Device(platform, standardised, {"platform": platform, "standardised": standardised, **meta})


def device_from_option(option: str, described: Device, label: str) -> Device:
    """The :class:`Device` the user named (``--platform``), in place of what ``Metadata.csv`` says.

    Parameters
    ----------
    option
        One of :data:`PLATFORM_OPTIONS`.
    described
        What ``Metadata.csv`` says (:func:`device_from_metadata`); its device and app fields are kept.
    label
        The export, for messages.

    Raises
    ------
    CurbsideInputError
        ``option`` is not one of :data:`PLATFORM_OPTIONS`.
    """
    if option not in PLATFORM_OPTIONS:
        raise CurbsideInputError("--platform", f"unknown platform {option!r} (one of "
                                 f"{', '.join(PLATFORM_OPTIONS)})")
    platform, standardised = _READINGS[PLATFORM_OPTIONS[option]]
    if described.known and _reading(described) != PLATFORM_OPTIONS[option]:
        logger.warning("%s: Metadata.csv says %s; read as %s (--platform)", label,
                       _OPTION_OF[_reading(described)], option)
    meta = {k: v for k, v in described.meta.items() if k not in ("platform", "standardised")}
    return Device(platform, standardised, {"platform": platform, "standardised": standardised,
                                           "platform_given": option, **meta})


def _named(reading: str) -> str:
    return reading.replace("ios", "iOS").replace("android", "Android")


def _reading(device: Device) -> str:
    return "standardised ios" if device.platform == "ios" and device.standardised else device.platform


def metadata_sign(device: Device) -> float:
    """Accelerometer sign that turns the export's convention into Android's, from the device alone."""
    return -1.0 if device.platform == "ios" and not device.standardised else 1.0


def magnetic_north_deg(imu: pd.DataFrame, magnetometer: pd.DataFrame) -> float | None:
    """Azimuth (deg, clockwise from the world frame's north) of the horizontal magnetic field.

    The field measured in the phone frame is rotated into the world frame by ``imu``'s quaternions and
    averaged as unit vectors. In a correct East-North-Up frame it points to magnetic north: the local
    declination (a few degrees in most places) plus magnetic disturbance.

    Parameters
    ----------
    imu
        ``t`` and ``qx,qy,qz,qw`` (device to ENU).
    magnetometer
        ``t,mx,my,mz`` in the phone frame (any unit).

    Returns
    -------
    float or None
        In (-180, 180]; ``None`` when the two do not overlap or the field is vertical.
    """
    t = imu["t"].to_numpy()
    mt = magnetometer["t"].to_numpy()
    keep = (t >= mt[0]) & (t <= mt[-1])
    if keep.sum() < 2:
        return None
    m = np.column_stack([np.interp(t[keep], mt, magnetometer[c].to_numpy()) for c in ("mx", "my", "mz")])
    world = Rotation.from_quat(imu.loc[keep, _QUAT].to_numpy()).apply(m)
    horizontal = np.linalg.norm(world[:, :2], axis=1)
    good = horizontal > 1e-6
    if not good.any():
        return None
    unit = world[good, :2] / horizontal[good, None]
    east, north = unit.mean(axis=0)
    return float(np.degrees(np.arctan2(east, north)))


def north_quarter(north: float) -> float | None:
    """The nearest multiple of 90 deg to an azimuth of north, when within the tolerance of it."""
    snapped = 90.0 * round(north / 90.0)
    return snapped if abs(north - snapped) < NORTH_TOLERANCE_DEG else None


def _uncalibrated_in_g(streams, export) -> bool:
    """Whether ``AccelerometerUncalibrated.csv`` logs in g (iOS without standardisation; Android: m/s^2)."""
    name = "AccelerometerUncalibrated.csv"
    try:
        table = streams[name] if name in streams else export.read(name)
    except CurbsideInputError:  # only a cue: a file the reader does not need must not stop it
        return False
    if table is None or not {"x", "y", "z"} <= set(table.columns):
        return False
    xyz = table[["x", "y", "z"]].apply(pd.to_numeric, errors="coerce").dropna().to_numpy()
    return len(xyz) > 0 and acceleration_unit(xyz)[0] == "g"


def _platform_cues(streams, export, frame: pd.DataFrame | None, sign: float | None,
                   mag: pd.DataFrame | None) -> list[tuple[tuple[str, ...], str]]:
    """What in the data shows the platform, strongest first: ``(the readings it allows, the evidence)``.

    ``frame``: ``t`` and the quaternions as exported (device to world, not turned); ``sign``: the
    accelerometer sign found against them (``None`` when not measured); ``mag``: the magnetometer.
    """
    cues = []
    if sign is not None and sign < 0:  # iOS without standardisation; Android never
        cues.append((("ios",), "acceleration in iOS's sign convention (gravity reads -9.8 m/s^2 up)"))
    elif sign is not None:
        cues.append((("android", "standardised ios"),
                     "acceleration in Android's sign convention (Android, or standardised iOS)"))
    if "TotalAcceleration.csv" in streams:
        cues.append((("android",), "TotalAcceleration.csv (iOS writes none)"))
    if _uncalibrated_in_g(streams, export):
        cues.append((("ios",), "AccelerometerUncalibrated.csv in g"))
    north = None if frame is None or mag is None else magnetic_north_deg(frame, mag)
    quarter = None if north is None else north_quarter(north)
    if quarter == 0:
        cues.append((("android",), f"magnetic north at {round(north):+d} deg in the orientation's frame "
                     "(East-North-Up)"))
    elif quarter == 90:  # an x-north frame read as East-North-Up shows north on its x axis: east
        cues.append((("ios", "standardised ios"), f"magnetic north at {round(north):+d} deg in the "
                     "orientation's frame (North-West-Up)"))
    orientation = streams.get("Orientation.csv", pd.DataFrame())
    columns = tuple(c for c in orientation.columns if c in _ORIENTATION_COLUMNS)
    if columns == _IOS_1_1X_ORIENTATION:  # 1.10-1.11 predate standardisation (1.29)
        cues.append((("ios",), f"Orientation.csv columns in iOS 1.10-1.11 order ({','.join(columns)})"))
    return cues


def settle_device(device: Device, streams, export, frame: pd.DataFrame | None, sign: float | None,
                  mag: pd.DataFrame | None, meta: dict) -> Device:
    """``device``, or when ``Metadata.csv`` names no platform the one the cues show (logged, in ``meta``).

    Each cue, strongest first, narrows the readings still possible unless it allows none of them (it
    is then "against"); a tie left at the end goes to the first of :data:`_READINGS`. Without any cue
    Android frames are assumed and ``meta`` records no platform.

    Parameters
    ----------
    device
        From :func:`device_from_metadata`.
    streams, export
        The export's tables and the export (for a raw accelerometer the reader skipped).
    frame
        ``t`` and the quaternions as exported; ``None`` without an orientation.
    sign
        The accelerometer sign measured against ``frame``; ``None`` when not measured.
    mag
        ``t,mx,my,mz``; ``None`` without a magnetometer (or an orientation).
    meta
        Updated in place with ``platform``, ``standardised`` and ``platform_inferred_from``.

    Returns
    -------
    Device
        Known from now on (settling twice infers once).
    """
    if device.known:
        return device
    cues = _platform_cues(streams, export, frame, sign, mag)
    if not cues:
        logger.warning("%s: no Metadata.csv platform, and no cue to it in the data; assuming Android frames "
                       "(an iOS export: give --platform ios or ios-standardised)", export.label)
        return Device()
    possible = set(_READINGS)
    for readings, _ in cues:
        if possible & set(readings):
            possible &= set(readings)
    reading = next(r for r in _READINGS if r in possible)
    agree = [why for readings, why in cues if reading in readings]
    against = [why for readings, why in cues if reading not in readings]
    others = [r for r in _READINGS if r in possible and r != reading]  # the data cannot tell these apart
    fits = f"; {' or '.join(_named(r) for r in others)} fits the data too (then give --platform " \
        f"{' or '.join(_OPTION_OF[r] for r in others)})" if others else ""
    logger.log(logging.INFO if len(agree) > 1 and not against and not others else logging.WARNING,
               "%s: no Metadata.csv platform; %s inferred (%s) from %s%s%s", export.label, _named(reading),
               _FRAMES[reading], "; ".join(agree), f"; against it: {'; '.join(against)}" if against else "",
               fits)
    platform, standardised = _READINGS[reading]
    meta.update(platform=platform, standardised=standardised, platform_inferred_from=agree)
    return Device(platform, standardised)
