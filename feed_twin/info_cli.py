"""`feed-twin info`: versions of feed_twin and of the libraries it stands on."""

from __future__ import annotations

import argparse
import importlib.metadata

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
    return 0
