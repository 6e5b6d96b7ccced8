"""The graph in one process, real time, wall clock, all nodes reading the ``--params-file``:
``turning_force_graph`` (simulator, estimator, controller, PMC bridge and recorder, for a desk)
and ``turning_force_machine`` (the same without the simulator, for the machine PC, where the DAQ
driver publishes ``servo/currents``).

Both configure and activate ``pmc_bridge`` once the graph exists, and deactivate and clean it up
when the process stops. On a desk, a machine file whose module is on 127.0.0.1 is served by a
simulated PMC on Modbus/TCP for the graph's lifetime. (``turning-force run`` composes the nodes
in lock-step instead: :mod:`turning_force.commands.run`.)

Arming is never a guess. ``turning_force_graph`` arms the way ``turning-force run`` does: as
the files say (``experiment.arm_bridge``, default true, or ``pmc_bridge.armed``).
``turning_force_machine`` never arms by itself, whatever a file says: its first line, and
``/diagnostics``, say what state the bridge is in and what arms it (``~/arm``; the program-enable
input, where wired, gates it).
"""

from __future__ import annotations

import sys
from collections.abc import Sequence

from rclpy.node import Node
from rclpy.parameter import Parameter

from turning_force.core.experiment import Experiment, build_experiment
from turning_force.core.overlay import read_parameters
from turning_force.io.pmc_server import PmcSimulation, simulate_pmc
from turning_force.nodes.force_controller import ForceControllerNode
from turning_force.nodes.force_estimator import ForceEstimatorNode
from turning_force.nodes.lathe_sim import LatheSimNode
from turning_force.nodes.pmc_bridge import PmcBridgeNode
from turning_force.nodes.session_recorder import SessionRecorderNode
from turning_force.nodes.spin import run_nodes

__all__ = ['like_run', 'machine_main', 'main']


def like_run(args: Sequence[str]) -> Experiment:
    """What ``turning-force run`` makes of the ``--params-file`` files of ``args`` (later files
    override earlier ones, as ROS reads them): whether it arms the bridge, and the override the
    simulated axis approaches at."""
    sections: dict[str, dict[str, object]] = {}
    files = [args[k + 1] for k, arg in enumerate(args[:-1]) if arg == '--params-file']
    for path in files:
        for name, params in read_parameters(path).items():
            sections.setdefault(name, {}).update(params)
    return build_experiment(' + '.join(files) or 'defaults', sections)


def _machine(servers: list[PmcSimulation] | None = None, arm: bool = False) -> list[Node]:
    """The machine's nodes; ``arm``: arm the bridge once active (the desk graph); false: it
    stays disarmed until told, whatever the files say (the machine)."""
    bridge = PmcBridgeNode(autostart=False)
    nodes: list[Node] = [ForceEstimatorNode(), ForceControllerNode(), bridge,
                         SessionRecorderNode()]
    if servers is not None:   # a desk: serve a machine file on 127.0.0.1
        settings = bridge.parameters.current
        pmc = simulate_pmc(settings.machine_file, settings.backend, settings.override_table)
        pmc.start()
        servers.append(pmc)
    elif bridge.parameters.current.armed:
        bridge.set_parameters([Parameter('armed', value=False)])
        bridge.get_logger().warning('pmc_bridge.armed = true in a parameters file: not used by '
                                    'turning_force_machine, which never arms by itself')
    bridge.start()   # configure and activate, now that the graph exists
    if arm:
        bridge.arm()
    print(bridge.state_text(), flush=True)
    return nodes


def main(args: Sequence[str] | None = None) -> int:
    servers: list[PmcSimulation] = []
    argv = list(sys.argv if args is None else args)
    run = like_run(argv)
    approach = Parameter('approach_override_pct', value=run.plant.approach_override_pct)
    try:
        return run_nodes(lambda: [LatheSimNode(parameter_overrides=[approach]),
                                  *_machine(servers, run.bridge.armed)], args)
    finally:
        for server in servers:
            server.stop()


def machine_main(args: Sequence[str] | None = None) -> int:
    print('turning_force_machine: the PMC bridge starts disarmed and never arms by itself: '
          'arm it with its ~/arm service (ros2 service call .../pmc_bridge/arm '
          'std_srvs/srv/Trigger); where the program-enable input is wired, it acts only while '
          'that input is on', flush=True)
    return run_nodes(_machine, args)


if __name__ == '__main__':
    sys.exit(main())
