"""The installed `feed-twin` entry point lists every registered subcommand, and each one's
module provides configure(parser) and main(args)."""

from __future__ import annotations

import argparse
import importlib
import re
import subprocess
import sys
from pathlib import Path

import pytest

from feed_twin.cli import SUBCOMMANDS

FEED_TWIN = Path(sys.prefix) / "bin" / "feed-twin"


def test_the_entry_point_is_installed_and_lists_every_subcommand():
    assert FEED_TWIN.is_file(), f"{FEED_TWIN} missing: run `make setup`"
    result = subprocess.run(
        [str(FEED_TWIN), "--help"], capture_output=True, text=True, timeout=60, check=True
    )
    listed = result.stdout
    for cmd in SUBCOMMANDS:
        assert f"    {cmd.name}" in listed, f"{cmd.name} missing from feed-twin --help"
    assert "msgs-check" in listed


def test_subcommand_names_are_unique():
    names = [cmd.name for cmd in SUBCOMMANDS]
    assert len(names) == len(set(names)), names


@pytest.mark.parametrize("cmd", SUBCOMMANDS, ids=lambda c: c.name)
def test_every_subcommand_module_has_configure_and_main(cmd):
    module = importlib.import_module(cmd.module)
    assert callable(module.configure) and callable(module.main)
    parser = argparse.ArgumentParser(prog=f"feed-twin {cmd.name}")
    module.configure(parser)  # must not raise
    assert cmd.help


def test_an_unknown_subcommand_is_named():
    result = subprocess.run(
        [str(FEED_TWIN), "no-such-command"], capture_output=True, text=True, timeout=60
    )
    assert result.returncode == 2
    assert "unknown command 'no-such-command'; choose from " in result.stderr


def test_info_reports_the_installed_message_package():
    result = subprocess.run(
        [str(FEED_TWIN), "info"], capture_output=True, text=True, timeout=60, check=True
    )
    msgs = Path(__file__).parents[1] / "msgs"
    sources = sorted(p.stem for p in (msgs / "msg").glob("*.msg"))
    found = re.search(r"<version>(.+)</version>", (msgs / "package.xml").read_text())
    assert found is not None, "msgs/package.xml names its version"
    version = found[1]
    line = next(x for x in result.stdout.splitlines() if x.strip().startswith("feed_twin_msgs"))
    assert line.split(None, 1)[1] == f"{version} ({', '.join(sources)})"


def test_info_says_how_to_get_a_missing_message_package():
    from feed_twin.info_cli import _interface_package

    assert _interface_package("no_such_msgs") == "not installed (run `make setup`)"
