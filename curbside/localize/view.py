"""The replay viewer: one offline HTML page that steps through one or more tracked walks.

``localize view RUN [RUN ...] -o view.html`` reads run folders written by ``localize run -o RUN`` and
draws, over the map layers of the runs' map: each run's estimate track, its particle cloud at every
footstep (``particles.npz``, from ``--save-particles``), the session's GNSS fixes with their accuracy
circles and the ground truth when the session has waypoints. A time slider with play/pause steps
through the walk; a panel (collapsible, and kept off the fitted walk) shows, for each run, the
sidewalk segment in words ("Market Street, north side"; the raw id in its tooltip) and its probability,
the error against the ground truth, the effective sample size and the recoveries so far. Runs of a
known method are labelled as in the reports (:data:`curbside.evaluate.runner.METHOD_LABELS`).

The page is self-contained: the vendored Leaflet and the data are inlined (see
:mod:`curbside.osmseg.webmap`). Particle clouds travel as base64 int16 offsets from each footstep's
estimate in micro-degrees (exact lon/lat to 0.1 m, ±3.6 km), which keeps a 10-minute walk at N = 500
at about 3 MB per run.
"""

from __future__ import annotations

import html
import json
import logging
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd
import pyproj

from curbside.errors import CurbsideInputError
from curbside.evaluate.runner import METHOD_LABELS
from curbside.io import atomic_path
from curbside.localize.particle_store import ParticleClouds, read_particles
from curbside.localize.paths import check_run_folder
from curbside.localize.session import Session
from curbside.localize.view_data import SegmentNamer, run_data, session_data
from curbside.osmseg.mapio import MapLayers, read_map
from curbside.osmseg.plot import clip_to_bbox
from curbside.osmseg.style import GNSS_FIX_COLOUR, METHOD_COLOURS
from curbside.osmseg.webmap import (
    asset_text,
    attribution,
    class_features,
    class_overlay_js,
    leaflet_page,
    script_json,
)
from curbside.projection import LocalFrame

log = logging.getLogger(__name__)

#: Colours of further runs, in turn: a second run of a method, or a run of no known method (after
#: :data:`~curbside.osmseg.style.METHOD_COLOURS`, the track colour of each method, the report's figures'
#: too). Searched so that each stays at least 20 (CIE76 ΔE) from every method colour, the GNSS fixes'
#: blue, the ground truth's black, the map's fills and each other, for normal vision and under
#: simulated deuteranopia, protanopia and tritanopia (Machado et al. 2009): 21.7 at the closest pair of
#: lines, 20.8 from a map fill (the best sixth colour found would bring that down to 20.4). Further runs
#: repeat them, with a warning.
EXTRA_COLOURS: tuple[str, ...] = ("#3416da", "#f07844", "#700f52", "#9e62ff", "#5a0fa5")
#: Metres of map kept around the tracks and the ground truth (the fitted view leaves room for the panel
#: beside the walk: that room shows map too).
MAP_MARGIN_M = 150.0
#: Pages larger than this (MB) get a warning: they take seconds to open.
LARGE_PAGE_MB = 20.0


@dataclass
class ViewRun:
    """One tracked walk, as the viewer shows it.

    Attributes
    ----------
    label
        Name in the legend and the panel.
    track
        ``t, lat, lon`` per footstep and, when known, ``n_eff``, ``recovered``, ``sidewalk_segment_id``,
        ``segment_prob``, ``accuracy_m``.
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
    segment_map
        The map whose ``segment_id`` the track's ``sidewalk_segment_id`` names (it gives the street
        names); ``None``: ``map_path``.
    """

    label: str
    track: pd.DataFrame
    session: Session | None = None
    session_key: str = ""
    mode: str = ""
    particles: ParticleClouds | None = None
    map_path: str | None = None
    recoveries: int = 0
    segment_map: str | None = None


