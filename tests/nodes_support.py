"""Shared helpers of the node-set tests: the axis config, private domains, the runner."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import time
from collections.abc import Iterable
from pathlib import Path

from feed_twin.ros.domain import private_graph_env

ROOT = Path(__file__).resolve().parents[1]
AXIS_CONFIG = ROOT / "config" / "axis_default.yaml"  # with its nc: and ros: sections
SHORT_PROGRAM = "%\nG21 G90 G54 G64\nG1 X10 F3000\nM30\n%\n"


def node_env(domain_id: int) -> dict[str, str]:
    env = dict(os.environ)
    env.update(private_graph_env(domain_id))
    return env


def start_run(args: list[str], domain_id: int, **popen) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-m", "feed_twin.cli", "run", *args],
        env=node_env(domain_id),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        **popen,
    )


def run(args: list[str], domain_id: int, timeout_s: float = 240.0) -> tuple[int, str, str]:
    proc = start_run(args, domain_id)
    try:
        out, err = proc.communicate(timeout=timeout_s)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate(timeout=10)
    return proc.returncode, out, err


def last_json(stdout: str) -> dict:
    return json.loads(stdout.strip().splitlines()[-1])


def found(pattern: str, text: str) -> re.Match[str]:
    """The first match of `pattern` in `text` (a log the test reads); fails showing the text."""
    match = re.search(pattern, text)
    assert match is not None, f"{pattern!r} not in:\n{text}"
    return match


def raw_topics(bag: str) -> dict[str, list[bytes]]:
    """Every topic's message bytes in the bag, in the order written (as the nodes made them:
    the run's signatures do not reach the bag)."""
    from mcap.reader import make_reader

    from feed_twin.io.bag import info

    out: dict[str, list[bytes]] = {}
    with open(info(bag).mcap_path, "rb") as f:
        for _, channel, message in make_reader(f).iter_messages(log_time_order=False):
            out.setdefault(channel.topic, []).append(message.data)
    return out


def wait_for(path: Path, pattern: str, proc, timeout_s: float = 120.0) -> None:
    """Until `pattern` appears in the log `path` of the run `proc` (which must not end first)."""
    wait_for_all(path.parent, [pattern], proc, timeout_s, files=path.name)


def wait_for_all(
    logs: Path, patterns: Iterable[str], proc, timeout_s: float, files: str = "*.log"
) -> None:
    """Until every regex of `patterns` appears in one of the run's logs (`logs`/`files`); fails
    naming the ones that never did, or at once when the run `proc` ends first."""
    missing = list(patterns)
    deadline = time.monotonic() + timeout_s
    while missing and time.monotonic() < deadline:
        if proc.poll() is not None:
            raise AssertionError(f"the run ended early: {proc.stderr.read()}")
        text = "".join(p.read_text(errors="replace") for p in sorted(logs.glob(files)))
        missing = [m for m in missing if not re.search(m, text)]
        if missing:
            time.sleep(0.1)
    assert not missing, f"not in the run's logs ({logs}) within {timeout_s} s: {missing}"


class Operator:
    """A person at the run's G-code node, in this process: calls its std_srvs/Trigger services
    (`start` resumes after M0). Made before the run's nodes exist, its discovery of them (up
    to a few seconds) overlaps their start-up."""

    def __init__(self, domain_id: int) -> None:
        import rclpy
        from rclpy.executors import SingleThreadedExecutor

        from feed_twin.ros.dds import init_context

        self.context = init_context(domain_id=domain_id)
        self.node = rclpy.create_node("operator", context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)

    def press(self, service: str, timeout_s: float = 30.0) -> str:
        """Call the Trigger `service`; its response message (fails unless it succeeded)."""
        from std_srvs.srv import Trigger

        client = self.node.create_client(Trigger, service)
        assert client.wait_for_service(timeout_sec=timeout_s), f"no service {service}"
        future = client.call_async(Trigger.Request())
        deadline = time.monotonic() + timeout_s
        while not future.done() and time.monotonic() < deadline:
            self.executor.spin_once(timeout_sec=0.1)
        assert future.done(), f"{service}: no response within {timeout_s} s"
        response = future.result()
        assert response is not None and response.success, f"{service}: {response}"
        return response.message

    def close(self) -> None:
        self.executor.shutdown(timeout_sec=1.0)
        self.node.destroy_node()
        self.context.try_shutdown()

    def __enter__(self) -> Operator:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
