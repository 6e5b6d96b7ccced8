"""The few lines every node's ``main`` shares: init, spin, and a clean stop on SIGINT/SIGTERM.

rclpy's own signal handler shuts the context down under the executor's feet (which then raises
from inside ``spin``); here the signal only asks the loop to stop, and the nodes are destroyed
while the context is still valid, so that a recorder closes its session properly.
"""

from __future__ import annotations

import signal
import sys
from collections.abc import Callable, Sequence
from types import FrameType

import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.signals import SignalHandlerOptions

from turning_force.core.errors import TurningForceError

__all__ = ['run_nodes']


def run_nodes(make: Callable[[], list[Node]], args: Sequence[str] | None = None) -> int:
    """Create the nodes ``make`` returns and spin them on one executor until signalled."""
    rclpy.init(args=list(args) if args is not None else None,
               signal_handler_options=SignalHandlerOptions.NO)
    stop = False

    def request_stop(signum: int, frame: FrameType | None) -> None:
        nonlocal stop
        stop = True

    previous = {s: signal.signal(s, request_stop) for s in (signal.SIGINT, signal.SIGTERM)}
    nodes: list[Node] = []
    executor = SingleThreadedExecutor()
    try:
        try:
            nodes = make()
        except TurningForceError as exc:   # logged by the node; no traceback for bad input
            print(f'turning_force: {exc}', file=sys.stderr)
            return 2
        for node in nodes:
            executor.add_node(node)
        while not stop and rclpy.ok():
            executor.spin_once(timeout_sec=0.1)
    finally:
        for node in nodes:
            executor.remove_node(node)
            node.destroy_node()
        executor.shutdown()
        rclpy.try_shutdown()
        for signum, handler in previous.items():
            signal.signal(signum, handler)
    return 0
