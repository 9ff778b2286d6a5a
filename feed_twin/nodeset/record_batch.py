"""Messages only the recorder reads, packed into one feed_twin_msgs/RecordBatch every N exchanges.

In a machine's node set every node is a process of its own, and a message to a reader in another
process is one datagram per reading process: the sim's feedback goes to its controller and to
the recorder, its state and joint states to the recorder alone, the controller's DriveCommand to
the sim and to the recorder. Sending and receiving a datagram costs tens of microseconds of
CPU on a virtual machine (the send wakes the receiving thread through the hypervisor), so at a
few thousand exchanges per second those copies for the recorder were a quarter of the node
set's CPU (docs/performance.md). With `ros.record_batch` N > 0 a node keeps the recorder's
copies of N exchanges and publishes them as one RecordBatch on `<namespace>/record/<role>`;
the recorder writes every message under its own topic with its own bytes, so the bag holds
what it held before, sample for sample. The messages the other nodes read still go out at once
on their topics.

The log time of a batched message in the bag is its publish time (the producer's system clock)
instead of its receive time: a batch arrives up to N exchanges after its first message. At the
end of a run a node publishes what it holds before it announces the end or stops; a node that
is killed loses at most N exchanges of its recorder copies.

Plain Python (no rclpy): the bytes are XCDR1 little endian, as rmw puts them on the wire
(feed_twin.io.cdr), checked against rclpy's serialiser in tests/test_record_batch.py.
"""

from __future__ import annotations

import struct
from collections.abc import Sequence

from feed_twin.io.cdr import ENCAPSULATION

_U32 = struct.Struct("<I")


def _pad(n: int, align: int) -> int:
    """Bytes of padding before a field aligned to `align` at offset `n` (after the header)."""
    return -n % align


class RecordBatch:
    """The recorder's copies of a node's messages until `capacity` exchanges are held.

    `topics`: the topics this node packs, in a fixed order (`add` takes the index). The
    topic list, its CDR prefix, is encoded once.
    """

    def __init__(self, topics: Sequence[str], capacity: int) -> None:
        if not topics:
            raise ValueError("topics: a batch needs at least one topic")
        if isinstance(capacity, bool) or not isinstance(capacity, int) or capacity < 1:
            raise ValueError(f"capacity = {capacity!r}: must be a whole number >= 1")
        if len(topics) > 0xFFFF:
            raise ValueError(f"topics: {len(topics)} is more than a uint16 index can name")
        self.topics = tuple(topics)
        self.capacity = capacity
        head = bytearray(_U32.pack(len(self.topics)))
        for name in self.topics:
            raw = name.encode() + b"\0"
            head += b"\0" * _pad(len(head), 4) + _U32.pack(len(raw)) + raw
        self._head = bytes(head)
        self._index: list[int] = []
        self._stamps: list[int] = []
        self._sizes: list[int] = []
        self._data: list[bytes] = []
        self.exchanges = 0

    def __len__(self) -> int:
        return len(self._data)

    def add(self, index: int, data: bytes, publish_time_ns: int) -> None:
        """Hold one message of topic `topics[index]` (its CDR bytes)."""
        # Fast DDS sends a payload padded to a multiple of 4 bytes: so does the batch, and the
        # bag holds the bytes a subscriber would have received.
        pad = -len(data) % 4
        if pad:
            data += b"\0" * pad
        self._index.append(index)
        self._stamps.append(publish_time_ns)
        self._sizes.append(len(data))
        self._data.append(data)

    def end_exchange(self) -> bool:
        """Count one exchange; True once `capacity` exchanges are held (time to `take`)."""
        self.exchanges += 1
        return self.exchanges >= self.capacity

    def take(self) -> bytes | None:
        """The RecordBatch bytes of everything held (None: nothing), and an empty batch."""
        n = len(self._data)
        self.exchanges = 0
        if n == 0:
            return None
        out = bytearray(ENCAPSULATION)
        out += self._head
        # offsets count from the end of the encapsulation header
        at = len(self._head)
        pad = _pad(at, 4)
        out += b"\0" * pad + _U32.pack(n) + struct.pack(f"<{n}H", *self._index)
        at += pad + 4 + 2 * n
        pad = _pad(at, 4)
        out += b"\0" * pad + _U32.pack(n)
        at += pad + 4
        pad = _pad(at, 8)
        out += b"\0" * pad + struct.pack(f"<{n}q", *self._stamps)
        at += pad + 8 * n
        pad = _pad(at, 4)
        out += b"\0" * pad + _U32.pack(n) + struct.pack(f"<{n}I", *self._sizes)
        at += pad + 4 + 4 * n
        data = b"".join(self._data)
        out += _U32.pack(len(data)) + data  # `at` is 4-aligned after the uint32 sizes
        self._index.clear()
        self._stamps.clear()
        self._sizes.clear()
        self._data.clear()
        return bytes(out)


def unpack(data: bytes) -> list[tuple[str, int, bytes]]:
    """(topic, publish time [ns], CDR bytes) of every message in RecordBatch bytes; ValueError
    for bytes that are not a well-formed batch."""
    if data[:4] != ENCAPSULATION:
        raise ValueError("not little-endian CDR (encapsulation header)")
    body = memoryview(data)[4:]
    at = 0

    def count(align: int = 4) -> int:
        nonlocal at
        at += _pad(at, align)
        if at + 4 > len(body):
            raise ValueError("truncated")
        (n,) = _U32.unpack_from(body, at)
        at += 4
        return n

    def array(fmt: str, size: int, n: int) -> tuple:
        nonlocal at
        at += _pad(at, size)
        end = at + size * n
        if end > len(body):
            raise ValueError("truncated")
        values = struct.unpack_from(f"<{n}{fmt}", body, at)
        at = end
        return values

    topics = []
    for _ in range(count()):
        length = count()
        if length < 1 or at + length > len(body) or body[at + length - 1] != 0:
            raise ValueError("a malformed topic name")
        topics.append(bytes(body[at : at + length - 1]).decode())
        at += length
    index = array("H", 2, count())
    stamps = array("q", 8, count())
    sizes = array("I", 4, count())
    total = count()
    if not len(index) == len(stamps) == len(sizes) or sum(sizes) != total:
        raise ValueError("the per-message arrays do not agree")
    if at + total > len(body) or (index and max(index) >= len(topics)):
        raise ValueError("truncated, or a topic index out of range")
    out = []
    for i, stamp, size in zip(index, stamps, sizes, strict=True):
        out.append((topics[i], stamp, bytes(body[at : at + size])))
        at += size
    return out


def messages_of(data: bytes, topic: str) -> list[bytes]:
    """The CDR bytes of every message in a RecordBatch of `topic` alone (the G-code node's
    setpoints for one controller, gcode_node --command-batch), in order; ValueError for bytes
    that are not a well-formed batch or that hold a message of another topic."""
    out = []
    for name, _, message in unpack(data):
        if name != topic:
            raise ValueError(f"it holds a message of {name}, not of {topic}")
        out.append(message)
    return out
