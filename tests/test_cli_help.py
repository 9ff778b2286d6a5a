"""Every subcommand's help: each option explained, one example that names the subcommand."""

from __future__ import annotations

import argparse
import importlib
import shlex

import pytest

from feed_twin.cli import SUBCOMMANDS, main


def _parsers(parser: argparse.ArgumentParser, prefix: str):
    yield prefix, parser
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield from _parsers(sub, f"{prefix} {name}")


@pytest.mark.parametrize("cmd", SUBCOMMANDS, ids=lambda c: c.name)
def test_every_option_has_help(cmd) -> None:
    parser = argparse.ArgumentParser(prog=f"feed-twin {cmd.name}")
    importlib.import_module(cmd.module).configure(parser)
    silent = [
        f"{where}: {'/'.join(a.option_strings) or a.dest}"
        for where, p in _parsers(parser, cmd.name)
        for a in p._actions
        if not a.help and not isinstance(a, argparse._SubParsersAction)
    ]
    assert silent == []


@pytest.mark.parametrize("cmd", SUBCOMMANDS, ids=lambda c: c.name)
def test_the_help_ends_with_an_example_of_the_subcommand(cmd, capsys) -> None:
    with pytest.raises(SystemExit):
        main([cmd.name, "--help"])
    text = capsys.readouterr().out
    assert text.rstrip().endswith(f"example:\n  {cmd.example}")
    assert cmd.example.startswith(f"feed-twin {cmd.name}")


@pytest.mark.parametrize("cmd", SUBCOMMANDS, ids=lambda c: c.name)
def test_the_example_parses(cmd) -> None:
    parser = argparse.ArgumentParser(prog=f"feed-twin {cmd.name}")
    importlib.import_module(cmd.module).configure(parser)
    parser.parse_args(shlex.split(cmd.example)[2:])
