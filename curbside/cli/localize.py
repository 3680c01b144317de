"""``localize``: sessions, inertial odometry, the particle filter, simulation and evaluation.

Sub-commands live one per module; each exposes ``register(subparsers)`` (``parameters``, shared with
``osmseg``, exposes ``register_localize``).
"""

from __future__ import annotations

from collections.abc import Sequence

from curbside.cli import (
    localize_convert,
    localize_evaluate,
    localize_ronin,
    localize_run,
    localize_serve,
    localize_view,
    parameters,
)
from curbside.cli.common import make_parser, run_cli


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``localize`` console script."""
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


if __name__ == "__main__":
    raise SystemExit(main())
