"""``osmseg``: derive, show and compare map layers.

Sub-commands live one per module (``osmseg_build``, ``osmseg_show``, ``osmseg_edit``,
``osmseg_compare``); each exposes ``register(subparsers)``. ``osmseg parameters`` lives with
``localize parameters`` in :mod:`curbside.cli.parameters`. The modules import what their command
needs when it runs, so that ``osmseg --help`` starts in a fraction of a second; a Ctrl-C while they
import still exits 130 with one line.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from curbside.cli.common import interrupted, make_parser, run_cli

if TYPE_CHECKING:
    from collections.abc import Sequence


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``osmseg`` console script."""
    try:
        from curbside.cli import osmseg_build, osmseg_compare, osmseg_edit, osmseg_show, parameters

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
    except KeyboardInterrupt:  # while the modules import or the arguments are parsed
        return interrupted("osmseg")


if __name__ == "__main__":
    raise SystemExit(main())
