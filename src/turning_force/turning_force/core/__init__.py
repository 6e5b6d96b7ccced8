"""The ROS-free core: plant, estimation, control laws, override tables, metrics, experiments.

Plain floats, arrays and ``dt`` in and out; never a message, a ``Time`` or a node.
"""
