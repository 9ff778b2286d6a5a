"""CDR bytes of feed_twin_msgs/ServoSample (msgs/msg/ServoSample.msg) with one `struct`.

The LinuxCNC bridge sends one ServoSample per servo period (1 kHz). Building an rclpy message
and serialising it cost about 40 us a period, a fifth of the bridge's work on this host; the
strings of a run's samples never change (frame_id empty, the axis, the joint names) and every
array holds one value per joint, so the whole message is one precompiled struct, packed in a
few microseconds (the layout rules: feed_twin.io.cdr). Padding is zeroed, as on the wire.
The same layout reads a bag's samples back as arrays (`from_message`, `read`), thousands of
times faster than a generic decoder. tests/test_linuxcnc_servo_cdr.py checks the bytes against
rclpy's serialiser.
"""

from __future__ import annotations

import struct
from collections.abc import Sequence

import numpy as np

from feed_twin.io.bag.raw import column
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

_NUMPY = {"i": "<i4", "I": "<u4", "Q": "<u8", "d": "<f8"}  # struct code -> numpy dtype


class ServoSampleLayout:
    """ServoSample of axis `axis` with joints `joints` and frame_id `frame_id` (empty when
    sent: a signature takes its place, feed_twin.nodeset.auth): (sec, nanosec, tick, tick_time,
    line, then the ARRAYS' values joint by joint, array after array) -> CDR, and back."""

    def __init__(self, axis: str, joints: Sequence[str], *, frame_id: str = "") -> None:
        if not joints:
            raise ValueError("joints: a servo sample needs at least one joint")
        fmt, offset = ["<"], 0
        fixed: list[object] = []  # the constant values, in order, None where a number goes
        # field -> (offset in the message, numpy code) of every number and string length
        self.offsets: dict[str, tuple[int, str]] = {}

        def add(code: str, size: int, align: int, value: object = None, name: str = "") -> None:
            nonlocal offset
            pad = -offset % align
            fmt.append(f"{pad}x{code}" if pad else code)
            offset += pad
            if name:
                self.offsets[name] = (len(ENCAPSULATION) + offset, _NUMPY[code])
            offset += size
            fixed.append(value)

        def string(name: str, text: str) -> None:
            raw = text.encode("utf-8") + b"\0"
            add("I", 4, 4, len(raw), f"{name}.length")
            add(f"{len(raw)}s", len(raw), 1, raw)

        add("i", 4, 4, name="header.stamp.sec")
        add("I", 4, 4, name="header.stamp.nanosec")
        string("header.frame_id", frame_id)
        string("axis", axis)
        add("Q", 8, 8, name="tick")
        add("d", 8, 8, name="tick_time")
        add("i", 4, 4, name="line")
        add("I", 4, 4, len(joints), "joints.length")
        for j, name in enumerate(joints):
            string(f"joints[{j}]", name)
        for array in ARRAYS:
            add("I", 4, 4, len(joints), f"{array}.length")
            for j in range(len(joints)):
                add("d", 8, 8, name=f"{array}[{j}]")
        self.joints = len(joints)
        self.size = len(ENCAPSULATION) + offset
        self._struct = struct.Struct("".join(fmt))
        self._fixed = fixed
        self._slots = [i for i, value in enumerate(fixed) if value is None]

    @classmethod
    def from_message(cls, data: bytes) -> ServoSampleLayout:
        """The layout of ServoSample bytes `data` (its strings and joints); ValueError when
        they are not a ServoSample with one value per joint in each array."""
        try:
            at = len(ENCAPSULATION) + 8  # after the stamp

            def string() -> str:
                nonlocal at
                at += -(at - len(ENCAPSULATION)) % 4
                (n,) = struct.unpack_from("<I", data, at)
                text = data[at + 4 : at + 4 + n - 1].decode("utf-8")
                at += 4 + n
                return text

            frame_id, axis = string(), string()
            at += -(at - len(ENCAPSULATION)) % 8 + 8 + 8 + 4  # tick, tick_time, line
            (count,) = struct.unpack_from("<I", data, at)
            at += 4
            joints = [string() for _ in range(min(count, 64))]
        except (struct.error, UnicodeDecodeError) as exc:
            raise ValueError(f"not a ServoSample ({exc})") from None
        layout = cls(axis, joints, frame_id=frame_id)
        if layout.size != len(data):
            raise ValueError(
                f"not a ServoSample with one value per joint in each array ({len(data)} bytes, "
                f"{layout.size} expected for joints {', '.join(joints)})"
            )
        return layout

    def read(self, table: np.ndarray) -> dict[str, np.ndarray]:
        """Every number of the messages in the rows of `table` (uint8, one message a row) by
        field name (`tick`, `following_error[0]`, ...); ValueError for rows of another layout."""
        if table.ndim != 2 or table.shape[1] != self.size:
            raise ValueError(f"rows of {table.shape[-1]} bytes: this layout's are {self.size}")
        out = {name: column(table, *where) for name, where in self.offsets.items()}
        for name in [n for n in out if n.endswith(".length")]:
            lengths = out.pop(name)
            if np.any(lengths != lengths[0]):
                raise ValueError(f"rows of several layouts: {name[: -len('.length')]} differs")
        return out

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
