"""A simulated PMC on Modbus/TCP: pymodbus's server standing in for the I/O module and the
PMC's input image, on this machine (127.0.0.1).

The bridge writes the override coils and reads them back as it would on the lathe; the
simulator (``lathe_sim`` with ``backend: modbus_tcp``) reads the same coils as the PMC would.
For tests it can answer late (``latency_s``), refuse writes (an exception response), hold coils
stuck (``stuck_coils``: a welded relay), and it keeps every write it was sent, so a test can
check that no pattern between two levels ever went out. With a machine file whose
``readback_address`` differs from the override coils (a WAGO coupler's output image at 0x0200)
it mirrors the override coils there, as the module does.

In a thread of this process (:class:`SimulatedPmcServer`) or as a process of its own::

    python -m turning_force.io.pmc_server [--machine FILE] [--host 127.0.0.1] [--port 0]

which binds 127.0.0.1 unless ``--host`` says otherwise, prints ``port N: listening on HOST:N``
once it listens, and serves until SIGINT or SIGTERM.
"""

from __future__ import annotations

import argparse
import asyncio
import signal
import sys
import threading
import time
from collections.abc import Sequence
from concurrent.futures import Future
from dataclasses import dataclass, field
from typing import Any

from pymodbus.constants import ExcCodes
from pymodbus.server import ModbusTcpServer
from pymodbus.simulator import DataType, SimData, SimDevice
from pymodbus.simulator.simutils import SimUtils

from turning_force.core.errors import ConfigError, TurningForceError, short_repr
from turning_force.core.experiment import Experiment
from turning_force.core.pmc.machine import Machine, load_machine
from turning_force.io.modbus_pmc import quiet_pymodbus

__all__ = ['PmcSimulation', 'ServerError', 'SimulatedPmcServer', 'Write', 'main',
           'simulate_pmc', 'simulated_parameters']

COILS = 1024           # 0x0000-0x03FF: room for a WAGO output image at 0x0200
DISCRETE_INPUTS = 64
REGISTERS = 16
WRITE_CODES = (5, 15)  # write single coil, write multiple coils


class ServerError(TurningForceError):
    """The simulated PMC server could not start (the port is taken, say)."""


@dataclass(frozen=True)
class Write:
    """One coil write the server was sent: its first address, the values, and when it came
    (``time.perf_counter()`` of this process) [s]."""

    address: int
    values: tuple[bool, ...]
    t_s: float = field(default=0.0, compare=False)


