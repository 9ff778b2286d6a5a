"""The trace of a node's loop splits a stall into CPU, run-queue wait, spans and the rest."""

from __future__ import annotations

import gc
import os
import subprocess
import sys
import time
from pathlib import Path

import pytest

from feed_twin.nodeset.turn_trace import NO_TRACE, TRACE_ENV, LoadedTrace, trace_from_environ


def _spin(seconds: float) -> None:
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        pass


def _traced(tmp_path: Path, body) -> LoadedTrace:
    trace = trace_from_environ("twin", {TRACE_ENV: str(tmp_path)})
    assert trace is not NO_TRACE
    trace.turn()
    body(trace)
    trace.turn()
    written = trace.write()
    assert written == tmp_path / f"twin_{os.getpid()}.npz"
    return LoadedTrace.load(tmp_path / f"twin_{os.getpid()}.npz")


def test_a_sleep_is_off_the_cpu_and_a_busy_span_on_it(tmp_path: Path) -> None:
    def body(trace) -> None:
        time.sleep(0.2)
        with trace.span("work", 7):
            _spin(0.1)

    loaded = _traced(tmp_path, body)
    summary = loaded.summary(top=1)
    turn = summary["turn_gap"]
    assert turn["count"] == 1
    (gap,) = turn["largest"]
    assert gap["wall_ms"] == pytest.approx(300.0, abs=60.0)
    # the busy span ran or waited for a CPU; the sleep was neither
    assert gap["cpu_ms"] + gap["runqueue_ms"] == pytest.approx(100.0, abs=30.0)
    assert gap["off_cpu_ms"] == pytest.approx(200.0, abs=40.0)
    assert gap["spans_ms"]["work"] == pytest.approx(100.0, abs=30.0)
    assert summary["spans"]["work"]["value_max"] == 7
    # the span's end is a sign of life: the sleep is the largest activity gap, alone
    largest = summary["activity_gap"]["largest"][0]
    assert largest["wall_ms"] == pytest.approx(200.0, abs=40.0)
    assert largest["cpu_ms"] < 20.0


def test_a_collection_is_a_span(tmp_path: Path) -> None:
    loaded = _traced(tmp_path, lambda trace: gc.collect())
    assert "gc2" in loaded.summary()["spans"]


@pytest.mark.skipif(not hasattr(os, "sched_setaffinity"), reason="needs CPU affinity")
def test_starvation_is_run_queue_wait(tmp_path: Path) -> None:
    """Sharing one CPU with a busy process at the same priority, a busy loop of 0.3 s wall
    time gets about half of it; the other half it waits on the run queue."""
    cpu = min(os.sched_getaffinity(0))
    before = os.sched_getaffinity(0)
    busy = subprocess.Popen([sys.executable, "-c", "while True: pass"])
    try:
        os.sched_setaffinity(busy.pid, {cpu})
        os.sched_setaffinity(0, {cpu})
        time.sleep(0.05)
        gap = _traced(tmp_path, lambda trace: _spin(0.3)).summary()["turn_gap"]["largest"][0]
    finally:
        os.sched_setaffinity(0, before)
        busy.kill()
        busy.wait()
    assert gap["runqueue_ms"] > 80.0
    assert gap["cpu_ms"] + gap["runqueue_ms"] == pytest.approx(gap["wall_ms"], rel=0.15)


def test_no_trace_unless_asked_and_a_bad_directory_named(tmp_path: Path) -> None:
    assert trace_from_environ("twin", {}) is NO_TRACE
    with NO_TRACE.span("work"):
        pass
    assert NO_TRACE.write() is None
    missing = tmp_path / "missing"
    with pytest.raises(ValueError, match=f"{TRACE_ENV} = '{missing}': not a directory"):
        trace_from_environ("twin", {TRACE_ENV: str(missing)})


def test_udp_drops_counts_what_a_full_receive_buffer_lost() -> None:
    import socket

    from feed_twin.nodeset.turn_trace import udp_drops

    before = udp_drops()
    reader = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    writer = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        reader.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
        reader.bind(("127.0.0.1", 0))
        for _ in range(200):  # never read: the buffer holds a few, the kernel drops the rest
            writer.sendto(b"x" * 1000, reader.getsockname())
        assert udp_drops() - before > 150
    finally:
        reader.close()
        writer.close()
    assert udp_drops() == before  # a closed socket's drops are no longer this process's
