"""The twin node in-process (no peers, no DDS traffic): a health verdict that rises from WARN to
ERROR is published and logged both times (rclpy refuses a log call site whose severity changes,
which used to kill the twin at the first ERROR after a WARN)."""

from __future__ import annotations

import argparse
from pathlib import Path

import pytest

from feed_twin.analysis.twin import ModelDoc, Twin
from feed_twin.ros.dds import init_context
from feed_twin.shadow.health import ERROR, OK, WARN, Verdict
from feed_twin.shadow.standin import write_map

pytestmark = [pytest.mark.ros]
CONFIG = Path("config/emps.yaml")


def verdict(level: int, t_s: float) -> Verdict:
    return Verdict(
        t_s=t_s, level=level, fe_dev_rms_m=1e-6, effort_dev_rms=2.0, baseline_fe_dev_rms_m=1e-7,
        baseline_effort_dev_rms=0.5, message=f"level {level} at {t_s}",
    )  # fmt: skip


def test_rising_verdicts_are_published_and_logged_without_killing_the_node(tmp_path) -> None:
    from feed_twin.ros import twin_node

    map_path = write_map(tmp_path / "map.yaml", Twin.compile(ModelDoc.load(CONFIG)), "/cnc/x")
    parser = argparse.ArgumentParser()
    twin_node.configure(parser)
    args = parser.parse_args(["--config", str(CONFIG), "--map", str(map_path)])
    context = init_context()
    try:
        node = twin_node.build(args, context)
        sent: list[bytes] = []
        # what goes out on <ns>/twin/health, caught by a stand-in for the publisher's method
        node._health_pub.publish = sent.append  # pyright: ignore[reportAttributeAccessIssue]
        for level, t_s in ((WARN, 1.0), (ERROR, 2.0), (WARN, 3.0), (OK, 4.0), (ERROR, 5.0)):
            node._verdict(verdict(level, t_s))
        assert len(sent) == 5
        assert not node.done
        node.liveness.stop()
        node.destroy_node()
    finally:
        context.try_shutdown()


AXIS_CONFIG = Path("config/axis_default.yaml")


def _bridge_twin(tmp_path: Path, context, *batch: str):
    """A twin node as the LinuxCNC bridge's run builds it (no effort), its residuals and
    states captured (packed with --batch-topic: `unpacked` takes them out)."""
    from feed_twin.ros import twin_node

    twin = Twin.compile(ModelDoc.load(AXIS_CONFIG))
    tmp_path.mkdir()
    map_path = write_map(tmp_path / "map.yaml", twin, "/cnc/x", with_effort=False)
    parser = argparse.ArgumentParser()
    twin_node.configure(parser)
    args = parser.parse_args(["--config", str(AXIS_CONFIG), "--map", str(map_path), *batch])
    node = twin_node.build(args, context)
    sent: list[bytes] = []
    states: list[bytes] = []
    # stand-ins for the publishers' methods catch what goes out (a batch: read by `unpacked`)
    if batch:
        node._batch_pub.publish = sent.append  # pyright: ignore[reportAttributeAccessIssue]
    else:
        node._residual_pub.publish = sent.append  # pyright: ignore[reportAttributeAccessIssue]
        node._state_pub.publish = states.append  # pyright: ignore[reportAttributeAccessIssue]
    return node, sent, states


def unpacked(batches: list[bytes]) -> tuple[list[bytes], list[bytes]]:
    """The residuals and states in a twin's packed outputs, each in order."""
    from feed_twin.nodeset.record_batch import unpack

    out: dict[str, list[bytes]] = {"/cnc/x/twin/residual": [], "/cnc/x/twin/state": []}
    for data in batches:
        for topic, _, message in unpack(data):
            out[topic].append(message)
    return out["/cnc/x/twin/residual"], out["/cnc/x/twin/state"]


