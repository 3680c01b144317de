"""``osmseg build``: derive building, street, crosswalk and sidewalk polygons from OpenStreetMap."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from curbside import settings
from curbside.cli.common import OVERWRITE_FILE_HELP, set_overrides
from curbside.errors import CurbsideInputError
from curbside.osmseg.config import LOCALISED_NAME, READ_MARGIN_M, UNMARKED_CHOICES, SegmentationConfig

if TYPE_CHECKING:
    from curbside.osmseg.mapio import MapLayers


def _description() -> str:
    """What ``osmseg build --help`` says before the options: the sources, the cache, the licence."""
    extract = " ".join(f"{v:.10g}" for v in settings.default_extract_bbox)
    return (
        "Derive building, street, crosswalk and sidewalk-segment polygons from OpenStreetMap (OSM) and\n"
        "write them as one GeoJSON map.\n\n"
        "Where the OSM data comes from:\n"
        "  --osm FILE   a file you have (.osm, .osm.bz2, .osm.gz or .osm.pbf, e.g. from Geofabrik or\n"
        "               `osmium extract`); nothing is downloaded\n"
        "  (no --osm)   an area inside downtown San Francisco (W S E N:\n"
        f"               {extract}): the bundled extract; nothing is downloaded\n"
        "  (no --osm)   any other area: every building and highway in it and "
        f"{READ_MARGIN_M:g} m around it,\n"
        "               downloaded from the Overpass API (overpass-api.de)\n"
        "The area is --bbox, or --place: a place name that Nominatim, OSM's geocoder, looks up online.\n\n"
        f"Downloads are cached in {settings.cache_dir}/overpass and .../nominatim\n"
        "(CURBSIDE_CACHE_DIR moves the cache; it is safe to delete), so a build repeated offline works;\n"
        "without a network an uncached build stops in seconds with a one-line error.\n\n"
        f"Map data {settings.osm_attribution}: credit it wherever the map is shown (every map\n"
        "written carries this line); a database derived from it that you share is ODbL too."
    )


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add ``build`` to ``subparsers``."""
    p = subparsers.add_parser(
        "build",
        help="derive map layers from OpenStreetMap",
        description=_description(),
        epilog="examples:\n"
        "  osmseg build -o map.geojson                       # the bundled extract, offline\n"
        "  osmseg build --bbox -73.990 40.750 -73.980 40.758 -o midtown.geojson   # Overpass\n"
        "  osmseg build --place 'Union Square, San Francisco' -o union-square.geojson\n"
        "  osmseg build --osm helsinki.osm.pbf -o helsinki.geojson   # the bounds the file declares",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    area = p.add_mutually_exclusive_group()
    area.add_argument(
        "--bbox",
        nargs=4,
        type=float,
        metavar=("W", "S", "E", "N"),
        help="area to build in WGS84 degrees, longitude first: west south east north, at most "
        f"{settings.max_bbox_area_km2:g} km^2 (default: the whole bundled extract; with --osm, the bounds "
        "the file declares, else all of it)",
    )
    area.add_argument(
        "--place",
        metavar="NAME",
        help="area to build: the bounding box of a place name, e.g. 'Union Square, San Francisco' (looked up "
        "with Nominatim; a name that is a point, such as a shop or an address, is refused: give --bbox)",
    )
    p.add_argument("--osm", type=Path, metavar="FILE",
                   help="read this OSM file instead of downloading: .osm, .osm.bz2, .osm.gz or .osm.pbf")
    p.add_argument("-o", "--output", type=Path, default=Path("map.geojson"),
                   help="output map GeoJSON, named .geojson or .json (default: %(default)s)")
    p.add_argument("--overwrite", action="store_true", help=OVERWRITE_FILE_HELP)
    p.add_argument(
        "--unmarked-as",
        choices=UNMARKED_CHOICES,
        default=SegmentationConfig.unmarked_crossing_as,
        help="what unmarked crossings become (default: %(default)s)",
    )
    p.add_argument(
        "--name-tag",
        metavar="TAG",
        help="name streets from this OSM tag where a way has it, e.g. name:nl in Brussels ('Wetstraat' for "
        "'Rue de la Loi': a sidewalk's street, as localize speaks it); elsewhere from name, then ref",
    )
    p.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="set any parameter of the build (SegmentationConfig; recorded in the map's params), e.g. "
        "crosswalk_width_m=4 or default_carriageway_width_m.residential=9 (repeatable; `osmseg parameters` "
        "lists them all)",
    )
    p.set_defaults(func=run)


