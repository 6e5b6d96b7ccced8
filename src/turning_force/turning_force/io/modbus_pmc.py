"""The PMC over Modbus/TCP: override bits to a digital I/O module, read back, faults named.

Each control period :meth:`ModbusPmc.write` sends the bits of one level in ONE write-coils
request (never a pattern that is not a level of the table), reads them back (the coils, or the
module's output image), reads the machine's inputs and writes changed outputs: what it returns
is what the PMC really sees. A refused request, no answer within the timeout (default one
control period), a wrong read-back or a lost connection is a fault: the connection is dropped,
and :meth:`ModbusPmc.connect` may be tried again once the back-off (``reconnect_min_s``
doubling to ``reconnect_max_s``) has passed. A lost connection cannot be written through: the
module's own watchdog must fall back to ``fail_safe_pct`` (docs/machine-pc.md).

Session-free (no rclpy): the bridge node, ``pmc-check`` and the tests use it alike.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

from pymodbus.client import ModbusTcpClient
from pymodbus.exceptions import ModbusException

from turning_force.core.errors import TurningForceError
from turning_force.core.pmc.machine import Machine, ModbusTcp
from turning_force.core.pmc.shopfloor import InputValues

__all__ = ['CoilReader', 'InputValues', 'IoResult', 'ModbusPmc', 'PmcIoError', 'pattern_text',
           'quiet_pymodbus']

EXCEPTION_NAMES = {1: 'illegal function', 2: 'illegal data address', 3: 'illegal data value',
                   4: 'device failure', 5: 'acknowledge', 6: 'device busy',
                   8: 'memory parity error', 10: 'gateway path unavailable',
                   11: 'gateway target failed to respond'}


class PmcIoError(TurningForceError):
    """The PMC module cannot be used (it refuses the connection, say)."""


class _Fault(Exception):
    """One failed exchange; the text says which request and why."""


@dataclass(frozen=True)
class IoResult:
    """One period's exchange with the module.

    ``bits``: the override signals read back (what the PMC sees), bit 0 first; empty after a
    fault. ``fault``: why the exchange failed, '' when it did not. ``round_trip_s``: from the
    write request to the last answer [s].
    """

    bits: tuple[bool, ...]
    inputs: InputValues
    fault: str = ''
    round_trip_s: float = 0.0

    @property
    def ok(self) -> bool:
        return not self.fault


def pattern_text(coils: Sequence[bool]) -> str:
    """Coil values as a machinist reads an I/O module's LEDs: ``1010`` from the first coil."""
    return ''.join('1' if c else '0' for c in coils)


def quiet_pymodbus() -> None:
    # pymodbus logs each failed request with a dump of the last frames; the bridge reports
    # every fault itself, in one line, in FeedOverride and /diagnostics.
    logging.getLogger('pymodbus').setLevel(logging.CRITICAL)


class _Link:
    """A pymodbus sync client held to a deadline per exchange, with its failures as text."""

    def __init__(self, config: ModbusTcp, timeout_s: float) -> None:
        quiet_pymodbus()
        self.config = config
        self.timeout_s = timeout_s
        # pymodbus's sync client leaves connect() and close() unannotated.
        self.client: Any = ModbusTcpClient(config.host, port=config.port, timeout=timeout_s,
                                           retries=0)
        self.connected = False
        self._deadline = 0.0

    def connect(self) -> None:
        self.client.comm_params.timeout_connect = self.timeout_s
        if not self.client.connect():
            self.client.close()
            raise _Fault(f'cannot connect to {self.config.host}:{self.config.port}')
        self.connected = True

    def close(self) -> None:
        self.client.close()
        self.connected = False

    def begin(self) -> None:
        self._deadline = time.monotonic() + self.timeout_s

    def call(self, what: str, request: Callable[..., Any], *args: Any, **kwargs: Any) -> Any:
        """One request against the exchange's deadline; a fault on no, late or refused answer."""
        if not self.connected:
            raise _Fault(f'{what}: not connected')
        remaining = self._deadline - time.monotonic()
        if remaining <= 0:
            raise _Fault(f'{what}: no time left of the {self.timeout_s * 1e3:.1f} ms timeout')
        # pymodbus's sync client waits timeout_connect for each answer; hold the exchange to
        # one deadline instead.
        self.client.comm_params.timeout_connect = remaining
        try:
            response = request(*args, device_id=self.config.unit_id, **kwargs)
        except ModbusException as exc:
            text = str(exc)
            if 'No response' in text:
                raise _Fault(f'{what}: no answer within {self.timeout_s * 1e3:.1f} ms') from exc
            if 'closed' in text:
                raise _Fault(f'{what}: connection lost (closed by the module)') from exc
            raise _Fault(f'{what}: connection lost ({text.strip()})') from exc
        except OSError as exc:
            raise _Fault(f'{what}: connection lost ({exc.strerror or exc})') from exc
        if response.isError():
            code = int(getattr(response, 'exception_code', 0))
            name = EXCEPTION_NAMES.get(code, 'unknown')
            raise _Fault(f'{what}: refused, exception code {code} ({name})')
        return response


