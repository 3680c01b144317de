"""``osmseg show``: render a map to a PNG or an interactive HTML page."""

from __future__ import annotations

import argparse

from curbside.cli.common import OVERWRITE_FILE_HELP


def add_bbox_option(parser: argparse.ArgumentParser, help_text: str) -> None:
    """Add ``--bbox W S E N`` (WGS84 degrees) to a sub-command."""
    parser.add_argument(
        "--bbox", nargs=4, type=float, metavar=("W", "S", "E", "N"), default=None, help=help_text
    )


def _show(args: argparse.Namespace) -> int:
    from curbside.io import check_output_file
    from curbside.osmseg.inputs import check_bbox, check_map_file, output_format

    output_format(args.output)
    check_output_file(args.output, args.overwrite, inputs=(args.map,))
    bbox = check_bbox(args.bbox) if args.bbox is not None else None
    check_map_file(args.map)
    # the heavy imports, once the cheap checks passed
    from curbside.osmseg.mapio import read_map
    from curbside.osmseg.plot import render_map

    layers = read_map(args.map)
    path = render_map(layers, args.output, bbox=bbox)
    window = "" if bbox is None else f", --bbox {' '.join(f'{v:g}' for v in bbox)}"
    print(f"wrote {path} ({args.map}{window}; {path.stat().st_size / 1e6:.1f} MB)")
    return 0


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add ``osmseg show`` to ``subparsers``."""
    parser = subparsers.add_parser(
        "show",
        help="render a map to PNG (matplotlib) or HTML (Leaflet, self-contained, no tile server)",
        description="Render map layers (any GeoJSON of the curbside schema) to a PNG or an interactive "
        "HTML map; the format follows the output's extension.",
    )
    parser.add_argument("map", help="map GeoJSON (osmseg build output or hand-labelled)")
    parser.add_argument("-o", "--output", required=True, help="output file: .png or .html")
    parser.add_argument("--overwrite", action="store_true", help=OVERWRITE_FILE_HELP)
    add_bbox_option(parser, "show only this WGS84 window")
    parser.set_defaults(func=_show)
