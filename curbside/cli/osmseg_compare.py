"""``osmseg compare`` (two maps, class by class) and ``osmseg import-datasf`` (DataSF footprints)."""

from __future__ import annotations

import argparse
import logging
from pathlib import Path

from curbside.cli.common import OVERWRITE_FILE_HELP
from curbside.cli.osmseg_build import check_map_name
from curbside.cli.osmseg_show import add_bbox_option
from curbside.errors import CurbsideInputError

log = logging.getLogger(__name__)


def _compare(args: argparse.Namespace) -> int:
    from curbside.io import check_output_file
    from curbside.osmseg.inputs import check_map_file

    if args.json:
        if Path(args.json).suffix.lower() != ".json":
            raise CurbsideInputError(args.json, "the figures are JSON: name the file .json")
        check_output_file(args.json, args.overwrite, inputs=(args.a, args.b))
    check_map_file(args.a)
    check_map_file(args.b)
    # the heavy imports, once the cheap checks passed
    from curbside.osmseg.compare import compare_maps, format_comparison, write_comparison
    from curbside.osmseg.mapio import read_map

    a, b = read_map(args.a), read_map(args.b)
    result = compare_maps(a, b, name_b=args.b)
    print(format_comparison(result, args.a, args.b))
    if args.json:
        write_comparison(result, args.json, args.a, args.b)
        log.info("wrote %s", args.json)
    return 0


def _import_datasf(args: argparse.Namespace) -> int:
    from curbside.io import check_output_file
    from curbside.osmseg.inputs import check_bbox, check_map_file

    bbox = check_bbox(args.bbox) if args.bbox is not None else None
    check_map_name(args.output)
    inputs = (*args.tiles, args.streets_from) if args.streets_from else tuple(args.tiles)
    check_output_file(args.output, args.overwrite, inputs=inputs)
    if args.streets_from:
        check_map_file(args.streets_from)
    # the heavy imports, once the cheap checks passed
    from curbside.osmseg.datasf import read_datasf, read_datasf_over
    from curbside.osmseg.mapio import read_map, write_map
    from curbside.osmseg.summary import class_summary, format_summary

    if args.streets_from:
        layers = read_datasf_over(args.tiles, read_map(args.streets_from), bbox, fill_holes=args.fill_holes)
    else:
        layers = read_datasf(args.tiles, bbox=bbox, fill_holes=args.fill_holes)
    write_map(layers, args.output)
    summary = class_summary(layers)
    print(format_summary(summary if args.streets_from else summary.loc[["building"]]))
    log.info("wrote %s", args.output)
    return 0


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add ``osmseg compare`` and ``osmseg import-datasf`` to ``subparsers``."""
    compare = subparsers.add_parser(
        "compare",
        help="compare two maps class by class (area, IoU, boundary distance, counts)",
        description="Compare map B with map A per class over the overlap of their extents: areas, IoU, "
        "mean symmetric boundary distance, polygon counts. Any GeoJSON of the curbside schema.",
    )
    compare.add_argument("a", help="map A (GeoJSON)")
    compare.add_argument("b", help="map B (GeoJSON)")
    compare.add_argument("--json", metavar="OUT", help="also write the figures to this JSON file")
    compare.add_argument("--overwrite", action="store_true", help=OVERWRITE_FILE_HELP)
    compare.set_defaults(func=_compare)

    datasf = subparsers.add_parser(
        "import-datasf",
        help="convert DataSF building-footprint TopoJSON tiles to a building-only map",
        description="Read DataSF 2013 building footprints (TopoJSON tiles) into a map GeoJSON with the "
        "building class only, e.g. for `osmseg compare map.geojson datasf.geojson`; with --streets-from, "
        "over another map's streets and sidewalks, a whole map to track on.",
    )
    datasf.add_argument("tiles", nargs="+", metavar="TILE", help="TopoJSON tile(s)")
    add_bbox_option(datasf, "keep the footprints that intersect this WGS84 box")
    datasf.add_argument(
        "--fill-holes", action="store_true", help="drop inner rings (light wells, courtyards)"
    )
    datasf.add_argument(
        "--streets-from",
        metavar="MAP",
        help="keep this map's streets, crosswalks and sidewalks under the DataSF buildings (the "
        "map-source comparison's third map; default bbox: MAP's extent)",
    )
    datasf.add_argument("-o", "--output", required=True, help="output map GeoJSON (.geojson or .json)")
    datasf.add_argument("--overwrite", action="store_true", help=OVERWRITE_FILE_HELP)
    datasf.set_defaults(func=_import_datasf)
