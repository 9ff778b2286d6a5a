"""Round trip of every message type feed_twin uses, over real DDS, field by field.

`filled_message` gives every leaf field of a message a distinct non-default value, so a field
that is dropped, truncated or swapped with another on the way shows up in `field_differences`.
`round_trip` publishes messages from one node and receives them in a second node of the same
process, through the RMW and DDS (not an intra-process shortcut: rclpy has none);
`round_trip_between_processes` receives them from a node in a child process. The CLI
`feed-twin msgs-check` runs both for all types in a private domain and reports the one-process
publish -> callback latency.
"""

from __future__ import annotations

import argparse
import importlib
import json
import math
import os
import re
import subprocess
import sys
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import rclpy
from feed_twin_msgs.msg import (
    AxisCommand,
    AxisFeedback,
    AxisState,
    DriveCommand,
    HealthStatus,
    ServoSample,
    TwinResidual,
)
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState

from feed_twin.ros.domain import private_graph_env, reserve_domain_id

FEED_TWIN_MESSAGE_TYPES: tuple[type, ...] = (
    AxisCommand,
    DriveCommand,
    AxisFeedback,
    AxisState,
    TwinResidual,
    HealthStatus,
    ServoSample,
)
# Standard messages the node set publishes alongside its own.
STANDARD_MESSAGE_TYPES: tuple[type, ...] = (JointState, Clock)
MESSAGE_TYPES = FEED_TWIN_MESSAGE_TYPES + STANDARD_MESSAGE_TYPES

_SEQUENCE_LENGTH = 3  # elements put into each unbounded sequence
_SIGNED = {"int8", "int16", "int32", "int64"}
_UNSIGNED = {"uint8", "uint16", "uint32", "uint64"}
_FLOATS = {"double", "float"}
_ARRAY = re.compile(r"^(?P<elem>[\w/]+)\[(?P<size>\d+)\]$")
_SEQUENCE = re.compile(r"^sequence<(?P<elem>[\w/]+)(?:,\s*(?P<bound>\d+))?>$")


def type_name(msg_type: type) -> str:
    """`pkg/msg/Type` of a generated message class."""
    package = msg_type.__module__.split(".")[0]
    return f"{package}/msg/{msg_type.__name__}"


def _message_class(type_string: str) -> type:
    package, name = type_string.split("/")
    return getattr(importlib.import_module(f"{package}.msg"), name)


class _Counter:
    def __init__(self, start: int) -> None:
        self.value = start

    def next(self) -> int:
        self.value += 1
        return self.value


def _scalar(type_string: str, counter: _Counter) -> Any:
    k = counter.next()
    if type_string in _FLOATS:
        return k + 0.125  # exact in float32 too, so a float field compares exactly
    if type_string in _SIGNED:
        return -(k % 100 + 1)  # negative: catches a signed field read as unsigned
    if type_string in _UNSIGNED:
        return k % 200 + 1
    if type_string == "boolean":
        return True
    if type_string == "string":
        return f"s{k}"
    if "/" in type_string:
        return _fill(_message_class(type_string)(), counter)
    raise ValueError(f"field type {type_string!r} is not supported by filled_message")


def _fill(message: Any, counter: _Counter) -> Any:
    for name, type_string in message.get_fields_and_field_types().items():
        if match := _ARRAY.match(type_string):
            values = [_scalar(match["elem"], counter) for _ in range(int(match["size"]))]
        elif match := _SEQUENCE.match(type_string):
            length = min(_SEQUENCE_LENGTH, int(match["bound"] or _SEQUENCE_LENGTH))
            values = [_scalar(match["elem"], counter) for _ in range(length)]
        else:
            values = _scalar(type_string, counter)
        setattr(message, name, values)
    return message


def filled_message(msg_type: type, *, seed: int = 0) -> Any:
    """A message of msg_type whose leaf fields all differ from their defaults and each other."""
    return _fill(msg_type(), _Counter(seed))


def _plain(value: Any) -> Any:
    if hasattr(value, "tolist"):  # array.array, numpy arrays
        return list(value.tolist())
    if isinstance(value, list | tuple):
        return list(value)
    return value


def field_differences(sent: Any, received: Any, prefix: str = "") -> list[str]:
    """Dotted paths of the fields whose values differ, as `path: sent != received`."""
    differences: list[str] = []
    for name in sent.get_fields_and_field_types():
        path = f"{prefix}{name}"
        a, b = getattr(sent, name), getattr(received, name)
        if hasattr(a, "get_fields_and_field_types"):
            differences += field_differences(a, b, prefix=f"{path}.")
            continue
        a, b = _plain(a), _plain(b)
        if a and isinstance(a, list) and hasattr(a[0], "get_fields_and_field_types"):
            if len(a) != len(b):
                differences.append(f"{path}: {len(a)} elements != {len(b)}")
            for index, (x, y) in enumerate(zip(a, b, strict=False)):
                differences += field_differences(x, y, prefix=f"{path}[{index}].")
        elif a != b:
            differences.append(f"{path}: {a!r} != {b!r}")
    return differences