class SimulatedPmcServer:
    """pymodbus's Modbus/TCP server in a thread of its own, with an event loop of its own.

    ``start()`` listens (port 0: one the OS chooses) and returns the port; ``stop()`` closes
    the listener and every connection, as a module that lost power would.
    """

    def __init__(self, machine: Machine | None = None, host: str = '127.0.0.1',
                 port: int = 0) -> None:
        self.host = host
        self.port = port
        self._mirror: tuple[int, int, int] | None = None   # first coil, count, mirror address
        if machine is not None and machine.modbus is not None:
            m = machine.modbus
            if m.readback_first != m.first_coil:
                self._mirror = (m.first_coil, len(m.override_coils), m.readback_first)
        # Faults, for tests: answer late, refuse writes, coils that keep a value whatever is
        # written (a welded relay, a blown output).
        self.latency_s = 0.0
        self.refuse_writes = False
        self.stuck_coils: dict[int, bool] = {}
        self._writes: list[Write] = []
        self._loop: asyncio.AbstractEventLoop | None = None
        self._server: Any = None   # the ModbusTcpServer, while it runs
        self._thread: threading.Thread | None = None
        self._device: SimDevice | None = None
        quiet_pymodbus()

    @property
    def writes(self) -> list[Write]:
        """Every coil write received, in order (refused ones included)."""
        return list(self._writes)

    # --- running ------------------------------------------------------------------------------

    def start(self) -> int:
        """Listen; returns the port. Raises :class:`ServerError` when it cannot."""
        started: Future[int] = Future()
        self._thread = threading.Thread(target=self._run, args=(started,),
                                        name='simulated-pmc', daemon=True)
        self._thread.start()
        try:
            self.port = started.result(timeout=10.0)
        except (OSError, OverflowError) as exc:
            raise ServerError(f'simulated PMC on {self.host}:{self.port}: cannot listen: '
                              f'{short_repr(str(exc), 120)}') from exc
        return self.port

    def stop(self) -> None:
        """Close the listener and every connection; join the thread."""
        loop, server = self._loop, self._server
        if loop is not None and server is not None and loop.is_running():
            asyncio.run_coroutine_threadsafe(server.shutdown(), loop).result(timeout=10.0)
        if self._thread is not None:
            self._thread.join(timeout=10.0)
        self._thread = self._server = self._loop = None

    def __enter__(self) -> SimulatedPmcServer:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def _run(self, started: Future[int]) -> None:
        loop = asyncio.new_event_loop()
        asyncio.set_event_loop(loop)
        self._loop = loop
        try:
            loop.run_until_complete(self._serve(started))
            # Requests still being answered (a latency under test) end with the server.
            pending = asyncio.all_tasks(loop)
            for task in pending:
                task.cancel()
            if pending:
                loop.run_until_complete(asyncio.gather(*pending, return_exceptions=True))
        finally:
            loop.close()

    async def _serve(self, started: Future[int]) -> None:
        self._device = SimDevice(0, simdata=(
            [SimData(0, count=COILS, values=False, datatype=DataType.BITS)],
            [SimData(0, count=DISCRETE_INPUTS, values=False, datatype=DataType.BITS)],
            [SimData(0, count=REGISTERS, values=0, datatype=DataType.REGISTERS)],
            [SimData(0, count=REGISTERS, values=0, datatype=DataType.REGISTERS)],
        ), action=self._action)
        server = ModbusTcpServer(self._device, address=(self.host, self.port))
        try:
            await server.serve_forever(background=True)
        except RuntimeError:
            started.set_exception(OSError(f'address {self.host}:{self.port} not available'))
            return
        self._server = server
        listener: Any = server.transport
        started.set_result(int(listener.sockets[0].getsockname()[1]))
        await server.serving

    async def _action(self, function_code: int, start_address: int, address: int,
                      count: int, registers: list[int],
                      values: list[int] | list[bool] | None) -> ExcCodes | None:
        if self.latency_s > 0:
            await asyncio.sleep(self.latency_s)
        if values is not None and function_code in WRITE_CODES:
            self._writes.append(Write(address, tuple(bool(v) for v in values),
                                      time.perf_counter()))
            if self.refuse_writes:
                return ExcCodes.DEVICE_FAILURE
            for k in range(len(values)):   # the action may change what is stored
                stuck = self.stuck_coils.get(address + k)
                if stuck is not None:
                    values[k] = stuck
        if function_code == 1 and self._mirror is not None:
            first, n, mirror = self._mirror
            bits = SimUtils.registersToBits(registers)
            offset = 16 * start_address
            bits[mirror - offset:mirror - offset + n] = bits[first - offset:first - offset + n]
            registers[:] = SimUtils.bitsToRegisters(bits)
        return None

    # --- the datastore, as the PMC and the machine see it -------------------------------------

    def _call(self, coroutine: Any) -> Any:
        if self._loop is None:
            raise ServerError('simulated PMC: not running')
        return asyncio.run_coroutine_threadsafe(coroutine, self._loop).result(timeout=10.0)

    def coils(self, address: int, count: int) -> list[bool]:
        """Coil values as the PMC's input image holds them (no Modbus request)."""
        return list(self._call(self._runtime().async_getValues(1, address, count)))

    def set_discrete_inputs(self, address: int, values: Sequence[bool]) -> None:
        """Set discrete inputs, as the machine's switches and relays would."""
        self._call(self._runtime().get_bit_block('d', 2, address, len(values),
                                                 [bool(v) for v in values]))

    def set_input_register(self, address: int, value: int) -> None:
        self._call(self._runtime().get_reg_block('i', 4, address, 1, [int(value)]))

    def _runtime(self) -> Any:
        server = self._server
        if server is None:
            raise ServerError('simulated PMC: not running')
        return next(iter(server.context.devices.values()))


