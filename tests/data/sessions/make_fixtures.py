"""Regenerate the Sensor Logger fixture exports from the IPIN cut (run from the repo root).

Each export re-expresses 5 s of real walking from ``ipin2023-cut.h5`` in the exact layout of one
real Sensor Logger variant (file set, column names and order, clocks, sign conventions, world frame,
``Metadata.csv`` fields), as seen in the real exports listed in ``README.md``:

- ``sensorlogger-android/``: Android app 1.28 (format 3), TotalAcceleration + gravity-free
  Accelerometer, rotation vector in East-North-Up, messy Location (a duplicate, two swapped rows, a
  (0, 0) fix), two taps;
- ``sensorlogger-ios.zip``: iOS app 1.11 in a sub-folder, Accelerometer + Gravity with the iOS
  (opposite) sign, orientation in North-West-Up in the old iOS column order, a magnetometer, and the
  ``__MACOSX/._*`` debris that zips made on a Mac carry;
- ``sensorlogger-android-v2.zip``: format 2 (2021): ``time`` (ns) only, no ``seconds_elapsed``,
  v2 ``Metadata.csv`` and Location columns; the other phone (SM-G930F, trial 23);
- ``sensorlogger-android-1.12.zip``: app 1.12: no Orientation.csv, 1.12 Location columns, and the
  0-byte ``Annotation.csv`` the app writes when annotations are on but never tapped;
- ``sensorlogger-ios-standardised.zip``: iOS app 1.49 with "Standardise Units & Frames" on:
  Android signs, and (an assumption: the app's documentation does not say) the orientation already
  in East-North-Up, with a magnetometer that lets the reader tell.
"""

from __future__ import annotations

import zipfile
from pathlib import Path

import h5py
import numpy as np
import pandas as pd
from scipy.spatial.transform import Rotation

HERE = Path(__file__).parent
G = 9.80665
T0_NS = 1_700_000_000_000_000_000  # 2023-11-14, format 3 exports; seconds_elapsed = t_s - 60
T0_V2_NS = 1_610_478_700_000_000_000  # 2021-01-12, the format-2 export; time = T0_V2_NS + (t_s - 55) s
V2_T_S = (66.0, 71.0)  # the format-2 cut of trial 23 (walking, with 4 fixes)
#: Earth field in the world frame (East, North, Up), uT: northward and downward, like mid-latitudes.
FIELD_ENU = np.array([0.0, 22.0, -40.0])
NWU_FROM_ENU = Rotation.from_euler("z", -90.0, degrees=True)
LOCATION_1_28 = ["bearingAccuracy", "speedAccuracy", "verticalAccuracy", "horizontalAccuracy", "speed",
                 "bearing", "altitude", "longitude", "latitude"]


def cut(trial: str, a: float, b: float) -> dict[str, np.ndarray]:
    with h5py.File(HERE / "ipin2023-cut.h5") as f:
        g = f[trial]
        raw = {k: g[k][:].astype(float) for k in ("acce", "gyro", "rotvec", "gnss")}
    return {k: v[(v[:, 0] >= a) & (v[:, 0] <= b)] for k, v in raw.items()}


def clock(t: np.ndarray, v2: bool = False) -> pd.DataFrame:
    t = np.round(t, 4)  # the logged decimals (the HDF5 holds float32: 66.0098 reads 66.00980377)
    if v2:
        return pd.DataFrame({"time": T0_V2_NS + np.round((t - 55.0) * 1e9).astype(np.int64)})
    return pd.DataFrame({"time": T0_NS + np.round((t - 60.0) * 1e9).astype(np.int64),
                         "seconds_elapsed": np.round(t - 60.0, 4)})


def table(t: np.ndarray, v2: bool = False, **cols: np.ndarray) -> pd.DataFrame:
    out = clock(t, v2)
    for k, v in cols.items():
        out[k] = np.round(v, 7)
    return out


def zyx(t: np.ndarray, xyz: np.ndarray, v2: bool = False) -> pd.DataFrame:
    """The per-axis layout every version uses: ``z,y,x`` after the clock columns."""
    return table(t, v2, z=xyz[:, 2], y=xyz[:, 1], x=xyz[:, 0])


def physics(d: dict[str, np.ndarray]) -> dict:
    """Attitude, gravity-free acceleration, gravity and magnetic field on the accelerometer clock."""
    acce, rotvec = d["acce"], d["rotvec"]
    rot = Rotation.from_quat(rotvec[:, 1:5])  # device to East-North-Up
    q_at_acce = Rotation.from_quat(
        np.column_stack([np.interp(acce[:, 0], rotvec[:, 0], rotvec[:, k]) for k in range(1, 5)])
    )
    gravity = q_at_acce.inv().apply([0.0, 0.0, G])
    return {"rot": rot, "gravity": gravity, "user": acce[:, 1:4] - gravity,
            "field": q_at_acce.inv().apply(FIELD_ENU)}


