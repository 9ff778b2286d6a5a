"""The node set's pure parts: the controller/drive split, the drive host and the in-process
lockstep, topic names, and the run summary. The ROS nodes in feed_twin.ros only convert
messages to and from these classes, so every run can also be computed without DDS."""