@dataclass
class PmcSimulation:
    """How a graph on a desk stands in for the PMC: ``backend`` and ``machine_file`` for both
    ``pmc_bridge`` and ``lathe_sim``, and the server to run while the graph runs (``None``:
    the bridge's in-process simulated PMC)."""

    backend: str = 'simulated'
    machine_file: str = ''
    server: SimulatedPmcServer | None = None

    @property
    def parameters(self) -> dict[str, str]:
        return {'backend': self.backend, 'machine_file': self.machine_file}

    def start(self) -> None:
        if self.server is not None:
            self.server.start()

    def stop(self) -> None:
        if self.server is not None:
            self.server.stop()


def simulate_pmc(machine_file: str, backend: str, override_table: str) -> PmcSimulation:
    """The PMC of a simulated run. A machine file whose module is on this machine (127.0.0.1)
    is served by a :class:`SimulatedPmcServer` on its port, and the loop closes through the
    real protocol; one whose module is elsewhere lends its table only: a simulation never
    writes to a real module."""
    if not machine_file:
        if backend == 'modbus_tcp':
            raise ConfigError("pmc_bridge.backend = 'modbus_tcp': needs a machine_file")
        return PmcSimulation()
    machine = load_machine(machine_file)
    machine.check_table(override_table)
    modbus = machine.modbus
    if modbus is None:
        return PmcSimulation('simulated', machine_file)
    if not modbus.is_loopback:
        if backend == 'modbus_tcp':
            raise ConfigError(f'{machine_file}: backend.host = {modbus.host!r}: a simulated run '
                              'drives no real module; give a machine file on 127.0.0.1, or '
                              'pmc_bridge.backend = simulated')
        return PmcSimulation('simulated', machine_file)
    return PmcSimulation('modbus_tcp', machine_file,
                         SimulatedPmcServer(machine, modbus.host, modbus.port))


def simulated_parameters(experiment: Experiment) -> tuple[dict[str, dict[str, Any]],
                                                          PmcSimulation]:
    """A simulated run's resolved parameters, the bridge's PMC laid in (:func:`simulate_pmc`),
    and that PMC."""
    bridge = experiment.bridge
    pmc = simulate_pmc(bridge.machine_file, bridge.backend, bridge.override_table)
    resolved = experiment.resolved_params()
    resolved['pmc_bridge'].update(pmc.parameters)
    return resolved, pmc


def _port(text: str) -> int:
    """An argparse type: a TCP port, 0 to 65535."""
    if not (text.isdigit() and int(text) <= 65535):
        raise argparse.ArgumentTypeError(f'{short_repr(text)}: expected a port, 0 to 65535')
    return int(text)


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog='python -m turning_force.io.pmc_server',
                                     description='A simulated PMC on Modbus/TCP.')
    parser.add_argument('--machine', help='machine file (mirrors its read-back image)')
    parser.add_argument('--host', default='127.0.0.1')
    parser.add_argument('--port', type=_port, default=0, help='0: one the OS chooses')
    args = parser.parse_args(argv)
    stop = threading.Event()
    for signum in (signal.SIGINT, signal.SIGTERM):
        signal.signal(signum, lambda *_: stop.set())
    try:
        machine = load_machine(args.machine) if args.machine else None
        server = SimulatedPmcServer(machine, args.host, args.port)
        port = server.start()
    except TurningForceError as exc:
        print(f'pmc_server: {exc}', file=sys.stderr)
        return 2
    print(f'port {port}: listening on {args.host}:{port}', flush=True)
    try:
        stop.wait()
    finally:
        server.stop()
    return 0


if __name__ == '__main__':
    sys.exit(main())