def _periods(n: int) -> list[tuple[int, bytes, bytes | None]]:
    """(stamp, command, joint_states or None) of `n` periods of a ramp, as the bridge makes
    them: row k's feedback is period k - 1's."""
    from feed_twin.io import msg_types
    from feed_twin.io.cdr import FlatCodec
    from feed_twin.shadow.bagstreams import encode_joint_state

    command = FlatCodec(msg_types.AXIS_COMMAND).fixed({"header.frame_id": "", "axis": "X"})
    out = []
    for k in range(n):
        stamp = k * 1_000_000
        x, v = 1e-5 * k * k, 2e-2 * k
        cmd = command.encode((stamp // 10**9, stamp % 10**9, x, v, 0.0, 7))
        prev = (k - 1) * 1_000_000
        js = encode_joint_state(prev, ["x"], [1e-5 * (k - 1) ** 2 - 1e-6], [], []) if k else None
        out.append((stamp, cmd, js))
    return out


def test_a_twin_fed_packed_periods_gives_the_output_it_gives_fed_one_message_each(
    tmp_path: Path,
) -> None:
    """The bridge's RecordBatches (twin_node --batch-topic) against per-topic messages: the
    same residuals, byte for byte, and a malformed batch is dropped and said."""
    from feed_twin.nodeset.record_batch import RecordBatch

    periods = _periods(400)
    context = init_context()
    try:
        single, single_out, _ = _bridge_twin(tmp_path / "a", context)
        for _, cmd, js in periods:
            single._on_command(cmd)
            if js is not None:
                single._on_measured(js)
        single._step(final=True)
        packed, packed_batches, _ = _bridge_twin(
            tmp_path / "b", context, "--batch-topic", "/cnc/x/linuxcnc/batch"
        )
        batch = RecordBatch(["/cnc/x/command", "/cnc/x/joint_states", "/cnc/x/other"], 1)
        for start in range(0, len(periods), 37):
            for _, cmd, js in periods[start : start + 37]:
                batch.add(0, cmd, 0)
                if js is not None:
                    batch.add(1, js, 0)
                batch.add(2, b"ignored: a topic the twin does not read", 0)
            data = batch.take()
            assert data is not None
            packed._on_batch(data)
        logged: list[str] = []

        class Log:
            def error(self, text: str) -> None:
                logged.append(text)

        packed.get_logger = Log  # pyright: ignore[reportAttributeAccessIssue]  a stand-in
        packed._on_batch(b"\x00\x00\x00\x00 not a batch")
        turns = packed.liveness.turns
        packed._step(final=True)
        assert packed.liveness.turns == turns + 1  # a step is progress its beats carry
        assert len(single_out) == len(periods) - 1  # every measured sample shadowed
        # a packed output per step, at most OUT_BATCH_SAMPLES slots each
        assert 1 < len(packed_batches) < len(periods) / 10
        packed_out, packed_states = unpacked(packed_batches)
        from feed_twin.ros.twin_node import RESIDUAL

        # the fixed-layout bytes are what the general encoder makes of the same values
        assert all(RESIDUAL.encode_map(RESIDUAL.decode_map(d)) == d for d in packed_out)
        from feed_twin.ros.twin_node import STATE

        states = [STATE.decode_map(d) for d in packed_states]
        assert all(STATE.encode_map(m) == d for m, d in zip(states, packed_states, strict=True))
        got = [RESIDUAL.decode_map(d) for d in packed_out]
        assert [m["following_error"] for m in states] == [m["following_error_twin"] for m in got]
        want = [RESIDUAL.decode_map(d) for d in single_out]
        assert len(got) == len(want)
        for g, w in zip(got, want, strict=True):
            # the rolling RMS sums over whatever block the twin advanced: the last digit
            rms = "following_error_deviation_rms"
            assert g.pop(rms) == pytest.approx(w.pop(rms), rel=1e-12)
            assert str(g) == str(w)  # (str: NaN efforts compare equal)
        assert packed.errors == 1
        assert logged == [
            "undecodable message dropped: not little-endian CDR (encapsulation header)"
        ]
        for node in (single, packed):
            node.liveness.stop()
            node.destroy_node()
    finally:
        context.try_shutdown()
