"""`feed-twin bag info BAG` and `feed-twin bag recover BAG`: inspect and repair recordings."""

from __future__ import annotations

import argparse
import sys

from feed_twin.io.bag import BagError, info, recover


def configure(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="bag_command", metavar="ACTION", required=True)
    p_info = sub.add_parser("info", help="print topics, types, message counts and duration")
    p_info.add_argument("bag", help="bag directory (or its .mcap file)")
    p_recover = sub.add_parser(
        "recover", help="make a killed recording readable again and regenerate metadata.yaml"
    )
    p_recover.add_argument("bag", help="bag directory (or its .mcap file)")


def main(args: argparse.Namespace) -> int:
    try:
        if args.bag_command == "info":
            print(info(args.bag).format())
            return 0
        result = recover(args.bag)
    except BagError as exc:
        print(f"feed-twin bag {args.bag_command}: {exc}", file=sys.stderr)
        return 1
    state = "was already complete" if result.was_complete else "was truncated"
    print(
        f"recovered {result.messages_recovered} messages; the file {state}; "
        f"metadata.yaml regenerated"
    )
    print(result.info.format())
    return 0