@dataclass(frozen=True, kw_only=True)
class RoundTrip:
    """Outcome for one message: what came back, and how long publish -> callback took."""

    type_name: str
    sent: Any
    received: Any | None  # None when nothing arrived within the timeout
    latency_s: (
        float  # wall-clock time from publish() to the subscriber callback [s]; NaN if unknown
    )

    @property
    def differences(self) -> list[str]:
        if self.received is None:
            return ["nothing received"]
        return field_differences(self.sent, self.received)


def standard_messages() -> list[Any]:
    """One filled message of each of MESSAGE_TYPES, identical in every process."""
    return [filled_message(t, seed=100 * i) for i, t in enumerate(MESSAGE_TYPES)]


def _topic(index: int, message: Any) -> str:
    return f"/feed_twin_msgcheck/m{index}_{type(message).__name__}"


def _qos(depth: int) -> QoSProfile:
    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST, depth=max(1, depth), reliability=ReliabilityPolicy.RELIABLE
    )


def _check_timeout(timeout_s: float) -> None:
    if not timeout_s > 0.0:
        raise ValueError(f"timeout_s = {timeout_s!r}: must be > 0")


def _listen(node: Any, messages: Sequence[Any]) -> dict[int, tuple[Any, float]]:
    """Subscribe to each message's topic; the dict fills with (message, arrival time)."""
    received: dict[int, tuple[Any, float]] = {}
    for index, message in enumerate(messages):

        def on_message(msg: Any, index: int = index) -> None:
            received.setdefault(index, (msg, time.perf_counter()))

        node.create_subscription(type(message), _topic(index, message), on_message, _qos(1))
    return received


def _advertise(node: Any, messages: Sequence[Any]) -> list[Any]:
    return [node.create_publisher(type(m), _topic(i, m), _qos(1)) for i, m in enumerate(messages)]


def _spin_until(executor: Any, deadline: float, done: Any) -> bool:
    while not done():
        if time.monotonic() >= deadline:
            return False
        executor.spin_once(timeout_sec=0.01)
    return True


def _results(
    messages: Sequence[Any], received: dict[int, tuple[Any, float]], sent_at: dict[int, float]
) -> list[RoundTrip]:
    results = []
    for index, message in enumerate(messages):
        msg, at = received.get(index, (None, float("nan")))
        results.append(
            RoundTrip(
                type_name=type_name(type(message)),
                sent=message,
                received=msg,
                latency_s=at - sent_at.get(index, float("nan")),
            )
        )
    return results


def round_trip(
    messages: Sequence[Any], *, domain_id: int, timeout_s: float = 10.0
) -> list[RoundTrip]:
    """Publish each message from one node and receive it in another of this process, over DDS.

    Each message gets its own topic; publishing waits until the subscription is matched, so
    nothing is lost to discovery. Messages that do not arrive within timeout_s (wall clock, for
    the whole call) come back with `received=None`.
    """
    _check_timeout(timeout_s)
    context = Context()
    rclpy.init(context=context, domain_id=domain_id)
    deadline = time.monotonic() + timeout_s
    try:
        talker = rclpy.create_node("feed_twin_msgcheck_talker", context=context)
        listener = rclpy.create_node("feed_twin_msgcheck_listener", context=context)
        executor = SingleThreadedExecutor(context=context)
        executor.add_node(talker)
        executor.add_node(listener)
        received = _listen(listener, messages)
        publishers = _advertise(talker, messages)
        _spin_until(executor, deadline, lambda: all(p.get_subscription_count() for p in publishers))
        sent_at: dict[int, float] = {}
        for index, (publisher, message) in enumerate(zip(publishers, messages, strict=True)):
            sent_at[index] = time.perf_counter()
            publisher.publish(message)
        _spin_until(executor, deadline, lambda: len(received) == len(messages))
        executor.shutdown()
        talker.destroy_node()
        listener.destroy_node()
        return _results(messages, received, sent_at)
    finally:
        rclpy.shutdown(context=context)


