"""Regenerate the Sensor Logger fixture exports from the IPIN cut (run from the repo root).

The exports re-express 5 s of real walking (IPIN 2023 TrainingTrial01_repetition01, t_s 62-67 s) in
Sensor Logger's documented conventions (see docs/sessions.md): Android with TotalAcceleration, and
iOS with gravity-free Accelerometer + Gravity in the opposite sign and the orientation in the
x-north/y-west/z-up frame. ``seconds_elapsed = t_s - 60``.
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
T0_NS = 1_700_000_000_000_000_000
A, B = 62.0, 67.0


def frame(t: np.ndarray, **cols: np.ndarray) -> pd.DataFrame:
    out = pd.DataFrame({"time": (T0_NS + np.round((t - 60.0) * 1e9)).astype(np.int64),
                        "seconds_elapsed": np.round(t - 60.0, 4)})
    for k, v in cols.items():
        out[k] = np.round(v, 6)
    return out


def main() -> None:
    with h5py.File(HERE / "ipin2023-cut.h5") as f:
        g = f["IPIN2023_T3_TrainingTrial01_repetition01"]
        acce, gyro, rotvec, gnss = (g[k][:].astype(float) for k in ("acce", "gyro", "rotvec", "gnss"))
    acce, gyro = (x[(x[:, 0] >= A) & (x[:, 0] <= B)] for x in (acce, gyro))
    rotvec, gnss = (x[(x[:, 0] >= A) & (x[:, 0] <= B)] for x in (rotvec, gnss))
    rot = Rotation.from_quat(rotvec[:, 1:5])
    q_at_acce = Rotation.from_quat(
        np.column_stack([np.interp(acce[:, 0], rotvec[:, 0], rotvec[:, k]) for k in range(1, 5)])
    )
    gravity = q_at_acce.inv().apply([0.0, 0.0, G])
    user = acce[:, 1:4] - gravity
    t_a, t_g, t_q = acce[:, 0], gyro[:, 0], rotvec[:, 0]
    gyro_df = frame(t_g, z=gyro[:, 3], y=gyro[:, 2], x=gyro[:, 1])
    location = frame(gnss[:, 0], horizontalAccuracy=gnss[:, 5], altitude=gnss[:, 3],
                     longitude=gnss[:, 2], latitude=gnss[:, 1])
    taps = pd.DataFrame({
        "time": [T0_NS + 8_050_000_000, T0_NS + 9_000_000_000], "seconds_elapsed": [8.05, 9.0],
        "text": ["49.4612756,11.11098835", "corner"], "millisecond_press_duration": [120, 90],
    })

    android = HERE / "sensorlogger-android"
    android.mkdir(exist_ok=True)
    q = rot.as_quat()
    tables = {
        "TotalAcceleration.csv": frame(t_a, z=acce[:, 3], y=acce[:, 2], x=acce[:, 1]),
        "Accelerometer.csv": frame(t_a, z=user[:, 2], y=user[:, 1], x=user[:, 0]),
        "Gyroscope.csv": gyro_df,
        "Orientation.csv": frame(t_q, qz=q[:, 2], qy=q[:, 1], qx=q[:, 0], qw=q[:, 3]),
    }
    for name, table in tables.items():
        table.to_csv(android / name, index=False)
    # A duplicated fix and two swapped rows, as real logs have: the reader must repair and count them.
    messy = pd.concat([location, location.iloc[[3]]]).iloc[[0, 2, 1, *range(3, len(location) + 1)]]
    messy.to_csv(android / "Location.csv", index=False)
    taps.to_csv(android / "Annotation.csv", index=False)
    pd.DataFrame({"version": [3], "device name": ["SM-A520F"], "platform": ["android"]}).to_csv(
        android / "Metadata.csv", index=False)

    q_nwu = (Rotation.from_euler("z", -90.0, degrees=True) * rot).as_quat()
    files = {
        "Accelerometer.csv": frame(t_a, z=-user[:, 2], y=-user[:, 1], x=-user[:, 0]),
        "Gravity.csv": frame(t_a, z=-gravity[:, 2], y=-gravity[:, 1], x=-gravity[:, 0]),
        "Gyroscope.csv": gyro_df,
        "Orientation.csv": frame(t_q, qz=q_nwu[:, 2], qy=q_nwu[:, 1], qx=q_nwu[:, 0], qw=q_nwu[:, 3]),
        "Location.csv": location,
        "Annotation.csv": taps,
        "Metadata.csv": pd.DataFrame({"version": [3], "device name": ["iPhone"], "platform": ["ios"]}),
    }
    with zipfile.ZipFile(HERE / "sensorlogger-ios.zip", "w", zipfile.ZIP_DEFLATED) as zf:
        for name, table in files.items():
            zf.writestr(f"walk-2023-06-14/{name}", table.to_csv(index=False))


if __name__ == "__main__":
    main()
