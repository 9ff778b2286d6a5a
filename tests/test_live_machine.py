"""`--live` in machine runs: a machine's recorder streams every axis it records, each axis a
recording of its own (feed_twin.nodeset.summary.LiveFeeds), read back from a real Rerun gRPC
server that saves what it receives. (The plans pass the live viewer to the recorder of a
machine's node set and to every twin of its shadow node set: tests/test_launch_plan.py.)"""

from __future__ import annotations

import re
import signal
import socket
import subprocess
import time

import pytest

from feed_twin.io import msg_types
from feed_twin.io.cdr import FlatCodec
from feed_twin.io.dashboard import rerun_binary
from feed_twin.nodeset.summary import LiveFeeds
from feed_twin.nodeset.topics import AxisTopics

URL = "rerun+http://127.0.0.1:9/proxy"


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _state(codec: FlatCodec, axis: str, k: int, x_m: float) -> bytes:
    values: dict = dict.fromkeys(codec.names, 0.0)
    values.update({
        "header.stamp.sec": 0, "header.stamp.nanosec": k * 1_000_000, "header.frame_id": "",
        "axis": axis, "table_position": x_m,
    })  # fmt: skip
    return codec.encode_map(values)


def _position_values(printed: str) -> set[float]:
    """The /position/table scalars [mm] in `rerun rrd print -vvv`'s tables."""
    values: set[float] = set()
    for block in printed.split("Chunk(")[1:]:
        if " - /position/table - " in block.splitlines()[0] and "Scalars:scalars" in block:
            values |= {float(v) for v in re.findall(r"┆ \[([-\d.e]+)\]", block)}
    return values


@pytest.mark.slow
def test_a_machines_recorder_streams_each_axis_as_its_own_recording(tmp_path) -> None:
    saved, port = tmp_path / "received.rrd", _free_port()
    server = subprocess.Popen(
        [str(rerun_binary()), "--save", str(saved), "--bind", "127.0.0.1", "--port", str(port)],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
    )  # fmt: skip
    try:
        deadline = time.monotonic() + 20.0
        while socket.socket().connect_ex(("127.0.0.1", port)) != 0:
            assert time.monotonic() < deadline and server.poll() is None, "no Rerun server"
            time.sleep(0.05)
        axes = [AxisTopics(machine="cnc", axis=a) for a in ("x", "y")]
        feeds = LiveFeeds(axes, f"rerun+http://127.0.0.1:{port}/proxy", decimation=10)
        codec = FlatCodec(msg_types.AXIS_STATE)
        for k in range(100):  # x at k mm, y at 500 + k mm
            feeds.feed("/cnc/x/state", _state(codec, "X", k, 1e-3 * k))
            feeds.feed("/cnc/y/state", _state(codec, "Y", k, 0.5 + 1e-3 * k))
        assert not feeds.wants("/cnc/z/state") and feeds.wants("/cnc/y/command")
        feeds.close()
        time.sleep(1.0)
    finally:
        server.send_signal(signal.SIGINT)  # it closes the file
        server.wait(timeout=20)
    printed = subprocess.run(
        [str(rerun_binary()), "rrd", "print", "-vvv", str(saved)],
        capture_output=True, text=True, timeout=60, check=True,
    ).stdout  # fmt: skip
    recordings = set(re.findall(r"Recording,\s+\"feed_twin\",\s+\"([^\"]+)\"", printed))
    assert sorted(r[-5:] for r in recordings) == ["cnc-x", "cnc-y"]  # one per axis
    assert len({r.removesuffix("-cnc-x").removesuffix("-cnc-y") for r in recordings}) == 1
    # every 10th state of each axis arrived, in mm
    expected = [float(k) for k in range(0, 100, 10)] + [500.0 + k for k in range(0, 100, 10)]
    assert sorted(_position_values(printed)) == pytest.approx(expected, abs=1e-9)


def test_live_feeds_need_an_axis() -> None:
    with pytest.raises(ValueError, match=r"^LiveFeeds needs the topics of at least one axis$"):
        LiveFeeds([], URL)