def method_label(mode: str) -> str:
    """The reports' name of a method (:data:`~curbside.evaluate.runner.METHOD_LABELS`), else ``mode``."""
    return METHOD_LABELS.get(mode, mode)


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
        Labelled by method as in the reports (:func:`method_label`), else by folder name;
        :func:`label_runs` makes the labels of several runs distinct.

    Raises
    ------
    CurbsideInputError
        Not a run folder, a track without ``t, lat, lon``, a session or map that cannot be read.
    """
    from curbside.localize.readers import read_any

    folder = Path(folder)
    track_csv, run_json = check_run_folder(folder)
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
    mode = str(info.get("mode") or "")
    return ViewRun(
        label=method_label(mode) if mode else folder.name,
        track=track,
        session=loaded,
        session_key=str(Path(session_src).resolve()) if session_src else "",
        mode=mode,
        particles=particles,
        map_path=str(map_path or info.get("map") or "") or None,
        recoveries=int(info.get("recoveries") or 0),
        segment_map=str(info.get("map") or "") or None,
    )


def label_runs(runs: list[ViewRun], names: list[str] | None = None) -> list[ViewRun]:
    """Give every run a distinct label: the method's, then the map's name (runs on several maps), the
    session's (runs of several sessions), then a number.

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
    several_sessions = len(session_names(runs)) > 1
    for run in runs:
        if len(maps) > 1:
            run.label = f"{run.label} · {Path(run.map_path).stem if run.map_path else 'no map'}"
        if several_sessions and run.session is not None:
            run.label = f"{run.label} · {run.session.name}"
    seen: dict[str, int] = {}
    for run in runs:
        seen[run.label] = seen.get(run.label, 0) + 1
        if seen[run.label] > 1:
            run.label = f"{run.label} ({seen[run.label]})"
    return runs


def session_names(runs: list[ViewRun]) -> dict[str, str]:
    """The distinct sessions of the runs that have one: key -> session name, in the runs' order."""
    return {r.session_key: r.session.name for r in runs if r.session is not None}


def run_colours(runs: list[ViewRun]) -> list[str]:
    """Each run's track colour: its method's (:data:`METHOD_COLOURS`) for the first run of a method,
    else the next of :data:`EXTRA_COLOURS`; past those, the extra colours again, with a warning."""
    colours: list[str] = []
    for run in runs:
        colour = METHOD_COLOURS.get(run.mode)
        if colour is None or colour in colours:
            spare = [c for c in EXTRA_COLOURS if c not in colours]
            colour = spare[0] if spare else EXTRA_COLOURS[len(colours) % len(EXTRA_COLOURS)]
        colours.append(colour)
    if len(set(colours)) < len(runs):
        log.warning("%d runs on one page share %d colours: tell them apart by their labels in the legend",
                    len(runs), len(set(colours)))
    return colours


def several_sessions_note(runs: list[ViewRun]) -> str | None:
    """What a page of runs of several sessions says about it (``None`` for runs of one session).

    The page draws every session's GNSS fixes in one colour and every ground truth in black, and plays
    each run on its own session's clock; the legend, the panel and each run's label name the session.
    """
    names = list(session_names(runs).values())
    if len(names) < 2:
        return None
    return (f"the runs come from {len(names)} sessions ({', '.join(names)}): their GNSS fixes share one "
            "colour and their ground truths another (the legend names each session's layers), and each run "
            "plays on its own session's clock")


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


def _map_overlays(
    maps: dict[str, MapLayers], bbox: tuple[float, float, float, float], namer: SegmentNamer
) -> str:
    statements = []
    for i, (name, layers) in enumerate(maps.items()):
        try:
            clipped = clip_to_bbox(layers, bbox)
        except CurbsideInputError:
            log.warning("the map %s has nothing under the runs", name)
            continue
        prefix = f"{name}: " if len(maps) > 1 else ""
        places = namer.places(layers)  # on the whole map: a segment at the edge keeps its street
        for cls, features in class_features(clipped, places=places).items():
            if features:
                statements.append(class_overlay_js(cls, features, prefix, visible=i == 0))
    return "\n".join(statements)


