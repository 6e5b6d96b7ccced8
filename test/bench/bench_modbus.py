"""The PMC over Modbus/TCP on this machine: how long one period's exchange takes, and how long
from a block of currents to the override on the coils, with the graph on the wall clock.

1. Write + read back (one write-coils, one read-coils), over >= 2000 periods, p50 / p99 / max:
   against pymodbus's server in this process (a thread) and in a process of its own; and the
   whole period of the 0-T wiring (write, read back from the output image, read the inputs).
2. Block to coil: lathe_sim on a 10 ms wall timer, estimator, controller and the bridge on
   ``modbus_tcp`` in one process (rclpy's EventsExecutor), the server in a thread: from the
   moment the simulator starts a block to the moment the server receives the write answering
   it. Over about 1000 blocks.

Measures; asserts nothing. Run: ``.venv/bin/python test/bench/bench_modbus.py`` (or
``make bench``).
"""

from __future__ import annotations

import os
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import rclpy
from rclpy.context import Context
from rclpy.parameter import Parameter

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))   # test/modbus_helpers.py
from modbus_helpers import ServerProcess, local_machine, write_machine
from turning_force.core.experiment import load_experiment
from turning_force.core.pmc.machine import MachineInputs, MachineOutputs
from turning_force.io.modbus_pmc import ModbusPmc
from turning_force.io.pmc_server import SimulatedPmcServer
from turning_force.nodes.force_controller import ForceControllerNode
from turning_force.nodes.force_estimator import ForceEstimatorNode
from turning_force.nodes.lathe_sim import LatheSimNode
from turning_force.nodes.pmc_bridge import PmcBridgeNode

FIG8 = Path(__file__).resolve().parents[2] / 'config' / 'experiments' / 'park1998_fig8.yaml'
PERIODS = 2000


def round_trips_ms(machine, periods: int = PERIODS) -> np.ndarray:
    pmc = ModbusPmc(machine, 0.01)
    assert pmc.connect() == '', pmc.fault
    table = machine.table
    levels = [table.encode(level) for level in table.levels_pct]
    out = np.empty(periods)
    for k in range(100):   # warm-up
        pmc.write(*levels[k % len(levels)])
    for k in range(periods):
        result = pmc.write(*levels[k % len(levels)])
        assert result.ok, result.fault
        out[k] = result.round_trip_s * 1e3
    pmc.close()
    return out


def row(label: str, values_ms: np.ndarray) -> str:
    return (f'{label:52s} {np.median(values_ms):7.3f} {np.percentile(values_ms, 99):7.3f} '
            f'{values_ms.max():7.3f} {values_ms.size:6d}')


def bare(machine):
    """Only the override: no inputs, no outputs; read back from the coils written."""
    return replace(machine, inputs=MachineInputs(), outputs=MachineOutputs(),
                   modbus=replace(machine.modbus, readback_address=None, timeout_s=1.0))


def exchange_table() -> None:
    print(f'{"exchange per period [ms]":52s} {"p50":>7s} {"p99":>7s} {"max":>7s} {"n":>6s}')
    with SimulatedPmcServer(local_machine()) as server:
        zero_t = local_machine(port=server.port, timeout_s=1.0)
        print(row('write + read back, server in this process', round_trips_ms(bare(zero_t))))
        print(row('0-T period (+ output image, inputs), same server', round_trips_ms(zero_t)))
    process = ServerProcess()
    try:
        zero_t = local_machine(port=process.port, timeout_s=1.0)
        print(row('write + read back, server in its own process', round_trips_ms(bare(zero_t))))
    finally:
        process.stop()


class TimedSim(LatheSimNode):
    """lathe_sim noting when each block starts (perf_counter, s)."""

    def __init__(self, **kwargs) -> None:
        super().__init__(**kwargs)
        self.block_starts: list[float] = []

    def step(self):
        self.block_starts.append(time.perf_counter())
        return super().step()


