"""The graph in one process, real time, wall clock, all nodes reading the ``--params-file``:

- ``ros2 run turning_force turning_force_graph``: simulator, estimator, controller, PMC bridge
  and recorder, for a desk.
- ``ros2 run turning_force turning_force_machine``: the same without the simulator, for the
  machine PC, where the DAQ driver publishes ``servo/currents``.

(``turning-force run`` composes the nodes in lock-step instead: :mod:`turning_force.session.run`.)
"""

from __future__ import annotations

import sys
from collections.abc import Sequence

from rclpy.node import Node

from turning_force.nodes.force_controller import ForceControllerNode
from turning_force.nodes.force_estimator import ForceEstimatorNode
from turning_force.nodes.lathe_sim import LatheSimNode
from turning_force.nodes.pmc_bridge import PmcBridgeNode
from turning_force.nodes.session_recorder import SessionRecorderNode
from turning_force.nodes.spin import run_nodes

__all__ = ['machine_main', 'main']


def _machine() -> list[Node]:
    return [ForceEstimatorNode(), ForceControllerNode(), PmcBridgeNode(), SessionRecorderNode()]


def main(args: Sequence[str] | None = None) -> int:
    return run_nodes(lambda: [LatheSimNode(), *_machine()], args)


def machine_main(args: Sequence[str] | None = None) -> int:
    return run_nodes(_machine, args)


if __name__ == '__main__':
    sys.exit(main())
