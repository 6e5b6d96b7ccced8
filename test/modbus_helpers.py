"""Machine files pointed at a Modbus/TCP server on 127.0.0.1, and that server in a process of its
own (started, killed, restarted), for test/io, test/nodes and test/cli."""

from __future__ import annotations

import selectors
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import yaml

from turning_force.core.pmc.machine import Machine, parse_machine

MACHINES = Path(__file__).resolve().parents[1] / 'config' / 'machines'


def machine_yaml(name: str = 'fanuc_0t.yaml', port: int = 5020, **backend: Any) -> dict:
    """A shipped machine file's data, its module moved to 127.0.0.1:port."""
    data = yaml.safe_load((MACHINES / name).read_text())
    data['backend'].update({'host': '127.0.0.1', 'port': port, **backend})
    return data


def local_machine(name: str = 'fanuc_0t.yaml', port: int = 5020, **backend: Any) -> Machine:
    return parse_machine(machine_yaml(name, port, **backend), f'{name} on 127.0.0.1:{port}')


def coil_pattern(pct: float, name: str = 'fanuc_0t.yaml') -> list[bool]:
    """The override coils that set ``pct`` on a shipped machine's wiring (the 0-T's inverted
    logic: every coil off is 0 %)."""
    machine = local_machine(name)
    assert machine.modbus is not None
    return machine.modbus.coils_for(machine.table.encode(pct)[1])


def write_machine(path: Path, name: str = 'fanuc_0t.yaml', port: int = 5020,
                  **backend: Any) -> Path:
    path.write_text(yaml.safe_dump(machine_yaml(name, port, **backend)))
    return path


class ServerProcess:
    """``python -m turning_force.io.pmc_server`` in a process of its own."""

    def __init__(self, port: int = 0, machine_file: Path | None = None) -> None:
        args = [sys.executable, '-m', 'turning_force.io.pmc_server', '--port', str(port)]
        if machine_file is not None:
            args += ['--machine', str(machine_file)]
        self.process = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                        text=True)
        self.line = self._line(timeout_s=30.0)
        self.port = int(self.line.split()[1].rstrip(':'))

    def _line(self, timeout_s: float) -> str:
        stdout = self.process.stdout
        assert stdout is not None
        with selectors.DefaultSelector() as selector:
            selector.register(stdout, selectors.EVENT_READ)
            deadline = time.monotonic() + timeout_s
            while time.monotonic() < deadline:
                if selector.select(timeout=0.5):
                    line = stdout.readline()
                    if line.startswith('port '):
                        return line
                    if not line:
                        break
        self.process.kill()
        _, err = self.process.communicate(timeout=10)
        raise RuntimeError(f'pmc_server did not start: {err}')

    def kill(self) -> None:
        """As a module losing power: no goodbye on the connections."""
        self.process.kill()
        self.process.communicate(timeout=10)

    def stop(self) -> None:
        if self.process.poll() is None:
            self.process.terminate()
            self.process.communicate(timeout=10)