def run_graph(port: int, tmp: str, duration_s: float) -> tuple[list[float], list[float], int]:
    """The graph on the wall clock against the module at ``port``: block starts, times the
    module acknowledged an override write (perf_counter, s), and the I/O faults."""
    from rclpy.experimental import EventsExecutor

    resolved = load_experiment(FIG8).resolved_params()
    path = write_machine(Path(tmp) / f'm{port}.yaml', port=port)   # timeout: one period
    shared = {'machine_file': str(path), 'backend': 'modbus_tcp'}
    context = Context()
    rclpy.init(context=context, domain_id=int(os.environ.get('ROS_DOMAIN_ID', 151)))
    executor = EventsExecutor(context=context)

    def params(section: str, **extra):
        return [Parameter(k, value=v) for k, v in {**resolved[section], **extra}.items()]

    nodes = []
    acked: list[float] = []
    try:
        sim = TimedSim(context=context, parameter_overrides=params('lathe_sim', **shared))
        bridge = PmcBridgeNode(autostart=False, context=context, parameter_overrides=params(
            'pmc_bridge', **shared, armed=True))
        nodes = [sim, bridge,
                 ForceEstimatorNode(context=context, parameter_overrides=params(
                     'force_estimator')),
                 ForceControllerNode(context=context, parameter_overrides=params(
                     'force_controller'))]
        for node in nodes:
            executor.add_node(node)
        bridge.start()
        client = bridge.backend._link.client
        write_coils = client.write_coils

        def timed_write_coils(*args, **kwargs):   # the module has set the coils when it acks
            response = write_coils(*args, **kwargs)
            acked.append(time.perf_counter())
            return response

        client.write_coils = timed_write_coils
        end = time.monotonic() + duration_s
        while time.monotonic() < end:
            executor.spin_once(timeout_sec=0.1)
        faults = bridge.backend.faults
    finally:
        for node in nodes:
            executor.remove_node(node)
            node.destroy_node()
        executor.shutdown()
        rclpy.try_shutdown(context=context)
    return sim.block_starts, acked, faults


def latencies_ms(starts: list[float], writes: list[float]) -> tuple[np.ndarray, int]:
    """For each block, the first write after its start and before the next block's."""
    out, missing = [], 0
    times = np.array(writes)
    for k in range(len(starts) - 1):
        inside = times[(times > starts[k]) & (times < starts[k + 1])]
        if inside.size:
            out.append((inside[0] - starts[k]) * 1e3)
        else:
            missing += 1
    return np.array(out[50:]), missing   # after start-up


def block_to_coil(duration_s: float = 10.0) -> None:
    print(f'\n{"fig8 graph on the wall clock, 10 ms blocks [ms]":52s} {"p50":>7s} {"p99":>7s} '
          f'{"max":>7s} {"n":>6s}')
    with tempfile.TemporaryDirectory() as tmp:
        with SimulatedPmcServer(local_machine()) as server:
            starts, acked, faults = run_graph(server.port, tmp, duration_s)
            received = [w.t_s for w in server.writes if w.address == 0]
        values, missing = latencies_ms(starts, received)
        print(row('block start -> write received, server thread', values))
        values, _ = latencies_ms(starts, acked)
        print(row('block start -> write acknowledged, server thread', values))
        print(f'  {len(starts)} blocks, {missing} without a write before the next, '
              f'{faults} I/O faults (10 ms timeout)')
        process = ServerProcess(machine_file=write_machine(Path(tmp) / 'p.yaml'))
        try:
            starts, acked, faults = run_graph(process.port, tmp, duration_s)
        finally:
            process.stop()
        values, missing = latencies_ms(starts, acked)
        print(row('block start -> write acknowledged, server process', values))
        print(f'  {len(starts)} blocks, {missing} without a write before the next, '
              f'{faults} I/O faults (10 ms timeout)')


def main() -> int:
    exchange_table()
    block_to_coil()
    return 0


if __name__ == '__main__':
    sys.exit(main())
