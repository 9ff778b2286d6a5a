"""A node's recorder copies sent packed (`ros.record_batch`, feed_twin/nodeset/record_batch.py)."""

from __future__ import annotations

import time
from collections.abc import Sequence

from feed_twin_msgs.msg import RecordBatch as RecordBatchMsg
from rclpy.node import Node
from rclpy.qos import QoSProfile

from feed_twin.nodeset.record_batch import RecordBatch
from feed_twin.ros.dds import DATA_QOS


def batch_qos(exchanges: int) -> QoSProfile:
    """DATA_QOS with a history as long in time as the data topics' (a batch holds `exchanges`
    of them): a recorder that falls behind loses nothing, and no more memory is held."""
    return QoSProfile(
        history=DATA_QOS.history,
        depth=max(10, DATA_QOS.depth // exchanges),
        reliability=DATA_QOS.reliability,
        durability=DATA_QOS.durability,
    )


class RecordSender:
    """Holds the recorder's copies of `topics` and publishes them every `exchanges` exchanges
    on `topic`; `flush` publishes what is held (at the end of a run)."""

    def __init__(self, node: Node, topic: str, topics: Sequence[str], exchanges: int) -> None:
        self.batch = RecordBatch(topics, exchanges)
        self.publisher = node.create_publisher(RecordBatchMsg, topic, batch_qos(exchanges))
        self._index = {name: i for i, name in enumerate(self.batch.topics)}

    def index(self, topic: str) -> int:
        return self._index[topic]

    def add(self, index: int, data: bytes) -> None:
        self.batch.add(index, data, time.time_ns())

    def end_exchange(self) -> None:
        if self.batch.end_exchange():
            self.flush()

    def flush(self) -> None:
        data = self.batch.take()
        if data is not None:
            self.publisher.publish(data)
