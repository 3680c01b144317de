"""``osmseg build``: derive building, street, crosswalk and sidewalk polygons from OpenStreetMap."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from curbside import settings
from curbside.cli.common import set_overrides
from curbside.configio import with_overrides
from curbside.errors import CurbsideInputError
from curbside.io import OVERWRITE_FILE_HELP, check_output_file
from curbside.osmseg.build import build_map
from curbside.osmseg.config import UNMARKED_CHOICES, SegmentationConfig
from curbside.osmseg.mapio import CLASSES, MapLayers, write_map


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add ``build`` to ``subparsers``."""
    p = subparsers.add_parser(
        "build",
        help="derive map layers from OpenStreetMap",
        description=(
            "Derive building, street, crosswalk and sidewalk-segment polygons from OpenStreetMap. "
            "No --osm: the bundled downtown San Francisco extract when the bbox lies inside it, "
            f"else Overpass (cached under {settings.cache_dir}/overpass). {settings.osm_attribution}."
        ),
    )
    p.add_argument(
        "--bbox",
        nargs=4,
        type=float,
        metavar=("W", "S", "E", "N"),
        help="area in WGS84 degrees (default: the bundled extract's default area; with --osm, the bounds "
        "the file declares, else all of it)",
    )
    p.add_argument("--osm", type=Path, metavar="FILE", help=".osm, .osm.bz2, .osm.gz or .osm.pbf file")
    p.add_argument("-o", "--output", type=Path, default=Path("map.geojson"),
                   help="output GeoJSON (default: %(default)s)")
    p.add_argument("--overwrite", action="store_true", help=OVERWRITE_FILE_HELP)
    p.add_argument(
        "--unmarked-as",
        choices=UNMARKED_CHOICES,
        default=SegmentationConfig.unmarked_crossing_as,
        help="what unmarked crossings become (default: %(default)s)",
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


def run(args: argparse.Namespace) -> int:
    """Build the map and write it."""
    if Path(args.output).suffix.lower() not in (".geojson", ".json"):
        raise CurbsideInputError(args.output, "the map is GeoJSON: name it .geojson")
    check_output_file(args.output, args.overwrite, inputs=(args.osm,) if args.osm else ())
    config = with_overrides(
        SegmentationConfig(unmarked_crossing_as=args.unmarked_as), set_overrides(args.set)
    )
    layers = build_map(tuple(args.bbox) if args.bbox else None, args.osm, config=config)
    path = write_map(layers, args.output)
    out = sys.stdout
    out.write(f"wrote {path} ({layers.meta['source']}; {settings.osm_attribution})\n")
    for line in summary_lines(layers):
        out.write(line + "\n")
    inside = layers.meta.get("sidewalk_ways_in_buildings", 0.0)
    if inside > 0 and inside >= _conflict_share_min():
        out.write(
            f"{100 * inside:.1f} % of the mapped sidewalks (footway=sidewalk) run inside buildings: are the "
            "buildings misaligned with the streets? localize softens this map's walls "
            "(filter.map.conflict_wall_tolerance_m)\n"
        )
    return 0
