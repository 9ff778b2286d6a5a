"""CDR bytes of feed_twin_msgs/ServoSample (msgs/msg/ServoSample.msg) with one `struct`.

The LinuxCNC bridge sends one ServoSample per servo period (1 kHz). Building an rclpy message
and serialising it cost about 40 us a period, a fifth of the bridge's work on this host; the
strings of a run's samples never change (frame_id empty, the axis, the joint names) and every
array holds one value per joint, so the whole message is one precompiled struct, packed in a
few microseconds (the layout rules: feed_twin.io.cdr). Padding is zeroed, as on the wire.
tests/test_linuxcnc_servo_cdr.py checks the bytes against rclpy's serialiser.
"""

from __future__ import annotations

import struct
from collections.abc import Sequence

from feed_twin.io.cdr import ENCAPSULATION

# the float64[] fields after the joint names, in the message's order
ARRAYS = (
    "position_command",
    "velocity_command",
    "acceleration_command",
    "position_feedback",
    "following_error",
    "servo_output",
)


class ServoSampleLayout:
    """ServoSample of axis `axis` with joints `joints` and an empty frame_id: (sec, nanosec,
    tick, tick_time, line, then the ARRAYS' values joint by joint, array after array) -> CDR."""

    def __init__(self, axis: str, joints: Sequence[str]) -> None:
        if not joints:
            raise ValueError("joints: a servo sample needs at least one joint")
        fmt, offset = ["<"], 0
        fixed: list[object] = []  # the constant values, in order, None where a number goes

        def add(code: str, size: int, align: int, value: object = None) -> None:
            nonlocal offset
            pad = -offset % align
            fmt.append(f"{pad}x{code}" if pad else code)
            offset += pad + size
            fixed.append(value)

        def string(text: str) -> None:
            raw = text.encode("utf-8") + b"\0"
            add("I", 4, 4, len(raw))
            add(f"{len(raw)}s", len(raw), 1, raw)

        add("i", 4, 4)  # header.stamp.sec
        add("I", 4, 4)  # header.stamp.nanosec
        string("")  # header.frame_id (a signature takes its place: feed_twin.nodeset.auth)
        string(axis)
        add("Q", 8, 8)  # tick
        add("d", 8, 8)  # tick_time
        add("i", 4, 4)  # line
        add("I", 4, 4, len(joints))
        for name in joints:
            string(name)
        for _ in ARRAYS:
            add("I", 4, 4, len(joints))
            for _ in joints:
                add("d", 8, 8)
        self.joints = len(joints)
        self._struct = struct.Struct("".join(fmt))
        self._fixed = fixed
        self._slots = [i for i, value in enumerate(fixed) if value is None]

    def encode(
        self, sec: int, nanosec: int, tick: int, tick_time: float, line: int, values: Sequence
    ) -> bytes:
        """`values`: len(ARRAYS) x joints numbers, array after array (ARRAYS' order)."""
        if len(values) != len(ARRAYS) * self.joints:
            raise ValueError(
                f"values: {len(values)} numbers, expected {len(ARRAYS)} arrays x {self.joints} "
                "joints"
            )
        packed = self._fixed.copy()
        for slot, value in zip(self._slots, (sec, nanosec, tick, tick_time, line, *values),
                               strict=True):  # fmt: skip
            packed[slot] = value
        return ENCAPSULATION + self._struct.pack(*packed)
