"""The graph in one process, real time, wall clock, all nodes reading the ``--params-file``:
``turning_force_graph`` (simulator, estimator, controller, PMC bridge and recorder, for a desk)
and ``turning_force_machine`` (the same without the simulator, for the machine PC, where the DAQ
driver publishes ``servo/currents``).

Both configure and activate ``pmc_bridge`` once the graph exists, and deactivate and clean it up
when the process stops. On a desk, a machine file whose module is on 127.0.0.1 is served by a
simulated PMC on Modbus/TCP for the graph's lifetime. (``turning-force run`` composes the nodes
in lock-step instead: :mod:`turning_force.commands.run`.)
"""

from __future__ import annotations

import sys
from collections.abc import Sequence

from rclpy.node import Node

from turning_force.io.pmc_server import PmcSimulation, simulate_pmc
from turning_force.nodes.force_controller import ForceControllerNode
from turning_force.nodes.force_estimator import ForceEstimatorNode
from turning_force.nodes.lathe_sim import LatheSimNode
from turning_force.nodes.pmc_bridge import PmcBridgeNode
from turning_force.nodes.session_recorder import SessionRecorderNode
from turning_force.nodes.spin import run_nodes

__all__ = ['machine_main', 'main']


def _machine(servers: list[PmcSimulation] | None = None) -> list[Node]:
    bridge = PmcBridgeNode(autostart=False)
    nodes: list[Node] = [ForceEstimatorNode(), ForceControllerNode(), bridge,
                         SessionRecorderNode()]
    if servers is not None:   # a desk: serve a machine file on 127.0.0.1
        settings = bridge.parameters.current
        pmc = simulate_pmc(settings.machine_file, settings.backend, settings.override_table)
        pmc.start()
        servers.append(pmc)
    bridge.start()   # configure and activate, now that the graph exists
    return nodes


def main(args: Sequence[str] | None = None) -> int:
    servers: list[PmcSimulation] = []
    try:
        return run_nodes(lambda: [LatheSimNode(), *_machine(servers)], args)
    finally:
        for server in servers:
            server.stop()


def machine_main(args: Sequence[str] | None = None) -> int:
    return run_nodes(_machine, args)


if __name__ == '__main__':
    sys.exit(main())