def summary_lines(layers: MapLayers) -> list[str]:
    """One line per class: polygon count and total area in m^2."""
    from curbside.osmseg.mapio import CLASSES

    gdf = layers.gdf
    lines = []
    for cls in CLASSES:
        rows = gdf[gdf["class"] == cls]
        lines.append(f"{cls:<10} {len(rows):>6} polygons {rows.area.sum():>12,.0f} m^2")
    return lines


def _conflict_share_min() -> float:
    """The filter's threshold (imported only when needed: the filter package is slow to import)."""
    from curbside.localize.filter.config import MapConfig

    return MapConfig.conflict_share_min


#: The names a map file written by curbside may have (GeoJSON goes by both); maps are read by any name.
MAP_SUFFIXES = (".geojson", ".json")


def check_map_name(path: str | Path) -> None:
    """Refuse a map output not named as GeoJSON (:data:`MAP_SUFFIXES`).

    Parameters
    ----------
    path
        The ``-o`` of ``osmseg build`` or ``osmseg import-datasf``.

    Raises
    ------
    CurbsideInputError
        Any other suffix.
    """
    if Path(path).suffix.lower() not in MAP_SUFFIXES:
        raise CurbsideInputError(path, "the map is GeoJSON: name it .geojson or .json")


def _checked_config(args: argparse.Namespace) -> SegmentationConfig:
    """The build's configuration, after the checks that need no heavy import: the output's name and
    folder, ``--set``, ``--bbox``, the ``--osm`` file's path.

    Raises
    ------
    CurbsideInputError
        Any of these.
    """
    from curbside.configio import with_overrides
    from curbside.io import check_output_file
    from curbside.osmseg.inputs import check_bbox, check_osm_file

    check_map_name(args.output)
    check_output_file(args.output, args.overwrite, inputs=(args.osm,) if args.osm else ())
    names = SegmentationConfig.street_name_keys
    if args.name_tag is not None:
        if not LOCALISED_NAME.fullmatch(args.name_tag):
            advice = "give name:<language>, e.g. name:en or name:zh"
            raise CurbsideInputError("--name-tag", f"{args.name_tag!r} is not a name tag: {advice}")
        names = (args.name_tag, *names)
    config = SegmentationConfig(unmarked_crossing_as=args.unmarked_as, street_name_keys=names)
    config = with_overrides(config, set_overrides(args.set))
    if args.bbox:
        check_bbox(args.bbox)
    if args.osm:
        check_osm_file(args.osm)
    return config


def run(args: argparse.Namespace) -> int:
    """Build the map and write it."""
    config = _checked_config(args)
    # the heavy imports, once the cheap checks passed
    from curbside.osmseg.build import build_map
    from curbside.osmseg.inputs import check_bbox
    from curbside.osmseg.mapio import write_map

    out = sys.stdout
    bbox = tuple(args.bbox) if args.bbox else None
    if args.place is not None:
        from curbside.osmseg.overpass import geocode_bbox

        found, name = geocode_bbox(args.place)
        bbox = check_bbox(found, f"--place {args.place!r}")
        out.write(f"--place {args.place!r} is {name}: --bbox {' '.join(f'{v:.7f}' for v in bbox)}\n")
    layers = build_map(bbox, args.osm, config=config)
    path = write_map(layers, args.output)
    out.write(f"wrote {path} ({layers.meta['source']}; {settings.osm_attribution})\n")
    for line in summary_lines(layers):
        out.write(line + "\n")
    mapped_km = layers.meta.get("sidewalk_ways_km", 0.0)
    if mapped_km > 0:
        out.write(f"{100 * layers.meta['sidewalk_ways_in_segments']:.1f} % of the {mapped_km:g} km of mapped "
                  "sidewalks (footway=sidewalk) lie in sidewalk segments\n")
    inside = layers.meta.get("sidewalk_ways_in_buildings", 0.0)
    if inside > 0 and inside >= _conflict_share_min():
        out.write(
            f"{100 * inside:.1f} % of the mapped sidewalks (footway=sidewalk) run inside buildings: are the "
            "buildings misaligned with the streets? localize softens this map's walls "
            "(filter.map.conflict_wall_tolerance_m)\n"
        )
    return 0
