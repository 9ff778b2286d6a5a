"""`feed-twin tune`: recommended gains and the margins of the configured loops of a config file."""

from __future__ import annotations

import argparse
import sys

from feed_twin.control.cascade import load_controller_config
from feed_twin.control.tuning import tune_config
from feed_twin.io.config import ConfigError, load_yaml


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--config", required=True, help="YAML file with a controller: section")


def main(args: argparse.Namespace) -> int:
    try:
        data = load_yaml(args.config)
        if "controller" not in data:
            raise ConfigError(f"{args.config}: no controller section")
        config = load_controller_config(data["controller"], source=str(args.config))
    except ConfigError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(f"{args.config}: mode {config.mode}, base period {config.base_period_s * 1e6:g} us")
    for line in tune_config(config).lines():
        print(line)
    return 0
