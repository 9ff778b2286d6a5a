"""rosbag2-layout MCAP recordings: write raw CDR bytes, read back decoded, inspect, recover.

A bag is a directory holding `metadata.yaml` (rosbag2 version 9) and one `<name>_0.mcap` file
in the `ros2` profile: `ros2msg` schemas with their dependency blocks (`schema`), `cdr`
message encoding, channel metadata `offered_qos_profiles` and `topic_type_hash`, log time =
receive time and publish time = send time in nanoseconds. ROS 2 tools, `rosbags` and Rerun read
it as a normal rosbag2 recording.

Crash safety: `BagWriter` finishes the open MCAP chunk and flushes it to the OS every
`flush_period_s` from a background thread, so a SIGKILL loses at most that period. Such a file
has no footer; `recover` streams its records with a non-seeking reader, rewrites every complete
message into a valid file and regenerates `metadata.yaml`.

`BagReader` decodes messages to Python objects with the `mcap_ros2` decoder (no rclpy), for
analysis and the discrepancy workflow; `BagReader.columns` returns numpy arrays of fields.


Modules: `layout` (constants, `BagError`, QoS, `TopicInfo`/`BagInfo`, `bag_paths`), `schema`
(installed `.msg` definitions), `metadata` (metadata.yaml, `info`), `writer` (`BagWriter`),
`reader` (`BagReader`), `recovery` (`recover`, `add_topics`). The names other packages use are
re-exported here.
"""

from feed_twin.io.bag.layout import BagError, BagInfo, QosProfile, TopicInfo, bag_paths
from feed_twin.io.bag.metadata import info
from feed_twin.io.bag.reader import BagMessage, BagReader
from feed_twin.io.bag.recovery import RecoverResult, add_topics, recover
from feed_twin.io.bag.writer import BagWriter

__all__ = [
    "BagError",
    "BagInfo",
    "BagMessage",
    "BagReader",
    "BagWriter",
    "QosProfile",
    "RecoverResult",
    "TopicInfo",
    "add_topics",
    "bag_paths",
    "info",
    "recover",
]
