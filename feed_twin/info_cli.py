"""`feed-twin info`: versions of feed_twin and of the libraries it stands on."""

from __future__ import annotations

import argparse
import importlib.metadata
import re
import sys
from pathlib import Path

from feed_twin import __version__

_DISTRIBUTIONS = ("numpy", "scipy", "numba", "mcap", "rerun-sdk", "ros-jazzy-rclpy")


def configure(parser: argparse.ArgumentParser) -> None:
    del parser  # no options


def main(args: argparse.Namespace) -> int:
    del args
    print(f"feed_twin {__version__}")
    for dist in _DISTRIBUTIONS:
        try:
            version = importlib.metadata.version(dist)
        except importlib.metadata.PackageNotFoundError:
            version = "not installed"
        print(f"  {dist:<18} {version}")
    print(f"  {'feed_twin_msgs':<18} {_interface_package('feed_twin_msgs')}")
    return 0


def _interface_package(name: str) -> str:
    """Version and message types of an interface package installed into this environment's
    prefix, read from its share/ directory (no ROS import: this module is core)."""
    share = Path(sys.prefix) / "share" / name
    manifest = share / "package.xml"
    if not manifest.is_file():
        return "not installed (run `make setup`)"
    found = re.search(r"<version>\s*([^<\s]+)\s*</version>", manifest.read_text())
    messages = sorted(p.stem for p in (share / "msg").glob("*.msg"))
    return f"{found.group(1) if found else '?'} ({', '.join(messages)})"
