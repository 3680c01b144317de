"""The replay viewer: one offline HTML page that steps through one or more tracked walks.

``localize view RUN [RUN ...] -o view.html`` reads run folders written by ``localize run -o RUN`` and
draws, over the map layers of the runs' map: each run's estimate track, its particle cloud at every
footstep (``particles.npz``, from ``--save-particles``), the session's GNSS fixes with their accuracy
circles and the ground truth when the session has waypoints. A time slider with play/pause steps
through the walk; a panel shows, for each run, the sidewalk segment and its probability, the error
against the ground truth, the effective sample size and the recoveries so far.

The page is self-contained: the vendored Leaflet and the data are inlined (see
:mod:`curbside.osmseg.webmap`). Particle clouds travel as base64 int16 offsets from each footstep's
estimate in micro-degrees (exact lon/lat to 0.1 m, ±3.6 km), which keeps a 10-minute walk at N = 500
at about 3 MB per run.
"""

from __future__ import annotations

import base64
import html
import json
import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd
import pyproj

from curbside.errors import CurbsideInputError
from curbside.evaluate.groundtruth import groundtruth_at
from curbside.evaluate.metrics import format_waypoint_summary, waypoint_errors, waypoint_summary
from curbside.io import atomic_path
from curbside.localize.particle_store import ParticleClouds, read_particles
from curbside.localize.session import Session
from curbside.osmseg.mapio import MapLayers, read_map
from curbside.osmseg.plot import clip_to_bbox
from curbside.osmseg.webmap import (
    asset_text,
    attribution,
    bounds_js,
    class_features,
    class_overlay_js,
    leaflet_page,
    script_json,
)
from curbside.projection import WGS84, LocalFrame

log = logging.getLogger(__name__)

#: Track colour of each method (the report's figures use the same).
METHOD_COLOURS: dict[str, str] = {
    "gnss": "#d62728", "inertial": "#2ca02c", "fused": "#9467bd", "paper": "#ff7f0e"
}
#: Colours of further runs, in turn.
EXTRA_COLOURS: tuple[str, ...] = ("#1f77b4", "#8c564b", "#e377c2", "#17becf", "#bcbd22", "#7f7f7f")
#: Degrees per unit of the particle offsets sent to the page.
PAGE_OFFSET_UNIT_DEG = 1e-6
#: Metres of map kept around the tracks and the ground truth.
MAP_MARGIN_M = 80.0
#: Pages larger than this (MB) get a warning: they take seconds to open.
LARGE_PAGE_MB = 20.0
#: Clouds of more particles are drawn thinned to about this many (every k-th particle): the page
#: stays the size it had at the paper's N = 500, and a cloud of 500 dots shows its shape as well.
MAX_DRAWN_PARTICLES = 500


@dataclass
class ViewRun:
    """One tracked walk, as the viewer shows it.

    Attributes
    ----------
    label
        Name in the legend and the panel.
    track
        ``t, lat, lon`` per footstep and, when known, ``n_eff``, ``recovered``, ``sidewalk_segment_id``,
        ``segment_prob``.
    session
        The recording (GNSS fixes, waypoints), or ``None``.
    session_key
        Identifies the session: runs with the same key share its GNSS and ground-truth layers.
    mode
        ``gnss``, ``inertial``, ``fused``... (picks the colour).
    particles
        The particle clouds, or ``None``.
    map_path
        The map the run was tracked on, or ``None``.
    recoveries
        Collapses of the particle cloud over the whole run.
    """

    label: str
    track: pd.DataFrame
    session: Session | None = None
    session_key: str = ""
    mode: str = ""
    particles: ParticleClouds | None = None
    map_path: str | None = None
    recoveries: int = 0


