"""ROS 2 nodes: thin shells that convert messages to core calls and back.

This is the only subpackage allowed to import rclpy or generated message modules.
"""