def android_euler(rot: Rotation) -> dict[str, np.ndarray]:
    """roll, pitch, yaw columns for realism (the reader ignores them): yaw = azimuth of the device y."""
    y = rot.apply([0.0, 1.0, 0.0])
    z = rot.apply([0.0, 0.0, 1.0])
    return {"roll": np.arcsin(np.clip(-z[:, 0], -1, 1)), "pitch": np.arcsin(np.clip(-y[:, 2], -1, 1)),
            "yaw": np.arctan2(y[:, 0], y[:, 1])}


def location(gnss: np.ndarray, columns: list[str], v2: bool = False) -> pd.DataFrame:
    values = {"horizontalAccuracy": gnss[:, 5], "altitude": gnss[:, 3], "longitude": gnss[:, 2],
              "latitude": gnss[:, 1], "speed": np.full(len(gnss), 1.2), "bearing": np.full(len(gnss), 95.0)}
    out = clock(gnss[:, 0], v2)
    for col in columns:
        out[col] = np.round(values.get(col, np.full(len(gnss), 1.5)), 8)
    return out


def taps(v2: bool = False) -> pd.DataFrame:
    out = clock(np.array([68.05, 69.0]), v2)
    out["text"] = ["49.4612756,11.11098835", "corner"]
    out["millisecond_press_duration"] = [120, 90]
    return out


def write_zip(path: Path, files: dict[str, pd.DataFrame | bytes], folder: str = "") -> None:
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as zf:
        for name, content in files.items():
            data = content if isinstance(content, bytes) else content.to_csv(index=False).encode()
            zf.writestr(f"{folder}{name}", data)


