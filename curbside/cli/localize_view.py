"""``localize view``: the replay viewer, one offline HTML page over one or more run folders.

::

    localize view RUN [RUN ...] -o view.html [--session SESSION] [--map MAP] [--labels NAME ...]
                  [--cloud-every K]

``RUN`` is a folder written by ``localize run -o RUN`` (``--save-particles`` adds the particle cloud).
The session (GNSS fixes, ground truth) and the map are the ones ``RUN/run.json`` names, unless
``--session`` / ``--map`` say otherwise.
"""

from __future__ import annotations

import argparse
import logging
from pathlib import Path
from typing import TYPE_CHECKING

from curbside.cli.common import OVERWRITE_FILE_HELP, positive_int
from curbside.errors import CurbsideInputError

if TYPE_CHECKING:
    from curbside.localize.view import ViewRun

log = logging.getLogger(__name__)


def _check_arguments(args: argparse.Namespace) -> None:
    """Refuse, before the heavy imports, what needs no reading: the output's name and folder, a missing
    run folder, session or map.

    Raises
    ------
    CurbsideInputError
        Any of these.
    """
    from curbside.io import check_output_file
    from curbside.localize.paths import check_run_folder, check_source_path
    from curbside.osmseg.inputs import check_map_file

    if Path(args.output).suffix.lower() not in (".html", ".htm"):
        raise CurbsideInputError(args.output, "the viewer is an HTML page: name it .html")
    check_output_file(args.output, args.overwrite, inputs=(args.map,) if args.map else ())
    for folder in args.runs:
        check_run_folder(folder)
    if args.session:
        check_source_path(args.session)
    if args.map:
        check_map_file(args.map)


def _view(args: argparse.Namespace) -> int:
    _check_arguments(args)
    # the heavy imports, once the cheap checks passed
    from tqdm.auto import tqdm

    from curbside.localize.view import label_runs, load_run, maps_of, write_view
    from curbside.localize.view_data import SegmentNamer

    # One bar over the slow steps, on a terminal only: each run (its session and clouds), the maps, the page.
    with tqdm(total=len(args.runs) + 2, desc="localize view: reading runs", unit="step", leave=False,
              disable=None) as bar:
        runs: list[ViewRun] = []
        for folder in args.runs:
            runs.append(load_run(folder, args.session, args.map))
            bar.update()
        label_runs(runs, args.labels)
        bar.set_description("localize view: reading maps")
        namer = SegmentNamer()
        maps = {Path(args.map).stem: namer.read(args.map)} if args.map else maps_of(runs, namer.read)
        bar.update()
        bar.set_description("localize view: writing the page")
        path = write_view(runs, args.output, maps, cloud_every=args.cloud_every, namer=namer)
        bar.update()
    clouds = sum(r.particles is not None for r in runs)
    print(
        f"{path}: {len(runs)} run(s), {clouds} with particle clouds, "
        f"{path.stat().st_size / 1e6:.1f} MB; open it in a browser (works offline)"
    )
    return 0


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add ``view`` to the ``localize`` sub-commands."""
    parser = subparsers.add_parser(
        "view",
        help="replay one or more runs in an offline HTML page (time slider, particle clouds)",
        description=(
            "Write one self-contained HTML page (no network needed) replaying runs of `localize run`: "
            "each run's estimate track, its 68 % radius (accuracy_m) and particle cloud at each footstep "
            "(clouds with --save-particles), "
            "the session's GNSS fixes with their accuracy circles and the ground truth when it has "
            "waypoints, over the map layers. A time slider with play/pause steps through the walk; a "
            "panel shows the sidewalk segment and its probability, the error against the ground truth "
            "beside the 68 % radius, "
            "n_eff and the recoveries."
        ),
    )
    parser.add_argument("runs", nargs="+", metavar="RUN", help="run folder(s) written by `localize run -o`")
    parser.add_argument("-o", "--output", required=True, help="output page (.html)")
    parser.add_argument("--overwrite", action="store_true", help=OVERWRITE_FILE_HELP)
    parser.add_argument("--session", help="session to show (default: the one each run.json names)")
    parser.add_argument("--map", help="map GeoJSON to draw (default: the map(s) the runs were tracked on)")
    parser.add_argument(
        "--labels", nargs="+", metavar="NAME",
        help="legend names, one per run (default: the mode, then the map's name where the maps differ)",
    )
    parser.add_argument(
        "--cloud-every", type=positive_int, default=1, metavar="K",
        help="keep the particle cloud of every K-th footstep only, for long walks (default: %(default)s)",
    )
    parser.set_defaults(func=_view)
