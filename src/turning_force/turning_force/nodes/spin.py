"""The few lines every node's ``main`` shares: init, spin, shut down cleanly on Ctrl-C."""

from __future__ import annotations

from collections.abc import Callable, Sequence

import rclpy
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node

__all__ = ['run_nodes']


def run_nodes(make: Callable[[], list[Node]], args: Sequence[str] | None = None) -> int:
    """Create the nodes ``make`` returns and spin them on one executor until shut down."""
    rclpy.init(args=list(args) if args is not None else None)
    nodes: list[Node] = []
    executor = rclpy.executors.SingleThreadedExecutor()
    try:
        nodes = make()
        for node in nodes:
            executor.add_node(node)
        executor.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        for node in nodes:
            node.destroy_node()
        executor.shutdown()
        rclpy.try_shutdown()
    return 0
