"""The PMC over Modbus/TCP: override bits to a digital I/O module, read back, faults named.

Each control period :meth:`ModbusPmc.write` sends the bits of one level in ONE write-coils
request (never a pattern that is not a level of the table), reads them back (the coils, or the
module's output image), reads the machine's inputs and writes changed outputs: what it returns
is what the PMC really sees. A refused request, a malformed answer (short, of another
function, out of range), a wrong read-back or a lost connection is a fault: the connection is
dropped, and :meth:`ModbusPmc.connect` may be tried again once the back-off
(``reconnect_min_s`` doubling to ``reconnect_max_s``) has passed. No answer within the timeout
(default one control period) is a miss: the next period tries again on a fresh connection, and
only ``max_missed_periods`` misses in a row are a fault (a busy PC is not a broken module). A
lost connection cannot be written through: the module's own watchdog turns the outputs off,
which the wiring makes safe (docs/safety.md).

One owner per module: with ``owner_register`` the bridge writes a token of its own there when
it connects and reads it each period; a token that is not its own means a second bridge, and
both refuse (the one that sees it first writes ``CONFLICT``, which the other then reads).
Without one, the override coils are read before each write: a pattern this bridge did not
write means another writer; it writes the 0 % pattern once, which the other then reads as a
pattern it did not write, and both refuse.

Every wait reads an injected clock (monotonic seconds by default), never the wall clock.

Session-free (no rclpy): the bridge node, ``pmc-check`` and the tests use it alike.
"""

from __future__ import annotations

import logging
import random
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

from pymodbus.client import ModbusTcpClient
from pymodbus.exceptions import ModbusException

from turning_force.core.errors import TurningForceError, short_repr
from turning_force.core.pmc.machine import Machine, ModbusTcp
from turning_force.core.pmc.shopfloor import InputValues
from turning_force.core.tools import NO_TOOL

__all__ = ['CONFLICT', 'CoilReader', 'InputValues', 'IoResult', 'ModbusPmc', 'PmcIoError',
           'pattern_text', 'quiet_pymodbus']

Clock = Callable[[], float]

# The owner register's value once two bridges have met on one module: both refuse.
CONFLICT = 0xFFFF

EXCEPTION_NAMES = {1: 'illegal function', 2: 'illegal data address', 3: 'illegal data value',
                   4: 'device failure', 5: 'acknowledge', 6: 'device busy',
                   8: 'memory parity error', 10: 'gateway path unavailable',
                   11: 'gateway target failed to respond'}


class PmcIoError(TurningForceError):
    """The PMC module cannot be used (it refuses the connection, say)."""


class _Fault(Exception):
    """One failed exchange; the text says which request and why. ``miss``: no answer in time
    (the module may only be slow); ``refuse``: another writer on the module (no reconnect)."""

    def __init__(self, text: str, *, miss: bool = False, refuse: bool = False) -> None:
        super().__init__(text)
        self.miss = miss
        self.refuse = refuse


@dataclass(frozen=True)
class IoResult:
    """One period's exchange with the module.

    ``bits``: the override signals read back (what the PMC sees), bit 0 first; empty after a
    fault or a miss. ``fault``: why the exchange failed, '' when it did not. ``missed``: no
    answer in time, within the miss budget (not a fault yet; the coils hold what they held).
    ``round_trip_s``: from the write request to the last answer [s].
    """

    bits: tuple[bool, ...]
    inputs: InputValues
    fault: str = ''
    round_trip_s: float = 0.0
    missed: str = ''

    @property
    def ok(self) -> bool:
        return not self.fault and not self.missed


def pattern_text(coils: Sequence[bool]) -> str:
    """Coil values as a machinist reads an I/O module's LEDs: ``1010`` from the first coil."""
    return ''.join('1' if c else '0' for c in coils)


def quiet_pymodbus() -> None:
    # pymodbus logs each failed request with a dump of the last frames; the bridge reports
    # every fault itself, in one line, in FeedOverride and /diagnostics.
    logging.getLogger('pymodbus').setLevel(logging.CRITICAL)


