"""``osmseg edit``: write the map editor, an offline HTML page that corrects a map and saves it."""

from __future__ import annotations

import argparse
from pathlib import Path

from curbside.cli.common import OVERWRITE_FILE_HELP
from curbside.cli.osmseg_show import add_bbox_option
from curbside.errors import CurbsideInputError


def _edit(args: argparse.Namespace) -> int:
    from curbside.io import check_output_file
    from curbside.osmseg.inputs import check_bbox, check_map_file

    if Path(args.output).suffix.lower() not in (".html", ".htm"):
        raise CurbsideInputError(args.output, "the editor is an HTML page: name it .html")
    check_output_file(args.output, args.overwrite, inputs=(args.map,))
    bbox = check_bbox(args.bbox) if args.bbox is not None else None
    check_map_file(args.map)
    # the heavy imports, once the cheap checks passed
    from curbside.osmseg.edit import file_features, window_features, write_editor
    from curbside.osmseg.mapio import read_map

    layers = read_map(args.map)
    features, kept = file_features(args.map), []
    if bbox is not None:
        features, kept = window_features(features, bbox)
    path = write_editor(layers, Path(args.map).name, args.output, features, kept, bbox)
    saved_too = f" (+{len(kept):,} outside the window, saved as they are)" if bbox is not None else ""
    print(
        f"{path}: editor for {len(features):,} polygons of {args.map}{saved_too} "
        f"({path.stat().st_size / 1e6:.1f} MB); open it in a browser, edit, then 'save edited map'"
    )
    return 0


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add ``osmseg edit`` to ``subparsers``."""
    parser = subparsers.add_parser(
        "edit",
        help="write an offline HTML map editor (move vertices, draw, delete, change class, save GeoJSON)",
        description=(
            "Write a self-contained HTML page (no network needed) to correct a map by hand: click a "
            "polygon, drag its vertices, change its class or sidewalk fields, delete it, or draw new "
            "polygons. 'Save edited map' downloads a GeoJSON of the curbside schema that records which "
            "features were edited; use it like any map, e.g. `osmseg compare MAP EDITED` or "
            "`localize evaluate SESSIONS --maps MAP EDITED`."
        ),
    )
    parser.add_argument("map", help="map GeoJSON (osmseg build output or hand-labelled)")
    parser.add_argument("-o", "--output", required=True, help="output page (.html)")
    parser.add_argument("--overwrite", action="store_true", help=OVERWRITE_FILE_HELP)
    add_bbox_option(parser, "show and edit only the polygons that meet this WGS84 window (whole, not "
                    "clipped); the saved map still holds every polygon of MAP")
    parser.set_defaults(func=_edit)
