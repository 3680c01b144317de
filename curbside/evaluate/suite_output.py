"""Where a benchmark writes: its output folder's rules and the maps it builds or reuses there.

A benchmark folder is new, empty or an earlier ``localize benchmark`` output, whose simulated sessions
and built maps are then reused (:func:`check_suite_folder`); a map file in it that curbside did not
write is neither used nor replaced without ``overwrite``. The folder is created and marked only once the
given map reads, and removed again when the run that created it fails before writing anything.
"""

from __future__ import annotations

import contextlib
import logging
import os
import shutil
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING

from curbside.errors import CurbsideInputError
from curbside.io import MARKER, check_output_folder, note_written, read_marker, written_by_curbside

if TYPE_CHECKING:  # the map's modules load geopandas: check_suite_folder runs before they are imported
    from curbside.osmseg.mapio import MapLayers

log = logging.getLogger(__name__)

OSM_MAP = "osm"
DATASF_MAP = "datasf"
#: What the output folder's marker records as its writer.
COMMAND = "localize benchmark"
#: What a benchmark writes at the top of its output folder.
_OUTPUTS = ("map.geojson", "map-datasf.geojson", "sessions", "report")


def _earlier_output(folder: Path) -> bool:
    """Whether ``folder``, without a marker, is a benchmark output of a version that wrote none: only
    the benchmark's own entries, its maps signed by curbside."""
    if not folder.is_dir() or read_marker(folder) is not None:
        return False
    entries = list(folder.iterdir())
    return bool(entries) and all(
        p.name in _OUTPUTS and (p.is_dir() if p.name in ("sessions", "report") else written_by_curbside(p))
        for p in entries
    )


def check_suite_folder(out_dir: str | Path, overwrite: bool = False) -> Path:
    """Check, before any work, that a benchmark may write ``out_dir``.

    It may when it is new, empty or an earlier benchmark output (whose sessions are then reused), or
    with ``overwrite``; see :func:`curbside.io.check_output_folder`.

    Returns
    -------
    pathlib.Path
        ``out_dir``, absolute.

    Raises
    ------
    CurbsideInputError
        Any other folder, a file, or a folder that cannot be written.
    """
    checked = check_output_folder(out_dir, overwrite or _earlier_output(Path(out_dir)), COMMAND)
    report = checked / "report"
    if os.path.lexists(report) and not report.is_dir():
        raise CurbsideInputError(report, "is a file, where the benchmark writes its report folder: move it")
    if report.is_dir() and any(report.iterdir()) and read_marker(report) is None:
        # the report is written last, and never over a folder curbside did not write: refuse it now
        raise CurbsideInputError(
            report, "holds files curbside did not write, where the benchmark writes its report: move them"
        )
    return checked


def _own_file(path: Path, overwrite: bool) -> bool:
    """Whether ``path`` is a file of the benchmark's to reuse; ``False`` when absent, or another file
    that ``overwrite`` lets it replace."""
    if not path.is_file():
        return False
    if written_by_curbside(path):
        return True
    if not overwrite:
        raise CurbsideInputError(
            path, "was not written by curbside: not using or replacing it (pass --overwrite to replace it)"
        )
    return False


def benchmark_maps(
    out_dir: Path, map_path: str | Path | None, datasf_tiles: list[str | Path] | None, overwrite: bool = False
) -> dict[str, str]:
    """The OSM map (built into ``out_dir`` unless given or already there) and the DataSF one."""
    from curbside.evaluate.benchmark import datasf_osm_map
    from curbside.osmseg.mapio import write_map

    if map_path is None:
        map_path = out_dir / "map.geojson"
        if not _own_file(map_path, overwrite):
            from curbside.osmseg.build import build_map

            log.info("building the OSM map -> %s", map_path)
            write_map(build_map(), map_path)
            note_written(map_path, COMMAND)
    elif not Path(map_path).is_file():
        raise CurbsideInputError(map_path, "no such map file")
    maps = {OSM_MAP: str(map_path)}
    if datasf_tiles:
        datasf = out_dir / "map-datasf.geojson"
        _own_file(datasf, overwrite)  # rebuilt every time (the tiles may differ), but never a user's file
        maps[DATASF_MAP] = str(datasf_osm_map(map_path, list(datasf_tiles), datasf))
        note_written(datasf, COMMAND)
    return maps


def check_map_area(map_path: str | Path, layers: MapLayers) -> None:
    """Refuse a ``--map`` whose extent misses the benchmark's area (:data:`subsets.SKY_BBOX`, downtown San
    Francisco), before minutes of simulated walks that could not be tracked on it.

    Parameters
    ----------
    map_path
        The map's file, for the message.
    layers
        The map, read.

    Raises
    ------
    CurbsideInputError
        Naming the map, its extent and the area, both in degrees.
    """
    from curbside.evaluate.subsets import SKY_BBOX

    west, south, east, north = layers.gdf.to_crs(4326).total_bounds
    w, s, e, n = SKY_BBOX
    if west > e or east < w or south > n or north < s:
        raise CurbsideInputError(
            map_path,
            f"the map (lon {west:.4f} to {east:.4f}, lat {south:.4f} to {north:.4f}) does not cover the "
            f"benchmark's walks in downtown San Francisco (lon {w} to {e}, lat {s} to {n}); build it with "
            "osmseg build, or leave --map out",
        )


@contextlib.contextmanager
def folder_for_run(out_dir: Path) -> Iterator[None]:
    """Create ``out_dir``, marked as a benchmark output at once (a run stopped half-way leaves a folder
    the next one resumes in); remove it again when this run created it and fails before writing."""
    created = not os.path.lexists(out_dir)
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
        note_written(out_dir / "sessions", COMMAND)
    except OSError as exc:
        raise CurbsideInputError(out_dir, f"cannot write here ({exc.strerror or exc})") from None
    try:
        yield
    except BaseException:
        left = [p for p in out_dir.iterdir() if p.name != MARKER]
        if created and all(p.is_dir() and not any(f.is_file() for f in p.rglob("*")) for p in left):
            shutil.rmtree(out_dir, ignore_errors=True)  # nothing in it but what this run just made
        raise