class ModbusPmc:
    """The override on a Modbus/TCP module: write one level, read it back, read the inputs.

    ``control_period_s`` sets the timeout when the machine file gives none. ``clock`` is the
    back-off's clock (monotonic seconds).
    """

    polled = True   # written, read back and its inputs read every period

    def __init__(self, machine: Machine, control_period_s: float,
                 clock: Callable[[], float] = time.monotonic) -> None:
        if machine.modbus is None:
            raise PmcIoError(f'{machine.source}: backend.type = {machine.backend!r}: not a '
                             'Modbus/TCP module')
        self.machine = machine
        self.config = machine.modbus
        self.timeout_s = self.config.timeout_for(control_period_s)
        self._clock = clock
        self._link = _Link(self.config, self.timeout_s)
        self.fault = ''
        self.faults = 0
        self._backoff_s = self.config.reconnect_min_s
        self._next_attempt_s = -float('inf')
        self._outputs: dict[str, bool] = dict.fromkeys(machine.outputs.points(), False)
        self._outputs_written: dict[str, bool] = {}
        self.inputs = InputValues()
        self.writes = 0

    @property
    def connected(self) -> bool:
        return self._link.connected

    @property
    def where(self) -> str:
        return f'modbus_tcp {self.config.address_text}'

    def reconnect_due(self) -> bool:
        """True when disconnected and the back-off since the last fault has passed."""
        return not self.connected and self._clock() >= self._next_attempt_s

    def connect(self) -> str:
        """Open the connection; '' on success, else the fault (and the back-off starts)."""
        try:
            self._link.connect()
        except _Fault as exc:
            return self._failed(str(exc))
        self._outputs_written = {}   # the module may have restarted: write them again
        return ''

    def close(self) -> None:
        """Release the module (outputs stay as last written until its watchdog acts)."""
        self._link.close()

    def set_output(self, name: str, value: bool) -> None:
        """Ask for an output (``alarm``, ``stop_request``); written at the next exchange."""
        if name not in self._outputs:
            raise PmcIoError(f'{self.machine.source}: outputs.{name}: not wired in this file')
        self._outputs[name] = bool(value)

    def write(self, code: int, bits: Sequence[bool]) -> IoResult:
        """Write one level's bits in one request, read them back, read the inputs.

        ``code``/``bits`` must be a level's encoding (:meth:`OverrideTable.encode`); anything
        else raises ``ValueError`` before any request goes out.
        """
        bits = tuple(bool(b) for b in bits)
        table = self.machine.table
        try:
            level = table.decode(bits)
            expected = table.encode(level)
        except ValueError as exc:
            raise ValueError(f'{self.where}: bits {bits} are not a level of {table.name}: '
                             'not written') from exc
        if expected != (code, bits):
            raise ValueError(f'{self.where}: code {code} with bits {bits} is not a level of '
                             f'{table.name}: not written')
        if not self.connected:
            return IoResult((), self.inputs, self.fault or f'{self.where}: not connected')
        link, config = self._link, self.config
        start = time.perf_counter()
        link.begin()
        try:
            coils = config.coils_for(bits)
            link.call('write override', link.client.write_coils, config.first_coil, coils)
            self.writes += 1
            answer = link.call('read back', link.client.read_coils, config.readback_first,
                               count=len(coils))
            seen = config.bits_from(answer.bits[:len(coils)])
            if seen != bits:
                raise _Fault(f'read back {pattern_text(answer.bits[:len(coils)])}, wrote '
                             f'{pattern_text(coils)}')
            self._write_outputs()
            self.inputs = self._read_inputs()
        except _Fault as exc:
            return IoResult((), self.inputs, self._failed(str(exc)),
                            time.perf_counter() - start)
        self.fault = ''
        self._backoff_s = self.config.reconnect_min_s
        return IoResult(seen, self.inputs, '', time.perf_counter() - start)

    def _write_outputs(self) -> None:
        link = self._link
        for name, point in self.machine.outputs.points().items():
            value = self._outputs[name]
            if self._outputs_written.get(name) != value:
                link.call(f'write {name}', link.client.write_coil, point.address,
                          point.raw(value))
                self._outputs_written[name] = value

    def _read_inputs(self) -> InputValues:
        inputs, link = self.machine.inputs, self._link
        addresses = inputs.discrete_inputs
        raw: dict[int, bool] = {}
        if addresses:
            first = min(addresses)
            answer = link.call('read inputs', link.client.read_discrete_inputs, first,
                               count=max(addresses) - first + 1)
            raw = {first + k: bool(b) for k, b in enumerate(answer.bits)}
        enable = (None if inputs.program_enable is None
                  else inputs.program_enable.signal(raw[inputs.program_enable.address]))
        threading = (None if inputs.threading is None
                     else inputs.threading.signal(raw[inputs.threading.address]))
        dial = inputs.operator_dial
        dial_pct: float | None = None
        if dial is not None and dial.kind == 'bits':
            try:
                dial_pct = dial.decode_bits([raw[a] for a in dial.addresses])
            except ValueError as exc:
                raise _Fault(f'operator dial: {exc}') from exc
        elif dial is not None:
            read = (link.client.read_input_registers if dial.kind == 'input_register'
                    else link.client.read_holding_registers)
            answer = link.call('read operator dial', read, dial.addresses[0], count=1)
            dial_pct = dial.decode_register(int(answer.registers[0]))
        return InputValues(enable, threading, dial_pct)

    def _failed(self, text: str) -> str:
        self._link.close()
        self.fault = f'{self.where}: {text}'
        self.faults += 1
        self._next_attempt_s = self._clock() + self._backoff_s
        self._backoff_s = min(2.0 * self._backoff_s, self.config.reconnect_max_s)
        return self.fault