def load_run(
    folder: str | Path, session: str | Path | None = None, map_path: str | Path | None = None
) -> ViewRun:
    """Read a run folder written by ``localize run -o FOLDER``.

    Parameters
    ----------
    folder
        Holds ``track.csv`` and ``run.json`` (and ``particles.npz`` with ``--save-particles``).
    session
        The session to show instead of ``run.json``'s (which names it by path; runs move).
    map_path
        The map instead of ``run.json``'s.

    Returns
    -------
    ViewRun
        Labelled by mode; :func:`label_runs` makes the labels of several runs distinct.

    Raises
    ------
    CurbsideInputError
        Not a run folder, a track without ``t, lat, lon``, a session or map that cannot be read.
    """
    from curbside.localize.readers import read_any

    folder = Path(folder)
    track_csv, run_json = folder / "track.csv", folder / "run.json"
    if not folder.exists():
        raise CurbsideInputError(folder, "no such run folder")
    if not track_csv.is_file():
        raise CurbsideInputError(folder, "not a run folder (no track.csv; write one with `localize run -o`)")
    try:
        info = json.loads(run_json.read_text(encoding="utf-8")) if run_json.is_file() else {}
        track = pd.read_csv(track_csv)
    except (OSError, ValueError) as exc:
        raise CurbsideInputError(folder, f"unreadable run ({exc})") from None
    missing = [c for c in ("t", "lat", "lon") if c not in track]
    if missing or not len(track):
        raise CurbsideInputError(track_csv, f"no footsteps with t, lat, lon (missing {missing})")
    session_src = session or info.get("session")
    loaded = None
    if session_src:
        try:
            loaded = read_any(session_src)
        except CurbsideInputError as exc:
            hint = "" if session else " (pass --session if the session moved)"
            raise CurbsideInputError(exc.source, f"{exc.problem}{hint}") from None
    particles = read_particles(folder / "particles.npz") if (folder / "particles.npz").is_file() else None
    return ViewRun(
        label=str(info.get("mode") or folder.name),
        track=track,
        session=loaded,
        session_key=str(Path(session_src).resolve()) if session_src else "",
        mode=str(info.get("mode") or ""),
        particles=particles,
        map_path=str(map_path or info.get("map") or "") or None,
        recoveries=int(info.get("recoveries") or 0),
    )


def label_runs(runs: list[ViewRun], names: list[str] | None = None) -> list[ViewRun]:
    """Give every run a distinct label: the mode, then the map's name, then a number.

    Parameters
    ----------
    runs
        The runs.
    names
        Labels to use instead (one per run).
    """
    if names is not None:
        if len(names) != len(runs):
            raise CurbsideInputError("--labels", f"give one label per run ({len(runs)}), got {len(names)}")
        for run, name in zip(runs, names, strict=True):
            run.label = name
        return runs
    maps = {r.map_path for r in runs}
    for run in runs:
        if len(maps) > 1:
            run.label = f"{run.label} · {Path(run.map_path).stem if run.map_path else 'no map'}"
    seen: dict[str, int] = {}
    for run in runs:
        seen[run.label] = seen.get(run.label, 0) + 1
        if seen[run.label] > 1:
            run.label = f"{run.label} ({seen[run.label]})"
    return runs


def _colour(run: ViewRun, used: set[str]) -> str:
    colour = METHOD_COLOURS.get(run.mode)
    if colour is None or colour in used:
        spare = [c for c in EXTRA_COLOURS if c not in used]
        colour = spare[0] if spare else EXTRA_COLOURS[len(used) % len(EXTRA_COLOURS)]
    used.add(colour)
    return colour


def _round(values: np.ndarray, decimals: int) -> list:
    values = np.round(np.asarray(values, float), decimals)
    return [None if not np.isfinite(v) else float(v) for v in values]


def _b64(values: np.ndarray, dtype: str) -> str:
    return base64.b64encode(np.ascontiguousarray(values, dtype=dtype).tobytes()).decode("ascii")