def round_trip_between_processes(*, domain_id: int, timeout_s: float = 20.0) -> list[RoundTrip]:
    """Receive standard_messages() here, published by a node in a child process, over DDS.

    The child (`python -m feed_twin.ros.msgcheck --talker DOMAIN_ID`) builds the same messages,
    waits for the subscriptions, publishes and stays alive until this side has them all, so
    reliable delivery completes. Latencies are not measured across processes (NaN).
    """
    _check_timeout(timeout_s)
    messages = standard_messages()
    context = Context()
    rclpy.init(context=context, domain_id=domain_id)
    deadline = time.monotonic() + timeout_s
    child = None
    try:
        listener = rclpy.create_node("feed_twin_msgcheck_listener", context=context)
        executor = SingleThreadedExecutor(context=context)
        executor.add_node(listener)
        received = _listen(listener, messages)
        child = subprocess.Popen(
            [sys.executable, "-m", "feed_twin.ros.msgcheck", "--talker", str(domain_id)],
            stdin=subprocess.PIPE,
            env={**os.environ, **private_graph_env(domain_id)},
        )
        _spin_until(executor, deadline, lambda: len(received) == len(messages))
        executor.shutdown()
        listener.destroy_node()
        return _results(messages, received, {})
    finally:
        if child is not None:
            if child.stdin is not None:
                child.stdin.close()  # tells the talker it may go
            try:
                child.wait(timeout=5.0)
            except subprocess.TimeoutExpired:
                child.kill()
                child.wait()
        rclpy.shutdown(context=context)


def _talker_main(domain_id: int, timeout_s: float = 60.0) -> int:
    """The child side of round_trip_between_processes; exits when its stdin closes."""
    messages = standard_messages()
    context = Context()
    rclpy.init(context=context, domain_id=domain_id)
    try:
        talker = rclpy.create_node("feed_twin_msgcheck_talker", context=context)
        executor = SingleThreadedExecutor(context=context)
        executor.add_node(talker)
        publishers = _advertise(talker, messages)
        matched = _spin_until(
            executor,
            time.monotonic() + timeout_s,
            lambda: all(p.get_subscription_count() for p in publishers),
        )
        if not matched:
            print(
                f"msgcheck talker: no listener matched within {timeout_s} s (domain {domain_id})",
                file=sys.stderr,
            )
            return 1
        for publisher, message in zip(publishers, messages, strict=True):
            publisher.publish(message)
        # Keep the node (and its reliable writer history) alive until the listener is done.
        waiter = threading.Thread(target=sys.stdin.read, daemon=True)
        waiter.start()
        while waiter.is_alive():
            executor.spin_once(timeout_sec=0.05)
        executor.shutdown()
        talker.destroy_node()
        return 0
    finally:
        rclpy.shutdown(context=context)


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--timeout", type=float, default=20.0, help="seconds to wait for all messages [s]"
    )
    parser.add_argument("--json", action="store_true", help="print one JSON object last")


def _report(title: str, results: list[RoundTrip]) -> int:
    print(title)
    failures = 0
    for result in results:
        problems = result.differences
        failures += bool(problems)
        verdict = "ok" if not problems else "FAILED: " + "; ".join(problems)
        fields = len(result.sent.get_fields_and_field_types())
        latency = "" if math.isnan(result.latency_s) else f"{result.latency_s * 1e3:7.3f} ms  "
        print(
            f"  {result.type_name:<32} {fields:>3} field{'s' if fields != 1 else ' '}  "
            f"{latency}{verdict}"
        )
    return failures


def main(args: argparse.Namespace) -> int:
    with reserve_domain_id() as domain:
        # rcl reads the discovery range from the environment at init.
        os.environ.update(private_graph_env(domain.domain_id))
        same_process = round_trip(
            standard_messages(), domain_id=domain.domain_id, timeout_s=args.timeout
        )
        two_processes = round_trip_between_processes(
            domain_id=domain.domain_id, timeout_s=args.timeout
        )
    failed_here = _report(
        f"{len(same_process)} message types, two nodes in one process, over DDS "
        f"(domain {domain.domain_id}), publish -> callback:",
        same_process,
    )
    failed_across = _report(
        f"{len(two_processes)} message types from a node in a child process:", two_processes
    )
    if args.json:
        print(
            json.dumps(
                {
                    "types": len(same_process),
                    "failed_one_process": failed_here,
                    "failed_two_processes": failed_across,
                    "latency_ms": {r.type_name: r.latency_s * 1e3 for r in same_process},
                }
            )
        )
    return 1 if failed_here or failed_across else 0


if __name__ == "__main__":
    cli = argparse.ArgumentParser(prog="python -m feed_twin.ros.msgcheck")
    cli.add_argument("--talker", type=int, required=True, metavar="DOMAIN_ID")
    cli.add_argument("--timeout", type=float, default=60.0, help="wait for a listener [s]")
    options = cli.parse_args()
    sys.exit(_talker_main(options.talker, options.timeout))
