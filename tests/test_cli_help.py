"""Every command explains itself: a description, a help text for each option, the default shown where
an option has one, and no raw reStructuredText in what ``--help`` prints."""

from __future__ import annotations

import argparse

import pytest

from curbside.cli import localize, osmseg

# `localize run`'s options are being rewritten with the filter; only its description is checked here.
DEFAULTS_UNCHECKED: set[tuple[str, str]] = set()


def _subcommands(module, name: str) -> list[tuple[str, str, argparse.ArgumentParser]]:
    captured = {}

    def run_cli(prog, parser, argv):
        captured["parser"] = parser
        return 0

    original = module.run_cli
    module.run_cli = run_cli
    try:
        module.main([])
    finally:
        module.run_cli = original
    parser = captured["parser"]
    (sub,) = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    return [(name, command, p) for command, p in sub.choices.items()]


COMMANDS = _subcommands(localize, "localize") + _subcommands(osmseg, "osmseg")


@pytest.mark.parametrize(("prog", "command", "parser"), COMMANDS, ids=[f"{p} {c}" for p, c, _ in COMMANDS])
def test_every_command_has_a_description_and_every_option_a_help(prog, command, parser):
    assert parser.description and len(parser.description) > 40, f"{prog} {command}: no description"
    text = parser.format_help()
    raw_rst = "``" in text or any(line.rstrip().endswith("::") for line in text.splitlines())
    assert not raw_rst, f"{prog} {command}: raw RST in --help"
    for action in parser._actions:
        if isinstance(action, argparse._HelpAction):
            continue
        name = "/".join(action.option_strings) or action.dest
        assert action.help, f"{prog} {command} {name}: no help"
        has_default = action.default not in (None, False, [], argparse.SUPPRESS) and not action.required
        if has_default and action.option_strings and (prog, command) not in DEFAULTS_UNCHECKED:
            assert "default" in action.help, f"{prog} {command} {name}: default {action.default!r} not shown"
