"""The README is a way in that works: at most about 200 lines, every short command in it runs,
every long one names a subcommand, options and files that exist; every repository path and
dotted name the docs/ pages cite resolves."""

from __future__ import annotations

import argparse
import importlib
import re
import shlex
from pathlib import Path

import pytest

from feed_twin.cli import SUBCOMMANDS
from feed_twin.cli import main as cli_main

ROOT = Path(__file__).resolve().parent.parent
README = ROOT / "README.md"
DOCS = sorted((ROOT / "docs").glob("*.md"))
SHARED = Path("/work/shared")  # the project's shared data (../shared from the main checkout)
RUN_THEM = {"info", "tune"}  # short enough to run here (model compiles the kernel: parsed only)
REPO_DIRS = ("feed_twin/", "tests/", "config/", "benchmarks/", "tools/", "docs/", "msgs/")


def commands(text: str) -> list[list[str]]:
    """The command lines of the ```sh blocks (continuations joined, comments dropped)."""
    out = []
    for block in re.findall(r"```sh\n(.*?)```", text, re.S):
        for line in block.replace("\\\n", " ").splitlines():
            words = shlex.split(line, comments=True)
            if words:
                out.append(words)
    return out


def test_the_readme_is_short() -> None:
    assert len(README.read_text().splitlines()) <= 200


@pytest.mark.parametrize("words", commands(README.read_text()), ids=lambda w: " ".join(w[:3]))
def test_every_readme_command_names_what_exists(words: list[str], capsys) -> None:
    program = words[0]
    if program == "make":
        targets = re.findall(r"^([\w-]+):", (ROOT / "Makefile").read_text(), re.M)
        assert set(words[1:]) <= set(targets), words
        return
    if program == ".venv/bin/rerun":
        assert words[1] == "--serve-web"
        return
    assert program in (".venv/bin/feed-twin", "feed-twin"), words
    by_name = {c.name: c for c in SUBCOMMANDS}
    cmd = by_name[words[1]]
    parser = argparse.ArgumentParser(prog=f"feed-twin {cmd.name}")
    importlib.import_module(cmd.module).configure(parser)
    args = parser.parse_args(words[2:])  # every option exists, every value parses
    for word in words[2:]:
        if word.startswith(("config/", "tests/")):
            assert (ROOT / word).exists(), word
        elif word.startswith("../shared/") and SHARED.is_dir():
            assert (SHARED / word.removeprefix("../shared/")).exists(), word
    if cmd.name in RUN_THEM:
        assert cli_main(words[1:]) == 0, capsys.readouterr().err
    del args


def _paths(text: str) -> set[str]:
    found = set()
    for token in re.findall(r"`([^`\s]+)`", text) + re.findall(r"\]\(([^)\s]+)\)", text):
        token = token.rstrip(".,;:)").split("::")[0].split("#")[0]
        token = re.sub(r":\d+(-\d+)?$", "", token)
        if token.startswith(REPO_DIRS) and not re.search(r"[<>*{}$]|\.\.\.|NAME|PROGRAM", token):
            found.add(token)
    return found


def _dotted(text: str) -> set[str]:
    return {m.rstrip(".") for m in re.findall(r"\bfeed_twin(?:\.[A-Za-z_]\w*)+", text)}


def _resolves(name: str) -> bool:
    parts = name.split(".")
    for cut in range(len(parts), 0, -1):
        try:
            obj = importlib.import_module(".".join(parts[:cut]))
        except ImportError:
            continue
        for attr in parts[cut:]:
            if not hasattr(obj, attr):
                return False
            obj = getattr(obj, attr)
        return True
    return False


@pytest.mark.parametrize("page", [README, *DOCS], ids=lambda p: p.name)
def test_every_path_and_dotted_name_in_the_docs_resolves(page: Path) -> None:
    text = page.read_text()
    missing = sorted(
        p for p in _paths(text) if not (ROOT / p).exists() and not (page.parent / p).exists()
    )
    assert missing == [], missing
    unresolved = sorted(n for n in _dotted(text) if not _resolves(n))
    assert unresolved == [], unresolved


def test_architecture_no_longer_cites_the_removed_edits_module() -> None:
    assert "`edits." not in (ROOT / "docs" / "architecture.md").read_text()


def test_the_benchmarks_page_is_what_the_saved_results_make() -> None:
    import runpy

    page = runpy.run_path(str(ROOT / "tools" / "benchmarks_page.py"))
    assert (ROOT / "docs" / "benchmarks.md").read_text() == page["page"]()
