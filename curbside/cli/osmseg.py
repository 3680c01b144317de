"""``osmseg``: derive, show and compare map layers.

Sub-commands live one per module (``osmseg_build``, ``osmseg_show``, ``osmseg_edit``,
``osmseg_compare``); each exposes ``register(subparsers)``. ``osmseg parameters`` lives with
``localize parameters`` in :mod:`curbside.cli.parameters`.
"""

from __future__ import annotations

from collections.abc import Sequence

from curbside.cli import osmseg_build, osmseg_compare, osmseg_edit, osmseg_show, parameters
from curbside.cli.common import make_parser, run_cli


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``osmseg`` console script."""
    parser = make_parser(
        "osmseg",
        "OpenStreetMap -> building, street, crosswalk and sidewalk-segment polygons. "
        "Map data © OpenStreetMap contributors (ODbL).",
    )
    sub = parser.add_subparsers(title="commands", metavar="COMMAND")
    for module in (osmseg_build, osmseg_show, osmseg_edit, osmseg_compare):
        module.register(sub)
    parameters.register_osmseg(sub)
    return run_cli("osmseg", parser, argv)


if __name__ == "__main__":
    raise SystemExit(main())
