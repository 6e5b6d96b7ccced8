"""The ROS 2 layer: one rclpy Node subclass per node, and message <-> core conversion.

Nodes hold no algorithm; the core does the work.
"""