class _Link:
    """A pymodbus sync client held to a deadline per exchange, with its failures as text."""

    def __init__(self, config: ModbusTcp, timeout_s: float, clock: Clock = time.monotonic) -> None:
        quiet_pymodbus()
        self.config = config
        self.timeout_s = timeout_s
        self.clock = clock
        # pymodbus's sync client leaves connect() and close() unannotated.
        self.client: Any = ModbusTcpClient(config.host, port=config.port, timeout=timeout_s,
                                           retries=0)
        self.connected = False
        self._deadline = 0.0

    def connect(self) -> None:
        self.client.comm_params.timeout_connect = self.timeout_s
        try:
            connected = self.client.connect()
        except Exception as exc:
            self.client.close()
            raise _Fault(f'cannot connect to {self.config.host}:{self.config.port} '
                         f'({short_repr(str(exc))})') from exc
        if not connected:
            self.client.close()
            raise _Fault(f'cannot connect to {self.config.host}:{self.config.port}')
        self.connected = True

    def close(self) -> None:
        self.client.close()
        self.connected = False

    def begin(self) -> None:
        self._deadline = self.clock() + self.timeout_s

    def call(self, what: str, function_code: int, request: Callable[..., Any], *args: Any,
             **kwargs: Any) -> Any:
        """One request against the exchange's deadline; a fault on a refused, malformed (of
        another function than ``function_code``) or lost answer, a miss on none in time."""
        if not self.connected:
            raise _Fault(f'{what}: not connected')
        remaining = self._deadline - self.clock()
        if remaining <= 0:
            raise _Fault(f'{what}: no time left of the {self.timeout_s * 1e3:.1f} ms timeout',
                         miss=True)
        # pymodbus's sync client waits timeout_connect for each answer; hold the exchange to
        # one deadline instead.
        self.client.comm_params.timeout_connect = remaining
        try:
            response = request(*args, device_id=self.config.unit_id, **kwargs)
        except ModbusException as exc:
            text = str(exc)
            if 'No response' in text:
                raise _Fault(f'{what}: no answer within {self.timeout_s * 1e3:.1f} ms',
                             miss=True) from exc
            if 'closed' in text:
                raise _Fault(f'{what}: connection lost (closed by the module)') from exc
            if 'decode' in text or 'transaction id' in text or 'device id' in text:
                raise _Fault(f'{what}: malformed answer ({short_repr(text.strip(), 120)})') \
                    from exc
            raise _Fault(f'{what}: connection lost ({short_repr(text.strip(), 120)})') from exc
        except OSError as exc:
            raise _Fault(f'{what}: connection lost ({exc.strerror or exc})') from exc
        except Exception as exc:
            raise _Fault(f'{what}: malformed answer ({type(exc).__name__}: '
                         f'{short_repr(str(exc))})') from exc
        if response is None or not hasattr(response, 'isError'):
            raise _Fault(f'{what}: malformed answer (none)')
        if response.isError():
            code = int(getattr(response, 'exception_code', 0))
            name = EXCEPTION_NAMES.get(code, 'unknown')
            raise _Fault(f'{what}: refused, exception code {code} ({name})')
        answered = getattr(response, 'function_code', None)
        if answered != function_code:
            raise _Fault(f'{what}: malformed answer (function code {short_repr(answered)}, '
                         f'asked {function_code})')
        return response

    def write(self, what: str, function_code: int, request: Callable[..., Any], address: int,
              value: Any) -> None:
        """A write whose answer must echo it: the address, and the count or the value."""
        answer = self.call(what, function_code, request, address, value)
        echo = (getattr(answer, 'address', None), getattr(answer, 'count', None),
                list(getattr(answer, 'bits', None) or []),
                list(getattr(answer, 'registers', None) or []))
        if function_code == 15:
            good = echo[:2] == (address, len(value))
        elif function_code == 5:
            good = echo[0] == address and echo[2][:1] == [bool(value)]
        else:
            good = echo[0] == address and echo[3][:1] == [value]
        if not good:
            raise _Fault(f'{what}: malformed answer (echo {short_repr(echo)}, wrote '
                         f'{short_repr(value)} at {address})')

    def bits(self, what: str, request: Callable[..., Any], address: int, count: int,
             function_code: int) -> list[bool]:
        """``count`` bits from a read request, checked: the answer of that function and at
        least that many bits (a short or foreign answer is a fault, not an IndexError)."""
        answer = self.call(what, function_code, request, address, count=count)
        bits = getattr(answer, 'bits', None)
        if not isinstance(bits, list) or len(bits) < count:
            size = len(bits) if isinstance(bits, list) else 0
            raise _Fault(f'{what}: malformed answer ({size} bits, asked {count})')
        return [bool(b) for b in bits[:count]]

    def register(self, what: str, request: Callable[..., Any], address: int,
                 function_code: int) -> int:
        """One register from a read request, checked like :meth:`bits`."""
        answer = self.call(what, function_code, request, address, count=1)
        registers = getattr(answer, 'registers', None)
        if not isinstance(registers, list) or not registers:
            raise _Fault(f'{what}: malformed answer (no register)')
        value = int(registers[0])
        if not 0 <= value <= 0xFFFF:
            raise _Fault(f'{what}: malformed answer (register {short_repr(value)})')
        return value


