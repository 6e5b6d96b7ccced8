"""Park's Fig. 8 through a real Modbus/TCP server: `turning-force run` with a machine file whose
module is on 127.0.0.1 starts a simulated PMC (pymodbus's server); the bridge writes and reads
back the 0-T's coils, the simulator reads them as the PMC would, and the run gives the metrics
of the simulated backend."""

from __future__ import annotations

import json
import socket
from pathlib import Path

import pytest
from rosbags.highlevel import AnyReader

from modbus_helpers import write_machine
from turning_force.cli import main
from turning_force.commands.run import run_lockstep
from turning_force.core.errors import ConfigError
from turning_force.core.experiment import load_experiment
from turning_force.session.bag import typestore
from turning_force.session.reader import read_session, recorded_metrics

ROOT = Path(__file__).resolve().parents[2]
FIG8 = ROOT / 'config' / 'experiments' / 'park1998_fig8.yaml'


def free_port() -> int:
    with socket.socket() as s:
        s.bind(('127.0.0.1', 0))
        return int(s.getsockname()[1])


def diagnostic_values(bag: Path, node: str) -> dict[str, str]:
    values: dict[str, str] = {}
    with AnyReader([bag], default_typestore=typestore()) as reader:
        connections = [c for c in reader.connections if c.topic == '/diagnostics']
        for connection, _, raw in reader.messages(connections=connections):
            for status in reader.deserialize(raw, connection.msgtype).status:
                if status.name == node:
                    values.update({kv.key: kv.value for kv in status.values})
    return values


def test_fig8_through_modbus_tcp_equals_the_simulated_backend(capfd, tmp_path):
    # The 0-T wiring of config/machines/fanuc_0t.yaml (read back from the output image at 512),
    # on 127.0.0.1. A lock-step run counts sim time; the answer timeout is wall time, so it is
    # set well above what a loaded CI machine may stall for.
    machine = write_machine(tmp_path / 'fanuc_0t_desk.yaml', port=free_port(), timeout_s=2.0)
    argv = ['run', str(FIG8), '--out', str(tmp_path / 'modbus'), '--json',
            '--set', f'/**.machine_file={machine}']
    assert main(argv) == 0
    modbus = json.loads(capfd.readouterr().out)['metrics']
    simulated_bag = tmp_path / 'simulated'
    run_lockstep(load_experiment(FIG8), simulated_bag)
    simulated = recorded_metrics(read_session(simulated_bag))
    # Same plant, controller and quantiser; the override goes over Modbus/TCP instead of
    # in-process, as bits that decode to the same level: the same numbers (1e-9 relative
    # allows for summation order only).
    for name, value in simulated.items():
        assert modbus[name] == pytest.approx(value, rel=1e-9, abs=1e-12), name
    # And it did go through the protocol: the bridge on the module, the simulator on its coils.
    bag = tmp_path / 'modbus'
    bridge = diagnostic_values(bag, '/pmc_bridge')
    assert bridge['backend'].startswith('modbus_tcp 127.0.0.1:')
    assert float(bridge['io_round_trip_ms']) > 0.0
    assert diagnostic_values(bag, '/lathe_sim')['override_from'].startswith(
        'coils of modbus_tcp 127.0.0.1:')
    assert read_session(bag).experiment.bridge.backend == 'modbus_tcp'


def test_a_simulated_run_never_drives_a_real_module(tmp_path):
    experiment = load_experiment(FIG8).with_sets([
        f'/**.machine_file={ROOT / "config" / "machines" / "fanuc_0t.yaml"}',
        'pmc_bridge.backend=modbus_tcp'])
    with pytest.raises(ConfigError, match=r"fanuc_0t.yaml: backend.host = '192.168.1.50': a "
                                          'simulated run drives no real module'):
        run_lockstep(experiment, tmp_path / 'never')
