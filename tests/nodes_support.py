"""Shared helpers of the node-set tests: the axis config, private domains, the runner."""

from __future__ import annotations

import json
import os
import subprocess
import sys
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
