"""`feed-twin bag info BAG` and `feed-twin bag recover BAG`: inspect and repair recordings."""

from __future__ import annotations

import argparse
import sys

from feed_twin.io import msg_types
from feed_twin.io.bag import BagError, BagInfo, info, recover

# Topics whose messages begin with their stamp (rosgraph Clock, std_msgs/Header first), in the
# order they are preferred as the simulated time base: sec (int32), nanosec (uint32) after the
# 4-byte CDR encapsulation header.
CLOCK_TOPIC = "/clock"
STAMPED_TYPES = (msg_types.CLOCK, msg_types.FEED_TWIN_PACKAGE, msg_types.JOINT_STATE)


def configure(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="bag_command", metavar="ACTION", required=True)
    p_info = sub.add_parser("info", help="print topics, types, message counts and duration")
    p_info.add_argument("bag", help="bag directory (or its .mcap file)")
    p_recover = sub.add_parser(
        "recover", help="make a killed recording readable again and regenerate metadata.yaml"
    )
    p_recover.add_argument("bag", help="bag directory (or its .mcap file)")


def simulated_span(bag: BagInfo) -> tuple[str, float] | None:
    """(topic, simulated duration [s]) from the stamps of the bag's first stamped topic."""
    import struct

    from mcap.reader import make_reader

    names = sorted(
        (t for t in bag.topics if t.message_count and t.type_name.startswith(STAMPED_TYPES)),
        key=lambda t: (t.name != CLOCK_TOPIC, t.name),
    )
    if not names:
        return None
    topic = names[0].name
    first: float | None = None
    last: float | None = None
    with open(bag.mcap_path, "rb") as handle:
        for _, _, message in make_reader(handle).iter_messages(topics=[topic]):
            sec, nsec = struct.unpack_from("<iI", message.data, 4)
            stamp = sec + nsec * 1e-9
            first = stamp if first is None else min(first, stamp)
            last = stamp if last is None else max(last, stamp)
    return None if first is None or last is None else (topic, last - first)


def with_simulated_duration(bag: BagInfo, text: str) -> str:
    """`bag.format()` with its duration line split into wall-clock and simulated time: the
    log times are when the recorder received the messages, the stamps the simulation's."""
    span = simulated_span(bag)
    simulated = "n/a (no stamped topic)" if span is None else f"{span[1]:.6f} s ({span[0]} stamps)"
    return text.replace(
        f"duration:  {bag.duration_s:.6f} s",
        f"duration:  {bag.duration_s:.6f} s wall clock (receive times)\nsimulated: {simulated}",
    )


def main(args: argparse.Namespace) -> int:
    try:
        if args.bag_command == "info":
            bag = info(args.bag)
            print(with_simulated_duration(bag, bag.format()))
            return 0
        result = recover(args.bag)
    except BagError as exc:
        print(f"feed-twin bag {args.bag_command}: {exc}", file=sys.stderr)
        return 1
    print(f"{result.text()}; metadata.yaml regenerated")
    print(with_simulated_duration(result.info, result.info.format()))
    return 0