class CoilReader:
    """Reads the override coils as the PMC does, and decodes them with the machine's table:
    the simulator's side of the simulated PMC (``lathe_sim`` with ``backend: modbus_tcp``)."""

    def __init__(self, machine: Machine, timeout_s: float = 1.0) -> None:
        if machine.modbus is None:
            raise PmcIoError(f'{machine.source}: backend.type = {machine.backend!r}: no coils '
                             'to read')
        self.machine = machine
        self._link = _Link(machine.modbus, timeout_s)

    @property
    def where(self) -> str:
        return self._link.config.address_text

    def read_pct(self) -> float:
        """The override the coils set [%]; :class:`PmcIoError` when they cannot be read or
        hold no level."""
        config, link = self.machine.modbus, self._link
        assert config is not None
        for attempt in (1, 2):   # a connection the server dropped is opened again, once
            try:
                if not link.connected:
                    link.connect()
                link.begin()
                answer = link.call('read override', link.client.read_coils, config.first_coil,
                                   count=len(config.override_coils))
                break
            except _Fault as exc:
                link.close()
                if attempt == 2:
                    raise PmcIoError(f'modbus_tcp {config.address_text}: {exc}') from exc
        bits = config.bits_from(answer.bits[:len(config.override_coils)])
        try:
            return self.machine.table.decode(bits)
        except ValueError as exc:
            raise PmcIoError(f'modbus_tcp {config.address_text}: {exc}') from exc

    def close(self) -> None:
        self._link.close()