def _cloud_data(clouds: ParticleClouds, every: int = 1) -> dict:
    """Every ``every``-th cloud as base64 little-endian int16 micro-degree offsets from its mean, each
    thinned to every k-th particle when it has more than :data:`MAX_DRAWN_PARTICLES`."""
    to_wgs84 = pyproj.Transformer.from_crs(pyproj.CRS(clouds.crs), WGS84, always_xy=True)
    stride = -(-clouds.n_particles // MAX_DRAWN_PARTICLES)
    drawn = (slice(None, None, every), slice(None, None, stride))
    lon, lat = to_wgs84.transform(clouds.x[drawn], clouds.y[drawn])
    ref_lon, ref_lat = np.mean(lon, axis=1), np.mean(lat, axis=1)
    limit = np.iinfo(np.int16).max
    dlon = np.rint((lon - ref_lon[:, None]) / PAGE_OFFSET_UNIT_DEG)
    dlat = np.rint((lat - ref_lat[:, None]) / PAGE_OFFSET_UNIT_DEG)
    far = int(np.count_nonzero((np.abs(dlon) > limit) | (np.abs(dlat) > limit)))
    if far:
        log.warning("%d particle(s) more than 3 km from their cloud's mean are drawn at the edge", far)
    out = {
        "t": _round(clouds.t[::every], 3),
        "n": lon.shape[1],
        "n_total": clouds.n_particles,
        "ref_lat": _round(ref_lat, 7),
        "ref_lon": _round(ref_lon, 7),
        "dlat": _b64(np.clip(dlat, -limit, limit), "<i2"),
        "dlon": _b64(np.clip(dlon, -limit, limit), "<i2"),
    }
    if clouds.weight is not None:
        weight = clouds.weight[drawn]
        peak = np.maximum(weight.max(axis=1, keepdims=True), 1e-300)
        out["alpha"] = _b64(np.rint(255 * weight / peak), "u1")
    return out


def _truth_errors(run: ViewRun) -> tuple[list | None, str | None]:
    """Error against the ground truth at each footstep, and the waypoint-error summary line."""
    waypoints = run.session.waypoints if run.session is not None else None
    if waypoints is None or len(waypoints) < 2:
        return None, None
    track = run.track
    frame = LocalFrame.around(float(waypoints["lon"].iat[0]), float(waypoints["lat"].iat[0]))
    t = track["t"].to_numpy(float)
    gx, gy = groundtruth_at(waypoints, t, frame)
    ex, ey = frame.to_xy(track["lon"].to_numpy(float), track["lat"].to_numpy(float))
    errors = _round(np.hypot(ex - gx, ey - gy), 2)
    try:
        summary = format_waypoint_summary(waypoint_summary(waypoint_errors(track, waypoints)))
    except CurbsideInputError:
        summary = None
    return errors, summary


def _run_data(run: ViewRun, colour: str, cloud_every: int = 1) -> dict:
    track = run.track
    errors, summary = _truth_errors(run)
    recovered = np.zeros(len(track), int)
    if "recovered" in track:
        recovered = track["recovered"].fillna(0).to_numpy(int)
    segments = None
    if "sidewalk_segment_id" in track:
        ids = track["sidewalk_segment_id"].astype(object)
        segments = ids.where(ids.notna(), None).tolist()
    return {
        "label": run.label,
        "colour": colour,
        "session": run.session_key,
        "t": _round(track["t"], 3),
        "lat": _round(track["lat"], 7),
        "lon": _round(track["lon"], 7),
        "n_eff": _round(track["n_eff"], 1) if "n_eff" in track else None,
        "recoveries_so_far": np.cumsum(recovered > 0).tolist(),
        "recoveries": int(max(run.recoveries, int((recovered > 0).sum()))),
        "segment": segments,
        "segment_prob": _round(track["segment_prob"], 3) if "segment_prob" in track else None,
        "accuracy_m": _round(track["accuracy_m"], 1) if "accuracy_m" in track else None,
        "error_m": errors,
        "waypoint_summary": summary,
        "cloud": _cloud_data(run.particles, cloud_every) if run.particles is not None else None,
    }


def _session_data(session: Session, key: str) -> dict:
    data: dict = {"key": key, "name": session.name, "gnss": None, "truth": None}
    if session.gnss is not None and len(session.gnss):
        g = session.gnss
        acc = g["accuracy_m"].to_numpy(float)
        valid = np.isfinite(acc) & (acc > 0)
        data["gnss"] = {
            "t": _round(g["t"][valid], 3),
            "lat": _round(g["lat"][valid], 7),
            "lon": _round(g["lon"][valid], 7),
            "acc": _round(acc[valid], 1),
        }
    if session.waypoints is not None and len(session.waypoints) >= 2:
        w = session.waypoints
        data["truth"] = {"t": _round(w["t"], 3), "lat": _round(w["lat"], 7), "lon": _round(w["lon"], 7)}
    return data


def _extent(runs: list[ViewRun], margin_m: float = 0.0) -> tuple[float, float, float, float]:
    """WGS84 ``(west, south, east, north)`` of the tracks and ground truths, ``margin_m`` around."""
    lon = np.concatenate([r.track["lon"].to_numpy(float) for r in runs])
    lat = np.concatenate([r.track["lat"].to_numpy(float) for r in runs])
    for run in runs:
        if run.session is not None and run.session.waypoints is not None:
            lon = np.concatenate([lon, run.session.waypoints["lon"].to_numpy(float)])
            lat = np.concatenate([lat, run.session.waypoints["lat"].to_numpy(float)])
    lon, lat = lon[np.isfinite(lon)], lat[np.isfinite(lat)]
    pad_lat = margin_m / 111_320.0
    pad_lon = pad_lat / max(np.cos(np.radians(np.mean(lat))), 0.1)
    return lon.min() - pad_lon, lat.min() - pad_lat, lon.max() + pad_lon, lat.max() + pad_lat


def _map_overlays(maps: dict[str, MapLayers], bbox: tuple[float, float, float, float]) -> str:
    statements = []
    for i, (name, layers) in enumerate(maps.items()):
        try:
            clipped = clip_to_bbox(layers, bbox)
        except CurbsideInputError:
            log.warning("the map %s has nothing under the runs", name)
            continue
        prefix = f"{name}: " if len(maps) > 1 else ""
        for cls, features in class_features(clipped).items():
            if features:
                statements.append(class_overlay_js(cls, features, prefix, visible=i == 0))
    return "\n".join(statements)


def view_page(
    runs: list[ViewRun],
    maps: dict[str, MapLayers] | None = None,
    title: str | None = None,
    cloud_every: int = 1,
) -> str:
    """The replay page of one or more runs.

    Parameters
    ----------
    runs
        The runs (distinct labels; see :func:`label_runs`).
    maps
        Map layers to draw under the runs, by name (the first is shown, the others listed in the layer
        control); clipped to the runs' extent. ``None``: the maps the runs were tracked on
        (:func:`maps_of`); ``{}``: none.
    title
        Page title (default: the sessions' names).
    cloud_every
        Keep the particle cloud of every ``cloud_every``-th footstep only (the slider shows the latest
        kept one): a long walk's page shrinks about that many times.

    Returns
    -------
    str
        The HTML document.
    """
    if not runs:
        raise CurbsideInputError("RUN", "no runs to show")
    if maps is None:
        maps = maps_of(runs)
    used: set[str] = set()
    run_data = [_run_data(run, _colour(run, used), cloud_every) for run in runs]
    sessions = {}
    for run in runs:
        if run.session is not None and run.session_key not in sessions:
            sessions[run.session_key] = _session_data(run.session, run.session_key)
    bbox = _extent(runs, MAP_MARGIN_M)
    names = sorted({s["name"] for s in sessions.values()}) or [r.label for r in runs]
    title = title or f"curbside replay: {', '.join(names)}"
    data = {"runs": run_data, "sessions": list(sessions.values()), "title": title}
    first = next(iter(maps.values())) if maps else None
    script = "\n".join(
        [
            _map_overlays(maps, bbox),
            f"map.fitBounds({bounds_js(*_extent(runs))}, {{padding: [30, 30]}});",
            f"const VIEW = {script_json(data)};",
            asset_text("curbside-view.js"),
        ]
    )
    return leaflet_page(
        title,
        script,
        attribution_html=html.escape(attribution(first)) if first is not None else "",
        body=asset_text("curbside-view.html"),
        page_css=asset_text("curbside-view.css"),
    )


def write_view(
    runs: list[ViewRun], path: str | Path, maps: dict[str, MapLayers] | None = None, cloud_every: int = 1
) -> Path:
    """Write :func:`view_page` to an HTML file (atomically); warn when it is large.

    Returns
    -------
    pathlib.Path
        ``path``.
    """
    page = view_page(runs, maps, cloud_every=cloud_every)
    path = Path(path)
    with atomic_path(path) as tmp:
        tmp.write_text(page, encoding="utf-8")
    size_mb = path.stat().st_size / 1e6
    log.info("wrote %s (%.1f MB)", path, size_mb)
    if size_mb > LARGE_PAGE_MB:
        log.warning("%s is %.0f MB and may open slowly; --cloud-every %d keeps fewer particle clouds",
                    path, size_mb, max(2, round(cloud_every * size_mb / LARGE_PAGE_MB + 0.5)))
    return path


def maps_of(runs: list[ViewRun]) -> dict[str, MapLayers]:
    """The distinct maps of the runs, read once each, by file stem (or path when stems collide)."""
    paths = list(dict.fromkeys(r.map_path for r in runs if r.map_path))
    stems = [Path(p).stem for p in paths]
    names = stems if len(set(stems)) == len(stems) else paths
    return {name: read_map(p) for name, p in zip(names, paths, strict=True)}


# -- the pages of `localize evaluate`'s report ----------------------------------------------------------


def _is_view_run(spec: dict, base: dict) -> bool:
    """A run at the report's base parameters, on any map (GNSS, which uses no map: on the base map only)."""
    if spec["method"] == "gnss":
        return spec["map_name"] == base["map"]
    return all(spec[k] == base[k] for k in ("jaywalk_weight", "particles", "gnss_sigma_factor"))


def runs_from_results(results: list[dict], base: dict) -> dict[str, list[ViewRun]]:
    """The viewer's runs of each session of an evaluation, at its base parameters.

    Parameters
    ----------
    results
        :func:`curbside.evaluate.runner.run_one` outputs: ``spec``, ``track`` (``t, x_m, y_m`` in the
        scoring frame), ``errors`` (``est_segment``), ``recoveries`` and, when the runner kept them,
        ``particles`` (packed, :mod:`curbside.localize.particle_store`).
    base
        The report's base parameters (``map``, ``jaywalk_weight``, ``particles``, ``gnss_sigma_factor``).

    Returns
    -------
    dict
        Session folder name -> its runs, labelled (:func:`label_runs`).
    """
    from curbside.localize.particle_store import unpack_particles
    from curbside.localize.session import read_session

    sessions: dict[str, Session] = {}
    frames: dict[str, LocalFrame] = {}
    by_session: dict[str, list[ViewRun]] = {}
    for result in results:
        spec = result["spec"]
        if not _is_view_run(spec, base):
            continue
        path = spec["session"]
        if path not in sessions:
            sessions[path] = read_session(path)
        session = sessions[path]
        if spec["metrics_map"]:
            if spec["metrics_map"] not in frames:
                frames[spec["metrics_map"]] = LocalFrame(pyproj.CRS(read_map(spec["metrics_map"]).crs))
            frame = frames[spec["metrics_map"]]
        else:  # the runner scores a run without a metrics map in the frame around the first waypoint
            first = session.waypoints.iloc[0]
            frame = LocalFrame.around(float(first["lon"]), float(first["lat"]))
        scored = result["track"]
        lon, lat = frame.to_lonlat(scored["x_m"].to_numpy(float), scored["y_m"].to_numpy(float))
        track = pd.DataFrame({"t": scored["t"].to_numpy(float), "lat": lat, "lon": lon})
        if "est_segment" in result["errors"]:
            track["sidewalk_segment_id"] = result["errors"]["est_segment"].to_numpy()
        particles = result.get("particles")
        by_session.setdefault(Path(path).name, []).append(
            ViewRun(
                label=spec["method"],
                track=track,
                session=session,
                session_key=str(Path(path).resolve()),
                mode=spec["method"],
                particles=unpack_particles(particles, path) if particles is not None else None,
                map_path=spec["map_path"] if spec["method"] != "gnss" else None,
                recoveries=int(result.get("recoveries", 0)),
            )
        )
    for runs in by_session.values():
        maps = {r.map_path for r in runs if r.map_path}
        for run in runs:
            if len(maps) > 1 and run.map_path:
                run.label = f"{run.label} · {Path(run.map_path).stem}"
    return by_session


def write_session_views(results: list[dict], base: dict, out_dir: str | Path) -> dict[str, Path]:
    """One viewer page per session of an evaluation, ``out_dir/SESSION.html``.

    Parameters
    ----------
    results, base
        See :func:`runs_from_results`.
    out_dir
        Folder of the pages (created).

    Returns
    -------
    dict
        Session folder name -> page path.
    """
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    maps: dict[str, MapLayers] = {}
    pages = {}
    for session, runs in runs_from_results(results, base).items():
        shown = {}
        for path in dict.fromkeys(r.map_path for r in runs if r.map_path):
            if path not in maps:
                maps[path] = read_map(path)
            shown[Path(path).stem] = maps[path]
        pages[session] = write_view(runs, out_dir / f"{session}.html", shown)
    return pages