def view_page(
    runs: list[ViewRun],
    maps: dict[str, MapLayers] | None = None,
    title: str | None = None,
    cloud_every: int = 1,
    namer: SegmentNamer | None = None,
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
    namer
        Reads the maps and names their segments in words, each once (the pages of a report share one);
        default: a new :class:`~curbside.localize.view_data.SegmentNamer`.

    Returns
    -------
    str
        The HTML document.
    """
    if not runs:
        raise CurbsideInputError("RUN", "no runs to show")
    namer = namer or SegmentNamer()
    if maps is None:
        maps = maps_of(runs, namer.read)
    runs_data = [run_data(run, colour, cloud_every, namer)
                 for run, colour in zip(runs, run_colours(runs), strict=True)]
    note = several_sessions_note(runs)
    if note is not None:
        log.warning("%s", note)
    sessions = {}
    for run in runs:
        if run.session is not None and run.session_key not in sessions:
            sessions[run.session_key] = session_data(run.session, run.session_key)
    bbox = _extent(runs, MAP_MARGIN_M)
    names = sorted({s["name"] for s in sessions.values()}) or [r.label for r in runs]
    title = title or f"curbside replay: {', '.join(names)}"
    west, south, east, north = _extent(runs)
    data = {"runs": runs_data, "sessions": list(sessions.values()), "title": title,
            "bounds": [[south, west], [north, east]], "gnss_colour": GNSS_FIX_COLOUR, "note": note}
    credits = " · ".join(dict.fromkeys(attribution(layers) for layers in maps.values()))
    script = "\n".join(
        [
            _map_overlays(maps, bbox, namer),
            f"const VIEW = {script_json(data)};",
            asset_text("curbside-view.js"),
        ]
    )
    return leaflet_page(
        title,
        script,
        attribution_html=html.escape(credits),
        body=asset_text("curbside-view.html"),
        page_css=asset_text("curbside-view.css"),
    )


def write_view(
    runs: list[ViewRun],
    path: str | Path,
    maps: dict[str, MapLayers] | None = None,
    cloud_every: int = 1,
    namer: SegmentNamer | None = None,
) -> Path:
    """Write :func:`view_page` to an HTML file (atomically); warn when it is large.

    Parameters
    ----------
    runs, maps, cloud_every, namer
        See :func:`view_page`.
    path
        The page.

    Returns
    -------
    pathlib.Path
        ``path``.
    """
    page = view_page(runs, maps, cloud_every=cloud_every, namer=namer)
    path = Path(path)
    with atomic_path(path) as tmp:
        tmp.write_text(page, encoding="utf-8")
    size_mb = path.stat().st_size / 1e6
    log.info("wrote %s (%.1f MB)", path, size_mb)
    if size_mb > LARGE_PAGE_MB:
        log.warning("%s is %.0f MB and may open slowly; --cloud-every %d keeps fewer particle clouds",
                    path, size_mb, max(2, round(cloud_every * size_mb / LARGE_PAGE_MB + 0.5)))
    return path


def maps_of(runs: list[ViewRun], read: Callable[[str], MapLayers] = read_map) -> dict[str, MapLayers]:
    """The distinct maps of the runs, read once each (with ``read``), by file stem (or path when stems
    collide)."""
    paths = list(dict.fromkeys(r.map_path for r in runs if r.map_path))
    stems = [Path(p).stem for p in paths]
    names = stems if len(set(stems)) == len(stems) else paths
    return {name: read(p) for name, p in zip(names, paths, strict=True)}


# -- the pages of `localize evaluate`'s report ----------------------------------------------------------


def _is_view_run(spec: dict, base: dict) -> bool:
    """A run at the report's base parameters, on any map (GNSS, which uses no map: on the base map only)."""
    if spec["method"] == "gnss":
        return spec["map_name"] == base["map"]
    return all(spec[k] == base[k] for k in ("jaywalk_weight", "particles", "gnss_sigma_factor"))


def _result_track(result: dict, frame: LocalFrame) -> pd.DataFrame:
    """A result's scored track back in lon/lat, with the panel's columns the result holds.

    ``accuracy_m`` comes from ``errors``; the segment and its ``segment_prob`` from ``errors_mode``
    when it has ``segment_prob`` (the posterior-mode estimate lies on the segment that probability is
    of), else the segment from ``errors``; ``n_eff`` from wherever the runner put it.
    """
    scored = result["track"]
    lon, lat = frame.to_lonlat(scored["x_m"].to_numpy(float), scored["y_m"].to_numpy(float))
    track = pd.DataFrame({"t": scored["t"].to_numpy(float), "lat": lat, "lon": lon})
    errors = result["errors"]
    mode = result.get("errors_mode")
    if mode is not None and "segment_prob" in mode and "est_segment" in mode:
        track["sidewalk_segment_id"] = mode["est_segment"].to_numpy()
        track["segment_prob"] = mode["segment_prob"].to_numpy(float)
    elif "est_segment" in errors:
        track["sidewalk_segment_id"] = errors["est_segment"].to_numpy()
    if "accuracy_m" in errors:
        track["accuracy_m"] = errors["accuracy_m"].to_numpy(float)
    for table in (scored, errors, mode):
        if table is not None and "n_eff" in table:
            track["n_eff"] = table["n_eff"].to_numpy(float)
            break
    return track


def runs_from_results(
    results: list[dict], base: dict, map_reader: Callable[[str], MapLayers] | None = None
) -> dict[str, list[ViewRun]]:
    """The viewer's runs of each session of an evaluation, at its base parameters.

    Parameters
    ----------
    results
        :func:`curbside.evaluate.runner.run_one` outputs: ``spec``, ``track`` (``t, x_m, y_m`` in the
        scoring frame), ``errors`` (``est_segment``, ``accuracy_m``), ``errors_mode`` (``est_segment``,
        ``segment_prob``), ``recoveries`` and, when the runner kept them, ``particles`` (packed,
        :mod:`curbside.localize.particle_store`) and ``n_eff`` (in ``track`` or ``errors``).
    base
        The report's base parameters (``map``, ``jaywalk_weight``, ``particles``, ``gnss_sigma_factor``).
    map_reader
        Reads a map by path (default :func:`~curbside.osmseg.mapio.read_map`).

    Returns
    -------
    dict
        Session folder name -> its runs, labelled as in the reports (:func:`method_label`, then the
        map's name when the session's runs used several).
    """
    from curbside.localize.particle_store import unpack_particles
    from curbside.localize.session import read_session

    read = map_reader or read_map
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
                frames[spec["metrics_map"]] = LocalFrame(pyproj.CRS(read(spec["metrics_map"]).crs))
            frame = frames[spec["metrics_map"]]
        else:  # the runner scores a run without a metrics map in the frame around the first waypoint
            first = session.waypoints.iloc[0]
            frame = LocalFrame.around(float(first["lon"]), float(first["lat"]))
        particles = result.get("particles")
        by_session.setdefault(Path(path).name, []).append(
            ViewRun(
                label=method_label(spec["method"]),
                track=_result_track(result, frame),
                session=session,
                session_key=str(Path(path).resolve()),
                mode=spec["method"],
                particles=unpack_particles(particles, path) if particles is not None else None,
                map_path=spec["map_path"] if spec["method"] != "gnss" else None,
                recoveries=int(result.get("recoveries", 0)),
                segment_map=spec["metrics_map"] or "",
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
    namer = SegmentNamer()  # every map read and named once for all the pages
    pages = {}
    for session, runs in runs_from_results(results, base, namer.read).items():
        shown = {Path(p).stem: namer.read(p) for p in dict.fromkeys(r.map_path for r in runs if r.map_path)}
        pages[session] = write_view(runs, out_dir / f"{session}.html", shown, namer=namer)
    return pages
