"""The run plan: from (config, mode, options) to the processes of a run and each one's nodes.

`plan.py` holds the plan's types (`NodeSpec`, `ProcessSpec`, `RunPlan`) and their command
lines; `machine.py` turns a machine's node plans (feed_twin.machine.nodes,
feed_twin.machine.shadow_nodes) into a `RunPlan`: every config is a machine, an axis file its
one-axis machine, in every mode. The executors that run a plan live with the transports they need:
processes watched by `feed_twin.ros.launch.launch` or one executor in one process
(feed_twin/ros/executors.py), the machine in-process (feed_twin.machine.run_cli).

Plain Python, no rclpy: a plan is data, tested without ROS.
"""