class ModbusPmc:
    """The override on a Modbus/TCP module: write one level, read it back, read the inputs.

    ``control_period_s`` sets the timeout when the machine file gives none. ``clock`` is every
    wait's clock (the answer deadline, the back-off): monotonic seconds, never the wall clock.
    ``token``: this bridge's owner token (random when not given).
    """

    polled = True   # written, read back and its inputs read every period

    def __init__(self, machine: Machine, control_period_s: float,
                 clock: Clock = time.monotonic, token: int | None = None) -> None:
        if machine.modbus is None:
            raise PmcIoError(f'{machine.source}: backend.type = {machine.backend!r}: not a '
                             'Modbus/TCP module')
        self.machine = machine
        self.config = machine.modbus
        self.timeout_s = self.config.timeout_for(control_period_s)
        self._clock = clock
        self._link = _Link(self.config, self.timeout_s, clock)
        self.token = random.randint(1, CONFLICT - 1) if token is None else token
        self.fault = ''
        self.refused = ''      # another writer on the module: no reconnect
        self.faults = 0
        self.misses = 0        # exchanges without an answer in time, in all
        self.missed_in_row = 0
        self.retries = 0       # connections opened again after a miss
        self._backoff_s = self.config.reconnect_min_s
        self._next_attempt_s = -float('inf')
        self._outputs: dict[str, bool] = dict.fromkeys(machine.outputs.points(), False)
        self._outputs_written: dict[str, bool] = {}
        self._coils_written: list[bool] | None = None   # since this connection opened
        self.inputs = InputValues()
        self.writes = 0

    @property
    def connected(self) -> bool:
        return self._link.connected

    @property
    def where(self) -> str:
        return f'modbus_tcp {self.config.address_text}'

    def reconnect_due(self) -> bool:
        """True when disconnected, not refused, and the back-off since the last fault (none
        after a miss) has passed."""
        return (not self.connected and not self.refused
                and self._clock() >= self._next_attempt_s)

    def connect(self) -> str:
        """Open the connection (and claim the module); '' on success, else the fault (and the
        back-off starts)."""
        if self.refused:
            return self.refused
        for attempt in range(1, self.config.max_missed_periods + 1):
            try:
                self._open()
                return ''
            except _Fault as exc:   # no answer in time: again, within the miss budget
                if not exc.miss or attempt == self.config.max_missed_periods:
                    return self._failed(exc)
                self.misses += 1
                self.retries += 1
                self._link.close()
        raise AssertionError('unreachable')

    def _open(self) -> None:
        """Connect, claim the module, read the inputs (the dial bounds the first write too),
        each request against the answer timeout from when the connection is open."""
        self._link.connect()
        self._link.begin()
        self._outputs_written = {}   # the module may have restarted: write them again
        self._coils_written = None
        self._claim()
        self.inputs = self._read_inputs()

    def close(self) -> None:
        """Release the module (outputs stay as last written until its watchdog acts); the
        owner token is cleared where it is still this bridge's."""
        link, register = self._link, self.config.owner_register
        if link.connected and register is not None and not self.refused:
            try:
                link.begin()
                if self._owner() == self.token:
                    link.write('release owner', 6, link.client.write_register, register, 0)
            except _Fault:
                pass   # going anyway: the next bridge claims a stale token
        link.close()

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
        retry = not self.connected and self.missed_in_row > 0 and not self.refused
        if not self.connected and not retry:
            return IoResult((), self.inputs, self.fault or f'{self.where}: not connected')
        link, config = self._link, self.config
        start = time.perf_counter()
        link.begin()
        try:
            if retry:   # after a miss: again at once, on a fresh connection
                self.retries += 1
                self._open()
            self._check_owner()
            coils = config.coils_for(bits)
            link.write('write override', 15, link.client.write_coils, config.first_coil, coils)
            self.writes += 1
            self._coils_written = coils
            read = link.bits('read back', link.client.read_coils, config.readback_first,
                             len(coils), 1)
            seen = config.bits_from(read)
            if seen != bits:
                raise _Fault(f'read back {pattern_text(read)}, wrote {pattern_text(coils)}')
            self._write_outputs()
            self.inputs = self._read_inputs()
        except _Fault as exc:
            elapsed = time.perf_counter() - start
            if exc.miss and not exc.refuse:
                self.misses += 1
                self.missed_in_row += 1
                if self.missed_in_row < config.max_missed_periods:
                    self._link.close()   # a late answer must not answer the next request
                    return IoResult((), self.inputs, '', elapsed,
                                    f'{self.where}: {exc} (miss {self.missed_in_row} of '
                                    f'{config.max_missed_periods} allowed in a row)')
                exc = _Fault(f'{exc}; {self.missed_in_row} periods in a row', miss=True)
            return IoResult((), self.inputs, self._failed(exc), elapsed)
        self.fault = ''
        self.missed_in_row = 0
        self._backoff_s = self.config.reconnect_min_s
        return IoResult(seen, self.inputs, '', time.perf_counter() - start)

    # --- one owner per module --------------------------------------------------------------

    def _owner(self) -> int:
        register = self.config.owner_register
        assert register is not None
        link = self._link
        return link.register('read owner', link.client.read_holding_registers, register, 3)

    def _claim(self) -> None:
        """Write this bridge's token to the owner register (a stale one is taken over: the
        bridge that left it is not answering; a live one sees the claim within a period)."""
        register = self.config.owner_register
        if register is None:
            return
        link = self._link
        self._owner()   # the register answers (a module without one refuses: a clear fault)
        link.write('claim owner', 6, link.client.write_register, register, self.token)

    def _check_owner(self) -> None:
        """Another bridge on the module is a refusal for both: the owner token is not ours
        (CONFLICT written for the other to see), or the override coils hold a pattern this
        bridge did not write, read so twice (one corrupted answer is a fault, not a second
        bridge; the 0 % pattern written for the other to see)."""
        register, link = self.config.owner_register, self._link
        if register is None:
            written = self._coils_written
            if written is None:
                return

            def coils() -> list[bool]:
                return link.bits('read override before writing', link.client.read_coils,
                                 self.config.readback_first, len(written), 1)

            now = coils()
            if now != written and coils() == now:
                # The other writer reads back what it wrote and would go on: the 0 % pattern
                # (feed hold, the safest level) written once shows it the same conflict, so
                # both refuse. Where it wrote 0 % itself, it holds the feed already.
                hold = self.config.coils_for(self.machine.table.encode(0.0)[1])
                if now != hold:
                    link.write('mark conflict', 15, link.client.write_coils,
                               self.config.first_coil, hold)
                raise _Fault(f'override coils read {pattern_text(now)}, this bridge wrote '
                             f'{pattern_text(written)}: another writer on the module; both '
                             'refuse, the coils left at 0 % (stop the other bridge, then '
                             'restart this one)', refuse=True)
            return
        owner = self._owner()
        if owner == self.token or self._owner() == self.token:
            return
        if owner != CONFLICT:
            link.write('mark conflict', 6, link.client.write_register, register, CONFLICT)
            raise _Fault(f'owner register {register} holds token {owner}, not this '
                         f"bridge's ({self.token}): another bridge on the module; both refuse "
                         '(stop one, then restart the other)', refuse=True)
        raise _Fault(f'owner register {register} reads CONFLICT: another bridge on the '
                     'module found this one; both refuse (stop one, then restart the other)',
                     refuse=True)

    # --- outputs and inputs ----------------------------------------------------------------

    def _write_outputs(self) -> None:
        link = self._link
        for name, point in self.machine.outputs.points().items():
            value = self._outputs[name]
            if self._outputs_written.get(name) != value:
                link.write(f'write {name}', 5, link.client.write_coil, point.address,
                           point.raw(value))
                self._outputs_written[name] = value

    def _read_inputs(self) -> InputValues:
        inputs, link = self.machine.inputs, self._link
        addresses = inputs.discrete_inputs
        raw: dict[int, bool] = {}
        if addresses:
            first = min(addresses)
            count = max(addresses) - first + 1
            read = link.bits('read inputs', link.client.read_discrete_inputs, first, count, 2)
            raw = {first + k: b for k, b in enumerate(read)}
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
            input_register = dial.kind == 'input_register'
            read_register = (link.client.read_input_registers if input_register
                             else link.client.read_holding_registers)
            count = link.register('read operator dial', read_register, dial.addresses[0],
                                  4 if input_register else 3)
            dial_pct = dial.decode_register(count)
            top = self.machine.table.max_pct
            if not 0.0 <= dial_pct <= top:
                raise _Fault(f'operator dial: register {count} reads {dial_pct:g} %, outside '
                             f'the {self.machine.table.name} range [0, {top:g}] %')
        tool = None
        if inputs.tool is not None:
            try:
                tool = inputs.tool.decode([raw[a] for a in inputs.tool.addresses])
            except ValueError:   # no number (a turret indexing): no tool's settings either
                tool = NO_TOOL
        return InputValues(enable, threading, dial_pct, tool_number=tool)

    def _failed(self, fault: _Fault | str) -> str:
        self._link.close()
        self.missed_in_row = 0
        self.fault = f'{self.where}: {fault}'
        if isinstance(fault, _Fault) and fault.refuse:
            self.refused = self.fault
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
                read = link.bits('read override', link.client.read_coils, config.first_coil,
                                 len(config.override_coils), 1)
                break
            except _Fault as exc:
                link.close()
                if attempt == 2:
                    raise PmcIoError(f'modbus_tcp {config.address_text}: {exc}') from exc
        bits = config.bits_from(read)
        try:
            return self.machine.table.decode(bits)
        except ValueError as exc:
            raise PmcIoError(f'modbus_tcp {config.address_text}: {exc}') from exc

    def close(self) -> None:
        self._link.close()
