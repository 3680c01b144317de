"""``localize``: sessions, inertial odometry, the particle filter, simulation and evaluation.

Sub-commands live one per module; each exposes ``register(subparsers)`` (``parameters``, shared with
``osmseg``, exposes ``register_localize``). The modules import what their command needs when it runs,
so that ``localize --help`` starts in a fraction of a second; a Ctrl-C while they import still exits
130 with one line.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from curbside.cli.common import interrupted, make_parser, run_cli

if TYPE_CHECKING:
    from collections.abc import Sequence


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``localize`` console script."""
    try:
        from curbside.cli import (
            localize_convert,
            localize_evaluate,
            localize_ronin,
            localize_run,
            localize_serve,
            localize_view,
            parameters,
        )

        parser = make_parser(
            "localize",
            "Track a pedestrian from phone IMU and GNSS with a map-aware particle filter.",
        )
        sub = parser.add_subparsers(title="commands", metavar="COMMAND")
        for module in (localize_run, localize_view, localize_convert, localize_ronin, localize_evaluate,
                       localize_serve):
            module.register(sub)
        parameters.register_localize(sub)
        return run_cli("localize", parser, argv)
    except KeyboardInterrupt:  # while the modules import or the arguments are parsed
        return interrupted("localize")


if __name__ == "__main__":
    raise SystemExit(main())
