"""A small tracked walk for the viewer tests: the crossroads map, a session, and run folders.

The walker goes east along the north sidewalks of the crossroads fixture (``tests/data/maps``), across
the north crosswalk, for about 80 s; GNSS is biased 6 m south with 2 m noise. The runs are tracked
by ``localize run --save-particles`` at N = 100, which writes each particle filter run's ``particles.npz``
itself (:mod:`curbside.localize.particle_store`).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pyproj

from curbside.cli.localize import main as localize_main
from curbside.projection import LocalFrame

FRAME = LocalFrame(pyproj.CRS(32610))
#: The crossroads map fixture.
CROSSROADS = Path(__file__).resolve().parent / "data" / "maps" / "crossroads.geojson"
#: Start and end of the walk, UTM 10N metres (on sidewalk s4, then s0 east of the crossing).
START_XY = (552995.0, 4182750.5)
END_XY = (553100.0, 4182750.5)
SPEED_MPS = 1.3


def write_session(folder: Path, seed: int = 0) -> Path:
    """Write the walk as a SPEC session folder."""
    rng = np.random.default_rng(seed)
    folder.mkdir(parents=True)
    duration_s = (END_XY[0] - START_XY[0]) / SPEED_MPS
    steps = np.arange(0.0, duration_s, 0.55)
    pd.DataFrame({"t": steps}).to_csv(folder / "steps.csv", index=False)
    tv = np.arange(0.0, duration_s, 0.1)
    pd.DataFrame(
        {"t": tv, "ve": SPEED_MPS + rng.normal(0, 0.05, len(tv)), "vn": rng.normal(0, 0.05, len(tv))}
    ).to_csv(folder / "velocity.csv", index=False)
    tg = np.arange(0.0, duration_s, 1.0)
    lon, lat = FRAME.to_lonlat(
        START_XY[0] + SPEED_MPS * tg + rng.normal(0, 2, len(tg)), START_XY[1] - 6 + rng.normal(0, 2, len(tg))
    )
    pd.DataFrame({"t": tg, "lat": lat, "lon": lon, "accuracy_m": np.full(len(tg), 8.0)}).to_csv(
        folder / "gnss.csv", index=False
    )
    tw = np.linspace(0.0, duration_s, 4)
    wlon, wlat = FRAME.to_lonlat(START_XY[0] + SPEED_MPS * tw, np.full(4, START_XY[1]))
    pd.DataFrame({"t": tw, "lat": wlat, "lon": wlon}).to_csv(folder / "waypoints.csv", index=False)
    slon, slat = FRAME.to_lonlat(*START_XY)
    meta = {"start": {"lat": float(slat), "lon": float(slon), "heading_deg": 90.0, "t": 0.0}}
    (folder / "meta.json").write_text(json.dumps(meta))
    return folder


def write_runs(root: Path, map_path: Path, modes: tuple[str, ...] = ("gnss", "fused")) -> list[Path]:
    """Track the walk in each mode into ``root/MODE`` with ``localize run --save-particles``."""
    session_dir = write_session(root / "walk")
    folders = []
    for mode in modes:
        out = root / mode
        args = ["run", str(session_dir), "--map", str(map_path), "--mode", mode, "--particles", "100",
                "--save-particles", "-o", str(out)]
        assert localize_main(args) == 0
        folders.append(out)
    return folders