def android_1_28(d: dict, p: dict) -> None:
    out = HERE / "sensorlogger-android"
    out.mkdir(exist_ok=True)
    acce, gyro, rotvec, gnss = d["acce"], d["gyro"], d["rotvec"], d["gnss"]
    q = p["rot"].as_quat()
    files = {
        "TotalAcceleration.csv": zyx(acce[:, 0], acce[:, 1:4]),
        "Accelerometer.csv": zyx(acce[:, 0], p["user"]),
        "Gyroscope.csv": zyx(gyro[:, 0], gyro[:, 1:4]),
        "Orientation.csv": table(rotvec[:, 0], qz=q[:, 2], qy=q[:, 1], qx=q[:, 0], qw=q[:, 3],
                                 **android_euler(p["rot"])),
        "Annotation.csv": taps(),
        "Metadata.csv": pd.DataFrame({
            "version": [3], "device name": ["SM-A520F"], "recording epoch time": [T0_NS // 1_000_000],
            "recording time": ["2023-11-14_22-13-20"], "recording timezone": ["Europe/Berlin"],
            "platform": ["android"], "appVersion": ["1.28"], "device id": ["fixture"],
            "sensors": ["Accelerometer|Gyroscope|Orientation|Location|Annotation|TotalAcceleration"],
            "sampleRateMs": ["10|10|10|0||10"]}),
    }
    for name, frame in files.items():
        frame.to_csv(out / name, index=False)
    loc = location(gnss, LOCATION_1_28)
    # Real logs repeat a fix, swap two, and start with a (0, 0) fix before the first position.
    first = loc.iloc[[0]].assign(latitude=0.0, longitude=0.0, time=loc["time"].iat[0] - 400_000_000,
                                 seconds_elapsed=loc["seconds_elapsed"].iat[0] - 0.4)
    messy = pd.concat([first, loc, loc.iloc[[3]]]).iloc[[0, 1, 3, 2, *range(4, len(loc) + 2)]]
    messy.to_csv(out / "Location.csv", index=False)


def ios_1_11(d: dict, p: dict) -> None:
    acce, gyro, rotvec, gnss = d["acce"], d["gyro"], d["rotvec"], d["gnss"]
    nwu = NWU_FROM_ENU * p["rot"]
    q = nwu.as_quat()
    ypr = nwu.as_euler("ZYX")
    folder = "2023-11-14_22-13-20/"
    files = {
        "Accelerometer.csv": zyx(acce[:, 0], -p["user"]),
        "Gravity.csv": zyx(acce[:, 0], -p["gravity"]),
        "Gyroscope.csv": zyx(gyro[:, 0], gyro[:, 1:4]),
        "Orientation.csv": table(rotvec[:, 0], yaw=ypr[:, 0], qx=q[:, 0], qz=q[:, 2], roll=ypr[:, 2],
                                 qw=q[:, 3], qy=q[:, 1], pitch=ypr[:, 1]),
        "Magnetometer.csv": zyx(acce[:, 0], p["field"]),
        "Location.csv": location(gnss, LOCATION_1_28),
        "Annotation.csv": taps(),
        "Metadata.csv": pd.DataFrame({
            "version": [3], "device name": ["iPhone 13"], "recording time": ["2023-11-14_22-13-20"],
            "platform": ["ios"], "appVersion": ["1.11"], "device id": ["fixture"],
            "sensors": ["Accelerometer|Gravity|Gyroscope|Orientation|Magnetometer|Location|Annotation"],
            "sampleRateMs": ["10|10|10|10|10|0|"]}),
    }
    write_zip(HERE / "sensorlogger-ios.zip", files, folder)
    with zipfile.ZipFile(HERE / "sensorlogger-ios.zip", "a") as zf:  # AppleDouble debris of Mac zips
        zf.writestr(f"__MACOSX/{folder}._Accelerometer.csv", b"\x00\x05\x16\x07\x00\x02\x00\x00Mac OS X")


def android_v2(d: dict, p: dict) -> None:
    acce, gyro, rotvec, gnss = d["acce"], d["gyro"], d["rotvec"], d["gnss"]
    q = p["rot"].as_quat()
    eul = android_euler(p["rot"])
    files = {
        "Accelerometer.csv": zyx(acce[:, 0], p["user"], v2=True),
        "Gravity.csv": zyx(acce[:, 0], p["gravity"], v2=True),
        "Gyroscope.csv": zyx(gyro[:, 0], gyro[:, 1:4], v2=True),
        "Orientation.csv": table(rotvec[:, 0], v2=True, qz=q[:, 2], qy=q[:, 1], qx=q[:, 0], qw=q[:, 3],
                                 roll=eul["roll"], pitch=eul["pitch"], yaw=eul["yaw"]),
        "Location.csv": location(gnss, LOCATION_1_28, v2=True),
        "Metadata.csv": pd.DataFrame({"version": [2], "device name": ["SM-G930F"],
                                      "recording time": ["2021-00-12_21-11-40"], "platform": ["android"]}),
    }
    write_zip(HERE / "sensorlogger-android-v2.zip", files)


def android_1_12(d: dict, p: dict) -> None:
    acce, gyro, gnss = d["acce"], d["gyro"], d["gnss"]
    files = {
        "TotalAcceleration.csv": zyx(acce[:, 0], acce[:, 1:4]),
        "Gyroscope.csv": zyx(gyro[:, 0], gyro[:, 1:4]),
        "Location.csv": location(gnss, ["horizontalAccuracy", "speed", "bearing", "altitude", "longitude",
                                        "latitude"]),
        "Annotation.csv": b"",
        "Metadata.csv": pd.DataFrame({
            "version": [3], "device name": ["SM-A520F"], "recording time": ["2023-11-14_22-13-20"],
            "platform": ["android"], "appVersion": ["1.12.0"], "device id": ["fixture"],
            "sensors": ["Gyroscope|Location|Annotation|TotalAcceleration"], "sampleRateMs": ["20|0||20"]}),
    }
    write_zip(HERE / "sensorlogger-android-1.12.zip", files)


def ios_standardised(d: dict, p: dict) -> None:
    acce, gyro, rotvec, gnss = d["acce"], d["gyro"], d["rotvec"], d["gnss"]
    q = p["rot"].as_quat()
    files = {
        "Accelerometer.csv": zyx(acce[:, 0], p["user"]),
        "Gravity.csv": zyx(acce[:, 0], p["gravity"]),
        "Gyroscope.csv": zyx(gyro[:, 0], gyro[:, 1:4]),
        "Orientation.csv": table(rotvec[:, 0], qz=q[:, 2], qy=q[:, 1], qx=q[:, 0], qw=q[:, 3]),
        "Magnetometer.csv": zyx(acce[:, 0], p["field"]),
        "Location.csv": location(gnss, LOCATION_1_28),
        "Metadata.csv": pd.DataFrame({
            "version": [3], "device name": ["iPhone 12 Pro Max"], "recording epoch time": [T0_NS // 10**6],
            "recording time": ["2023-11-14_22-13-20"], "recording timezone": ["Europe/Vienna"],
            "platform": ["ios"], "appVersion": ["1.49"], "device id": ["fixture"],
            "sensors": ["Accelerometer|Gravity|Gyroscope|Orientation|Magnetometer|Location"],
            "sampleRateMs": ["10|10|10|10|10|0"], "standardisation": ["true"]}),
    }
    write_zip(HERE / "sensorlogger-ios-standardised.zip", files, "2023-11-14_22-13-20/")


def main() -> None:
    trial01 = cut("IPIN2023_T3_TrainingTrial01_repetition01", 62.0, 67.0)
    trial23 = cut("IPIN2023_T3_TrainingTrial23_repetition03", *V2_T_S)
    p01, p23 = physics(trial01), physics(trial23)
    android_1_28(trial01, p01)
    ios_1_11(trial01, p01)
    android_v2(trial23, p23)
    android_1_12(trial01, p01)
    ios_standardised(trial01, p01)


if __name__ == "__main__":
    main()
