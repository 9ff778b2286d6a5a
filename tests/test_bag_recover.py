"""A recording killed with SIGKILL loses at most about one flush period and is recoverable."""

from __future__ import annotations

import os
import re
import signal
import struct
import subprocess
import sys
import time
from pathlib import Path

import pytest
from rosbags.rosbag2 import Reader
from rosbags.typesys import Stores, get_typestore
from rosbags_support import decode

from feed_twin.cli import main as cli_main
from feed_twin.io.bag import BagError, BagReader, info, recover

FLUSH_PERIOD_S = 0.25
RATE_HZ = 1000.0

# The child records std_msgs/Float64 messages whose value is their index, at about RATE_HZ, and
# reports how many it has written; the parent kills it mid-stream.
CHILD = f"""
import struct, sys, time
from feed_twin.io.bag import BagWriter
bag = BagWriter(sys.argv[1], flush_period_s={FLUSH_PERIOD_S})
bag.add_topic("/m/x/value", "std_msgs/msg/Float64")
k = 0
start = time.monotonic()
while True:
    data = b"\\x00\\x01\\x00\\x00" + struct.pack("<d", float(k))
    bag.write("/m/x/value", data, log_time_ns=k * 1_000_000)
    k += 1
    if k % 50 == 0:
        print(k, flush=True)
    while time.monotonic() - start < k / {RATE_HZ}:
        time.sleep(0.0002)
"""


def run_and_kill(bag: Path, seconds: float) -> int:
    proc = subprocess.Popen(
        [sys.executable, "-c", CHILD, str(bag)], stdout=subprocess.PIPE, text=True
    )
    assert proc.stdout is not None, "started with stdout=PIPE"
    written = 0
    try:
        deadline = time.monotonic() + 30.0
        while time.monotonic() < deadline:
            line = proc.stdout.readline()
            if not line:
                break
            written = int(line)
            if written >= seconds * RATE_HZ:
                break
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(timeout=10)
    finally:
        if proc.poll() is None:
            proc.kill()
        proc.stdout.close()
    assert written >= seconds * RATE_HZ, "the writer process did not get going"
    return written


def test_sigkilled_recording_is_recovered_and_read_by_rosbags(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    bag = tmp_path / "killed"
    written = run_and_kill(bag, seconds=1.5)
    mcap = bag / "killed_0.mcap"
    assert mcap.stat().st_size > 0
    assert not (bag / "metadata.yaml").exists()
    with pytest.raises(BagError, match=r"run `feed-twin bag recover .*killed`"):
        info(bag)

    assert cli_main(["bag", "recover", str(bag)]) == 0
    out = capsys.readouterr().out
    assert re.search(
        r"^recovered \d+ messages in \d+ complete chunks \(\d+ bytes kept, .*\); indexed in "
        r"place; metadata.yaml regenerated$",
        out,
        re.MULTILINE,
    ), out
    assert not list(bag.glob("*.recovering"))  # no second copy

    store = get_typestore(Stores.ROS2_JAZZY)
    with Reader(bag) as reader:
        values = [decode(store, raw, conn.msgtype).data for conn, _, raw in reader.messages()]
    kept = len(values)
    # Every message up to the last flush survives, in order; at most one flush period (plus
    # scheduling slack of one more) of the stream is lost.
    assert values == [float(k) for k in range(kept)]
    assert kept >= written - 2 * FLUSH_PERIOD_S * RATE_HZ
    assert kept <= written + 100
    assert info(bag).message_count == kept
    assert BagReader(bag).columns("/m/x/value", ["data"])["data"][-1] == kept - 1


def test_recover_of_a_complete_bag_keeps_everything(tmp_path: Path) -> None:
    from feed_twin.io.bag import BagWriter

    bag = tmp_path / "whole"
    with BagWriter(bag) as writer:
        writer.add_topic("/v", "std_msgs/msg/Float64")
        for k in range(10):
            writer.write("/v", b"\x00\x01\x00\x00" + struct.pack("<d", k), log_time_ns=k)
    result = recover(bag)
    assert result.was_complete
    assert result.messages_recovered == 10
    assert result.info.topics[0].type_name == "std_msgs/msg/Float64"


def test_recover_error_messages(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    junk = tmp_path / "junk"
    junk.mkdir()
    (junk / "junk_0.mcap").write_bytes(b"not an mcap file at all")
    with pytest.raises(BagError, match=r"junk_0.mcap: nothing recoverable: not an MCAP file"):
        recover(junk)
    assert cli_main(["bag", "recover", str(tmp_path / "missing")]) == 1
    assert "feed-twin bag recover: " in capsys.readouterr().err
    assert cli_main(["bag", "recover", str(tmp_path / "missing")]) == 1
    assert "missing: no such bag directory" in capsys.readouterr().err
