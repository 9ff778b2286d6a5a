"""`feed-twin tune`: recommended gains and the margins of the configured loops of a config file."""

from __future__ import annotations

import argparse
import sys

from feed_twin.control.config import load_controller_config
from feed_twin.control.tuning import LoadMode, tune_config
from feed_twin.core.config import ConfigError, load_yaml


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--config", required=True, help="YAML file with a controller: section")
    parser.add_argument(
        "--load-mode-hz",
        type=float,
        default=None,
        help="first mode of the load against the motor [Hz] (limits Kv on a scale loop)",
    )
    parser.add_argument(
        "--load-mode-zeta",
        type=float,
        default=0.03,
        help="damping ratio of that mode [-] (default 0.03)",
    )


def main(args: argparse.Namespace) -> int:
    try:
        data = load_yaml(args.config)
        if "controller" not in data:
            raise ConfigError(f"{args.config}: no controller section")
        config = load_controller_config(data["controller"], source=str(args.config))
        load_mode = None
        if args.load_mode_hz is not None:
            load_mode = LoadMode(frequency_hz=args.load_mode_hz, zeta=args.load_mode_zeta)
    except ValueError as exc:
        print(f"feed-twin tune: {exc}", file=sys.stderr)
        return 2
    print(f"{args.config}: mode {config.mode}, base period {config.base_period_s * 1e6:g} us")
    for line in tune_config(config, load_mode=load_mode).lines():
        print(line)
    return 0
