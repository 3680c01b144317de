"""Writing a track: ``track.csv``, ``track.geojson``, ``run.json`` and optional ``particles.npz``.

Everything goes into one output folder, written atomically: the folder is assembled under a temporary
name and renamed into place only when every file is complete.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from curbside import __version__
from curbside.io import json_ready, output_folder
from curbside.localize.particle_store import write_particles
from curbside.localize.track_result import TrackResult

#: Decimal places of lon/lat in ``track.geojson`` (1e-7 degree is about 1 cm).
COORD_DECIMALS = 7


def track_geojson(track: pd.DataFrame, properties: dict[str, Any] | None = None) -> dict[str, Any]:
    """The track as a GeoJSON FeatureCollection: a LineString (two rows or more), then a Point per row.

    Parameters
    ----------
    track
        Rows with ``t, lat, lon`` and any other columns (they become Point properties).
    properties
        Properties of the LineString feature (mode, seed...).

    Returns
    -------
    dict
        RFC 7946 GeoJSON (WGS84 lon/lat).
    """
    lon = np.round(track["lon"].to_numpy(float), COORD_DECIMALS)
    lat = np.round(track["lat"].to_numpy(float), COORD_DECIMALS)
    coords = np.column_stack([lon, lat]).tolist()
    features: list[dict[str, Any]] = []
    if len(coords) >= 2:  # RFC 7946: a LineString has two or more positions
        features.append(
            {
                "type": "Feature",
                "properties": {"kind": "track", **(properties or {})},
                "geometry": {"type": "LineString", "coordinates": coords},
            }
        )
    columns = [c for c in track.columns if c not in ("lat", "lon")]
    records = track[columns].to_dict(orient="records")
    for point, record in zip(coords, records, strict=True):
        features.append(
            {
                "type": "Feature",
                "properties": {"kind": "footstep", **json_ready(record)},
                "geometry": {"type": "Point", "coordinates": point},
            }
        )
    return {"type": "FeatureCollection", "features": features}


def write_track(
    result: TrackResult, out_dir: str | Path, run_info: dict[str, Any] | None = None, *,
    overwrite: bool = False,
) -> Path:
    """Write a :class:`TrackResult` into ``out_dir`` atomically, under the output-folder rules of
    :func:`curbside.io.output_folder` (a new, empty or previous curbside folder; files curbside did not
    write are never touched).

    Files: ``track.csv`` (one row per update), ``track.geojson``, ``run.json`` and, when the result holds
    snapshots, ``particles.npz`` (the cloud at each update, packed: :mod:`curbside.localize.particle_store`).
    ``run.json`` holds ``run_info`` (the session and map paths...), what the run used and
    produced, and the whole run configuration under ``config``: ``localize run --config run.json``
    replays the run from it.

    Parameters
    ----------
    result
        The output of :func:`curbside.localize.pipeline.track_session`.
    out_dir
        Destination folder.
    run_info
        Inputs to record in ``run.json`` (``session``, ``map``...).
    overwrite
        Also write into a non-empty folder curbside did not write (its other files are kept).

    Returns
    -------
    pathlib.Path
        ``out_dir``.
    """
    out_dir = Path(out_dir)
    # What the run measured has no NaN (a figure that does not exist is null); the config is written as
    # it is, so that a parameter set to inf (a disabled gate) replays as inf.
    info = json_ready({
        "generator": f"curbside {__version__}",
        **(run_info or {}),
        "mode": result.mode,
        "velocity_source": result.velocity_source,
        "step_source": result.step_source,
        "rows": len(result.track),
        "recoveries": result.recoveries,
        "injections": result.injections,
        "heading_corrections": result.heading_corrections,
        "calibration": result.calibration,
        "unseen_velocity_from_s": result.unseen_velocity_from_s,
        "familiar_velocity": result.familiar_velocity,
        "fix_lag": result.fix_lag,
        "ronin_familiarity": result.ronin_familiarity,
        "wall_tolerance_m": result.wall_tolerance_m,
        "walkable_first": result.walkable_first,
    }) | {"config": result.config.to_dict()}
    with output_folder(out_dir, "localize run", overwrite=overwrite) as tmp:
        result.track.to_csv(tmp / "track.csv", index=False, float_format="%.10g")
        doc = track_geojson(result.track, {"mode": result.mode})
        (tmp / "track.geojson").write_text(json.dumps(doc, separators=(",", ":")), encoding="utf-8")
        (tmp / "run.json").write_text(json.dumps(info, indent=2), encoding="utf-8")
        if result.snapshots is not None:
            write_particles(result.snapshots, tmp / "particles.npz")
    return out_dir
