"""feed_twin: a digital twin of a CNC ball-screw feed axis on ROS 2.

The package is a pure core (plant, control, gcode, sim, analysis, io) that never imports rclpy,
plus `feed_twin.ros`, the only subpackage that talks to ROS 2.
"""

__version__ = "0.1.0"
