"""``localize parameters`` and ``osmseg parameters``: every key that ``--set`` accepts, with its default.

::

    localize parameters [PATTERN] [--mode gnss|inertial|paper|fused] [--markdown]
    osmseg parameters [PATTERN] [--markdown]

The keys, values, types and descriptions come from the config dataclasses themselves
(:func:`curbside.configio.parameters`), so the listing cannot drift from the code.
``python -m curbside.cli.parameters`` prints ``docs/parameters.md``; a test keeps that page in step.
"""

from __future__ import annotations

import argparse
import json
import textwrap
from collections.abc import Iterable
from typing import TYPE_CHECKING

from curbside.errors import CurbsideInputError
from curbside.localize.runconstants import MODES

if TYPE_CHECKING:
    from curbside.configio import Parameter
    from curbside.localize.runconfig import RunConfig
    from curbside.osmseg.config import SegmentationConfig

_INTRO = """\
# Parameters

Every key that `--set KEY=VALUE` accepts, with its default and what it does: `localize run` and
`localize serve` take the run's keys (they are also the `config` member of a run's `run.json`, which
`localize run --config` replays), `osmseg build` the map's (recorded in the map's `params`). Examples:

```sh
localize run SESSION --map map.geojson --set filter.gnss.sigma_factor=1.0 -o out/t
osmseg build --set crosswalk_width_m=4 --set default_carriageway_width_m.residential=9 -o map.geojson
localize parameters gnss            # the same listing in the terminal, filtered
```

The defaults are curbside fused's; the column *paper* gives the value of `--mode paper` (the paper's
plain filter) where it differs. Why each value was chosen: [filter.md](filter.md) and
[tuning.md](tuning.md) for the filter, [osmseg.md](osmseg.md) for the map. This page is generated
from the code (`python -m curbside.cli.parameters > docs/parameters.md`); `tests/test_parameters.py`
fails when it falls out of step.
"""


def _matching(params: list[Parameter], pattern: str | None, where: str) -> list[Parameter]:
    if not pattern:
        return params
    found = [p for p in params if pattern.lower() in p.key.lower()]
    if not found:
        raise CurbsideInputError(where, f"no parameter key contains {pattern!r}")
    return found


def format_text(params: Iterable[Parameter], width: int = 100) -> str:
    """One ``key = value  (type)`` line per parameter and its description, indented."""
    lines = []
    for p in params:
        lines.append(f"{p.key} = {json.dumps(p.value)}  ({p.kind})")
        lines.extend(textwrap.wrap(p.description or "(no description)", width, initial_indent="    ",
                                   subsequent_indent="    "))
    return "\n".join(lines)


def _cell(text: str) -> str:
    return text.replace("|", "\\|")


def format_markdown(
    params: list[Parameter],
    summaries: dict[str, str],
    others: dict[str, object] | None = None,
    other_name: str = "",
) -> str:
    """A table per section (``### `section```, its summary), sections in order of first appearance;
    ``others`` adds a column of another preset's values where they differ."""
    by_section: dict[str, list[Parameter]] = {}
    for p in params:
        by_section.setdefault(p.key.rpartition(".")[0], []).append(p)
    columns = "| key | default | type |" + (f" {other_name} |" if others else "") + " description |"
    rule = "|---|---|---|" + ("---|" if others else "") + "---|"
    blocks: list[str] = []
    for section, members in by_section.items():
        head = f"`{section}`" if section else "Top level"
        blocks.append(f"### {head}\n\n{summaries.get(section, '')}\n\n{columns}\n{rule}")
        for p in members:
            other = ""
            if others is not None:
                value = others[p.key]
                other = f" `{json.dumps(value)}` |" if value != p.value else " |"
            blocks.append(f"| `{p.key}` | `{_cell(json.dumps(p.value))}` | {_cell(p.kind)} |{other} "
                          f"{_cell(p.description)} |")
        blocks.append("")
    return "\n".join(blocks)


def reference_markdown() -> str:
    """``docs/parameters.md``: the run's keys (with the paper preset's values) and the map build's."""
    from curbside.configio import parameters, sections
    from curbside.localize.runconfig import RunConfig
    from curbside.osmseg.config import SegmentationConfig

    run = RunConfig.for_mode("fused")
    paper = {p.key: p.value for p in parameters(RunConfig.for_mode("paper"))}
    osm = SegmentationConfig()
    return (
        f"{_INTRO}\n## `localize run`, `localize serve` (`RunConfig`)\n\n"
        + format_markdown(parameters(run), sections(run), paper, "paper")
        + "\n## `osmseg build` (`SegmentationConfig`)\n\n"
        + format_markdown(parameters(osm), sections(osm))
    )


def _list(args: argparse.Namespace) -> int:
    """Print the parameters of ``args.config(args)``, those whose key contains ``args.pattern``."""
    from curbside.configio import parameters, sections

    config = args.config(args)
    params = _matching(parameters(config), args.pattern, f"{args.prog} parameters")
    print(format_markdown(params, sections(config)) if args.markdown else format_text(params))
    return 0


def _add_parser(subparsers: argparse._SubParsersAction, what: str, example: str) -> argparse.ArgumentParser:
    parser = subparsers.add_parser(
        "parameters",
        help=f"list every parameter of {what} that --set accepts, with its default",
        description=f"List every key of {what} that --set KEY=VALUE accepts, with its default value, type "
        f"and what it does (docs/parameters.md has the same, for every command). Example: {example}",
    )
    parser.add_argument("pattern", nargs="?", metavar="PATTERN",
                        help="list only the keys that contain PATTERN (case-insensitive)")
    parser.add_argument("--markdown", action="store_true", help="Markdown tables instead of plain text")
    return parser


def register_localize(subparsers: argparse._SubParsersAction) -> None:
    """Add ``parameters`` to the ``localize`` sub-commands."""
    parser = _add_parser(subparsers, "a tracking run (localize run, localize serve)",
                         "localize parameters filter.gnss")
    parser.add_argument("--mode", choices=MODES, default="fused",
                        help="list the values of this method's defaults (default: fused)")
    parser.set_defaults(func=_list, prog="localize", config=_run_config)


def register_osmseg(subparsers: argparse._SubParsersAction) -> None:
    """Add ``parameters`` to the ``osmseg`` sub-commands."""
    parser = _add_parser(subparsers, "the map build (osmseg build)", "osmseg parameters width")
    parser.set_defaults(func=_list, prog="osmseg", config=_map_config)


def _run_config(args: argparse.Namespace) -> RunConfig:
    """The run configuration of ``--mode`` (imported here: the run configuration is slow to import)."""
    from curbside.localize.runconfig import RunConfig

    return RunConfig.for_mode(args.mode)


def _map_config(_args: argparse.Namespace) -> SegmentationConfig:
    """The map build's configuration."""
    from curbside.osmseg.config import SegmentationConfig

    return SegmentationConfig()


if __name__ == "__main__":
    print(reference_markdown(), end="")
