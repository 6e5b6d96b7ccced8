"""The whole graph in one process: ``ros2 run turning_force turning_force_graph``.

Real time, wall clock: the simulator, estimator, controller, PMC bridge and recorder on one
executor, all reading the ``--params-file`` given. (``turning-force run`` composes the same nodes
in lock-step instead: :mod:`turning_force.session.run`.)
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

__all__ = ['main']


def _graph() -> list[Node]:
    return [LatheSimNode(), ForceEstimatorNode(), ForceControllerNode(), PmcBridgeNode(),
            SessionRecorderNode()]


def main(args: Sequence[str] | None = None) -> int:
    return run_nodes(_graph, args)


if __name__ == '__main__':
    sys.exit(main())
