"""The ROS 2 message types feed_twin publishes, records and reads, by their installed names
(pkg/msg/Type): one place for the strings that codecs, bags and graph checks use."""

from __future__ import annotations

FEED_TWIN_PACKAGE = "feed_twin_msgs/msg/"  # the project's own interfaces (msgs/)

AXIS_COMMAND = f"{FEED_TWIN_PACKAGE}AxisCommand"
AXIS_FEEDBACK = f"{FEED_TWIN_PACKAGE}AxisFeedback"
AXIS_STATE = f"{FEED_TWIN_PACKAGE}AxisState"
DRIVE_COMMAND = f"{FEED_TWIN_PACKAGE}DriveCommand"
HEALTH_STATUS = f"{FEED_TWIN_PACKAGE}HealthStatus"
RECORD_BATCH = f"{FEED_TWIN_PACKAGE}RecordBatch"
SERVO_SAMPLE = f"{FEED_TWIN_PACKAGE}ServoSample"
TWIN_RESIDUAL = f"{FEED_TWIN_PACKAGE}TwinResidual"
CLOCK = "rosgraph_msgs/msg/Clock"
JOINT_STATE = "sensor_msgs/msg/JointState"
FLOAT64 = "std_msgs/msg/Float64"
STRING = "std_msgs/msg/String"
