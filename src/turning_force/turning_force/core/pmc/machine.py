"""A machine file: one CNC's override interface and how it is wired (``config/machines/``).

It names the override table the PMC reads, the ``backend`` (``simulated``, or a Modbus/TCP
digital I/O module whose outputs drive the PMC's inputs) and the optional inputs (program
enable, threading, operator dial, the tool in use: the T code's number, BCD or binary) and
outputs (alarm, stop request); the shipped files and
docs/machine-pc.md show every key. ``logic`` is the wiring between a module's point and the
PMC (``direct``: an energised output, or a set input, means the signal is 1); the PMC's own
sense of its signals (FANUC's active-low ``*FV``) belongs to the table. The override coils form
one contiguous block, so that one request sets every bit and the PMC never sees a pattern
between two levels. A dial is read as discrete inputs decoded with a table, or as a register
scaled to percent.

Errors name the file, the key and the bad value. ROS-free: the nodes and ``pmc-check`` read it.
"""

from __future__ import annotations

import ipaddress
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from turning_force.core.errors import ConfigError, short_repr
from turning_force.core.pmc.overrides import OverrideTable, get_table
from turning_force.core.yamlfile import read_yaml_file

__all__ = ['BACKENDS', 'DialInput', 'DigitalPoint', 'Machine', 'MachineInputs', 'MachineOutputs',
           'ModbusTcp', 'ToolInput', 'load_machine', 'parse_machine']

BACKENDS = ('simulated', 'modbus_tcp')
LOGIC = ('direct', 'inverted')
TOOL_CODES = ('bcd', 'binary')
_MAX_ADDRESS = 65535


@dataclass(frozen=True)
class DigitalPoint:
    """One bit on the module: a coil (output) or a discrete input, and its wiring sense."""

    address: int
    logic: str = 'direct'

    def signal(self, raw: bool) -> bool:
        """The signal a Modbus bit means (``inverted``: the complement)."""
        return raw != (self.logic == 'inverted')

    def raw(self, signal: bool) -> bool:
        """The Modbus bit that sets a signal."""
        return signal != (self.logic == 'inverted')


@dataclass(frozen=True)
class DialInput:
    """The operator's override dial: discrete inputs decoded with a table, or a register.

    ``kind`` is ``bits`` (``addresses`` are discrete inputs, bit 0 first, decoded with
    ``table`` after ``logic``), ``input_register`` or ``holding_register`` (``addresses`` holds
    one register; percent = raw count * ``scale_pct``).
    """

    kind: str
    addresses: tuple[int, ...]
    logic: str = 'direct'
    table: OverrideTable | None = None
    scale_pct: float = 1.0

    def decode_bits(self, raw: Sequence[bool]) -> float:
        """The dial's override [%] from its discrete inputs as read (``ValueError``: no level)."""
        assert self.table is not None
        point = DigitalPoint(0, self.logic)
        return self.table.decode(tuple(point.signal(bool(b)) for b in raw))

    def decode_register(self, raw: int) -> float:
        """The dial's override [%] from its register's count."""
        return raw * self.scale_pct


@dataclass(frozen=True)
class ToolInput:
    """The tool in use, as the ladder puts the T code's number out on discrete inputs (FANUC's
    T code signals, strobed by TF), bit 0 first: ``bcd`` (four bits a decimal digit, units
    first) or ``binary``; ``logic`` the wiring's sense."""

    addresses: tuple[int, ...]
    code: str = 'bcd'
    logic: str = 'direct'

    def decode(self, raw: Sequence[bool]) -> int:
        """The tool number the inputs as read give (``ValueError``: a BCD digit above 9)."""
        point = DigitalPoint(0, self.logic)
        bits = [point.signal(bool(b)) for b in raw]
        if self.code == 'binary':
            return sum(1 << k for k, bit in enumerate(bits) if bit)
        number = 0
        for place in range(len(bits) // 4):
            digit = sum(1 << k for k, bit in enumerate(bits[4 * place:4 * place + 4]) if bit)
            if digit > 9:
                raise ValueError(f'BCD digit {place} reads {digit}: not a tool number')
            number += digit * 10 ** place
        return number


@dataclass(frozen=True)
class MachineInputs:
    """Inputs from the machine, each optional: program enable (an M-code relay), thread
    cutting or tapping in progress, the operator's override dial, and the tool in use."""

    program_enable: DigitalPoint | None = None
    threading: DigitalPoint | None = None
    operator_dial: DialInput | None = None
    tool: ToolInput | None = None

    @property
    def discrete_inputs(self) -> tuple[int, ...]:
        """Every discrete-input address the inputs use."""
        out: list[int] = []
        for point in (self.program_enable, self.threading):
            if point is not None:
                out.append(point.address)
        if self.operator_dial is not None and self.operator_dial.kind == 'bits':
            out.extend(self.operator_dial.addresses)
        if self.tool is not None:
            out.extend(self.tool.addresses)
        return tuple(out)


@dataclass(frozen=True)
class MachineOutputs:
    """Outputs to the machine, each optional: an alarm lamp or PMC alarm input, and a stop or
    retract request (a PMC input the ladder turns into feed hold or a retract cycle)."""

    alarm: DigitalPoint | None = None
    stop_request: DigitalPoint | None = None

    def points(self) -> dict[str, DigitalPoint]:
        return {name: point for name, point in (('alarm', self.alarm),
                                                ('stop_request', self.stop_request))
                if point is not None}


@dataclass(frozen=True)
class ModbusTcp:
    """A Modbus/TCP digital I/O module whose outputs drive the PMC's override inputs."""

    host: str
    port: int = 502
    unit_id: int = 1
    override_coils: tuple[int, ...] = ()
    logic: str = 'direct'
    readback_address: int | None = None
    timeout_s: float | None = None
    reconnect_min_s: float = 0.1
    reconnect_max_s: float = 5.0
    fail_safe_pct: float = 100.0
    module_watchdog_s: float = 0.1
    max_missed_periods: int = 3
    owner_register: int | None = None

    @property
    def first_coil(self) -> int:
        return min(self.override_coils)

    @property
    def readback_first(self) -> int:
        """First coil read back: the module's output image (or the coils themselves)."""
        return self.first_coil if self.readback_address is None else self.readback_address

    @property
    def is_loopback(self) -> bool:
        """True when the module is on this machine (a simulated PMC server)."""
        if self.host == 'localhost':
            return True
        try:
            return ipaddress.ip_address(self.host).is_loopback
        except ValueError:
            return False

    def coils_for(self, bits: Sequence[bool]) -> list[bool]:
        """The coil values, from ``first_coil`` on, that set the PMC signals ``bits`` (bit 0
        first, as :meth:`OverrideTable.encode` gives them): one write request."""
        if len(bits) != len(self.override_coils):
            raise ValueError(f'expected {len(self.override_coils)} bits, got {len(bits)}')
        point = DigitalPoint(0, self.logic)
        values = [False] * len(bits)
        for bit, address in zip(bits, self.override_coils, strict=True):
            values[address - self.first_coil] = point.raw(bool(bit))
        return values

    def bits_from(self, coils: Sequence[bool]) -> tuple[bool, ...]:
        """The PMC signals (bit 0 first) that coil values from ``first_coil`` on set."""
        point = DigitalPoint(0, self.logic)
        return tuple(point.signal(bool(coils[address - self.first_coil]))
                     for address in self.override_coils)

    def timeout_for(self, control_period_s: float) -> float:
        """The answer timeout in force: the file's, or one control period."""
        return control_period_s if self.timeout_s is None else self.timeout_s

    @property
    def address_text(self) -> str:
        return f'{self.host}:{self.port} unit {self.unit_id}'

    def check_miss_budget(self, control_period_s: float, source: str) -> None:
        """Refuse a miss budget the module's own watchdog would not outlast: the bridge faults
        after ``max_missed_periods`` consecutive misses, which must come before the module drops
        its outputs (``module_watchdog_s``), or a busy PC would trip the module first."""
        budget_s = self.max_missed_periods * control_period_s
        if budget_s >= self.module_watchdog_s:
            raise ConfigError(
                f'{source}: backend.max_missed_periods = {self.max_missed_periods}: '
                f'{self.max_missed_periods} x the {control_period_s * 1e3:g} ms control period '
                f'= {budget_s * 1e3:g} ms, not below backend.module_watchdog_s = '
                f'{self.module_watchdog_s * 1e3:g} ms')


@dataclass(frozen=True)
class Machine:
    """One CNC's override interface: table, backend, optional inputs and outputs."""

    name: str
    source: str
    table: OverrideTable
    backend: str = 'simulated'
    modbus: ModbusTcp | None = None
    inputs: MachineInputs = MachineInputs()
    outputs: MachineOutputs = MachineOutputs()
    description: str = ''

    def all_off_pct(self) -> float | None:
        """What the PMC reads with every override output off (the module's watchdog tripped,
        its 24 V or the PC lost) [%]; ``None`` when that pattern is no level of the table."""
        if self.modbus is None:
            return None
        off = self.modbus.bits_from([False] * len(self.modbus.override_coils))
        try:
            return self.table.decode(off)
        except ValueError:
            return None

    def check_de_energised(self, hand_back_pct: float) -> None:
        """Refuse wiring that is not safe when de-energised: with every output off the PMC
        must read a level at or below ``hand_back_pct`` (docs/safety.md)."""
        modbus = self.modbus
        if modbus is None:
            return
        off = self.all_off_pct()
        n = len(modbus.override_coils)
        if off is None:
            raise ConfigError(f'{self.source}: backend.logic = {modbus.logic!r}: with every '
                              f'output off ({"0" * n}) the PMC reads no level of '
                              f'{self.table.name}; the wiring must fall back to a level')
        if off > hand_back_pct:
            other = 'inverted' if modbus.logic == 'direct' else 'direct'
            raise ConfigError(
                f'{self.source}: backend.logic = {modbus.logic!r}: with every output off '
                f'({"0" * n}: module watchdog, PC or 24 V lost) the PMC reads {off:g} % on '
                f'{self.table.name}, above the hand-back level ({hand_back_pct:g} %); wire it '
                f'so that off is safe (logic: {other}, or a ladder relay that falls back to the '
                'dial): docs/safety.md')
        if modbus.fail_safe_pct > hand_back_pct:
            raise ConfigError(f'{self.source}: backend.fail_safe_pct = '
                              f'{modbus.fail_safe_pct:g}: above the hand-back level '
                              f'({hand_back_pct:g} %)')

    def check_table(self, override_table: str) -> None:
        """Refuse a machine whose table is not the experiment's ``override_table``: the
        controller, the simulator and the bridge must quantise to the same levels."""
        try:
            expected = get_table(override_table)
        except ConfigError as exc:
            raise ConfigError(f'{self.source}: {exc}') from exc
        mine = self.table
        same = (mine.levels_pct, mine.codes, mine.bit_count, mine.negative_logic,
                mine.continuous, dict(mine.decode_aliases)) == (
            expected.levels_pct, expected.codes, expected.bit_count, expected.negative_logic,
            expected.continuous, dict(expected.decode_aliases))
        if not same:
            raise ConfigError(f'{self.source}: override_table = {mine.name!r}: differs from the '
                              f"experiment's override_table = {override_table!r}")


def load_machine(path: str | Path) -> Machine:
    """Read and validate a machine file."""
    path = Path(path)
    return parse_machine(read_yaml_file(path, ' machine file'), str(path))


class _Reader:
    """Reads keys of one mapping, naming the file and key path in every error."""

    def __init__(self, source: str, data: Any, path: str = '') -> None:
        self.source = source
        self.path = path
        if not isinstance(data, Mapping):
            where = f'{source}: {path}' if path else source
            raise ConfigError(f'{where}: expected a mapping, got {type(data).__name__}')
        self.data: Mapping[str, Any] = data

    def key(self, name: str) -> str:
        return f'{self.path}.{name}' if self.path else name

    def fail(self, name: str, reason: str) -> ConfigError:
        return ConfigError(f'{self.source}: {self.key(name)} = {short_repr(self.data.get(name))}: '
                           f'{reason}')

    def only(self, known: Sequence[str]) -> None:
        unknown = sorted(set(self.data) - set(known))
        if unknown:
            where = f'{self.source}: {self.path}' if self.path else self.source
            raise ConfigError(f'{where}: unknown keys {unknown}; known: {sorted(known)}')

    def has(self, name: str) -> bool:
        return self.data.get(name) is not None

    def child(self, name: str) -> _Reader:
        return _Reader(self.source, self.data.get(name, {}) or {}, self.key(name))

    def text(self, name: str, default: str | None = None,
             choices: Sequence[str] = ()) -> str:
        value = self.data.get(name, default)
        if value is None:
            raise self.fail(name, 'missing')
        if not isinstance(value, str) or not value:
            raise self.fail(name, 'expected a non-empty string')
        if choices and value not in choices:
            raise self.fail(name, f'expected one of {", ".join(choices)}')
        return value

    def integer(self, name: str, default: int | None = None, low: int = 0,
                high: int = _MAX_ADDRESS) -> int:
        value = self.data.get(name, default)
        if value is None:
            raise self.fail(name, 'missing')
        if isinstance(value, bool) or not isinstance(value, int) or not low <= value <= high:
            raise self.fail(name, f'expected an integer {low} to {high}')
        return value

    def number(self, name: str, default: float | None, low: float = 0.0,
               low_open: bool = True, high: float = math.inf) -> float | None:
        value = self.data.get(name, default)
        if value is None:
            return None
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise self.fail(name, 'expected a number')
        number = float(value)
        below = number <= low if low_open else number < low
        if not math.isfinite(number) or below or number > high:
            bracket = '(' if low_open else '['
            raise self.fail(name, f'expected a finite number in {bracket}{low:g}, {high:g}]')
        return number

    def addresses(self, name: str) -> tuple[int, ...]:
        value = self.data.get(name)
        if (not isinstance(value, list) or not value
                or any(isinstance(v, bool) or not isinstance(v, int)
                       or not 0 <= v <= _MAX_ADDRESS for v in value)):
            raise self.fail(name, f'expected a list of addresses 0 to {_MAX_ADDRESS}')
        if len(set(value)) != len(value):
            raise self.fail(name, 'an address is used twice')
        return tuple(value)


def _table(reader: _Reader, name: str) -> OverrideTable:
    value = reader.data.get(name)
    if isinstance(value, str):
        try:
            return get_table(value)
        except ConfigError as exc:
            raise reader.fail(name, str(exc).split(': ', 1)[-1]) from exc
    if isinstance(value, Mapping):
        return OverrideTable.from_mapping(value, f'{reader.source}: {reader.key(name)}')
    raise reader.fail(name, 'expected a built-in table name or an inline table (a mapping)')


def _point(reader: _Reader, name: str, address_key: str) -> DigitalPoint | None:
    if not reader.has(name):
        return None
    point = reader.child(name)
    point.only((address_key, 'logic'))
    return DigitalPoint(point.integer(address_key), point.text('logic', 'direct', LOGIC))


def _dial(reader: _Reader) -> DialInput | None:
    if not reader.has('operator_dial'):
        return None
    dial = reader.child('operator_dial')
    if dial.has('discrete_inputs'):
        dial.only(('discrete_inputs', 'table', 'logic'))
        addresses = dial.addresses('discrete_inputs')
        table = _table(dial, 'table')
        if table.continuous or table.bit_count != len(addresses):
            raise dial.fail('discrete_inputs', f'table {table.name} reads '
                                               f'{table.bit_count} bits')
        return DialInput('bits', addresses, dial.text('logic', 'direct', LOGIC), table)
    for kind in ('input_register', 'holding_register'):
        if dial.has(kind):
            dial.only((kind, 'scale_pct'))
            scale = dial.number('scale_pct', 1.0)
            assert scale is not None
            return DialInput(kind, (dial.integer(kind),), scale_pct=scale)
    raise ConfigError(f'{reader.source}: inputs.operator_dial: give discrete_inputs (with '
                      'table), input_register or holding_register')


def _tool(reader: _Reader) -> ToolInput | None:
    if not reader.has('tool'):
        return None
    tool = reader.child('tool')
    tool.only(('discrete_inputs', 'code', 'logic'))
    addresses = tool.addresses('discrete_inputs')
    code = tool.text('code', 'bcd', TOOL_CODES)
    if len(addresses) > 16 or (code == 'bcd' and len(addresses) % 4):
        raise tool.fail('discrete_inputs', f'{len(addresses)} bits: a {code} tool number takes '
                        + ('four bits a digit, up to four digits' if code == 'bcd'
                           else 'at most 16'))
    return ToolInput(addresses, code, tool.text('logic', 'direct', LOGIC))


def _modbus(backend: _Reader, table: OverrideTable) -> ModbusTcp:
    backend.only(('type', 'host', 'port', 'unit_id', 'override_coils', 'logic',
                  'readback_address', 'timeout_s', 'reconnect_min_s', 'reconnect_max_s',
                  'fail_safe_pct', 'module_watchdog_s', 'max_missed_periods', 'owner_register'))
    if table.continuous:
        raise ConfigError(f"{backend.source}: backend.type = 'modbus_tcp': the table "
                          f'{table.name} is continuous; a PMC takes levels')
    coils = backend.addresses('override_coils')
    if len(coils) != table.bit_count:
        raise backend.fail('override_coils', f'table {table.name} has {table.bit_count} bits')
    if sorted(coils) != list(range(min(coils), min(coils) + len(coils))):
        raise backend.fail('override_coils', 'not one contiguous block: the bits must go in '
                                             'one write request')
    timeout = backend.number('timeout_s', None, high=10.0)
    low = backend.number('reconnect_min_s', 0.1, high=60.0)
    high = backend.number('reconnect_max_s', 5.0, high=3600.0)
    assert low is not None and high is not None
    if high < low:
        raise backend.fail('reconnect_max_s', f'below reconnect_min_s ({low:g})')
    # The level the module's watchdog holds when the PC is gone: never above the programmed
    # feed (a safety parameter that cannot be set unsafe: docs/safety.md).
    fail_safe = backend.number('fail_safe_pct', 100.0, low_open=False, high=100.0)
    assert fail_safe is not None
    if fail_safe not in table.levels_pct:
        raise backend.fail('fail_safe_pct', f'not a level of {table.name}')
    if not backend.has('module_watchdog_s'):
        raise backend.fail('module_watchdog_s', "missing: the module's own fieldbus watchdog "
                           'time (it turns the outputs off when the PC stops talking)')
    watchdog = backend.number('module_watchdog_s', None, high=1.0)
    assert watchdog is not None
    misses = backend.integer('max_missed_periods', 3, low=1, high=100)
    owner = (backend.integer('owner_register') if backend.has('owner_register') else None)
    readback = (backend.integer('readback_address') if backend.has('readback_address')
                else None)
    return ModbusTcp(
        host=backend.text('host'), port=backend.integer('port', 502, low=1),
        unit_id=backend.integer('unit_id', 1, high=255), override_coils=coils,
        logic=backend.text('logic', 'direct', LOGIC), readback_address=readback,
        timeout_s=timeout, reconnect_min_s=low, reconnect_max_s=high, fail_safe_pct=fail_safe,
        module_watchdog_s=watchdog, max_missed_periods=misses, owner_register=owner)


def parse_machine(data: Any, source: str) -> Machine:
    """A validated :class:`Machine` from a machine file's parsed YAML; errors name ``source``."""
    top = _Reader(source, data)
    top.only(('name', 'description', 'override_table', 'backend', 'inputs', 'outputs'))
    name = top.text('name', Path(source).stem)
    table = _table(top, 'override_table')
    backend = top.child('backend')
    kind = backend.text('type', 'simulated', BACKENDS)
    modbus = None
    if kind == 'modbus_tcp':
        modbus = _modbus(backend, table)
    else:
        backend.only(('type',))
    ins = top.child('inputs')
    ins.only(('program_enable', 'threading', 'operator_dial', 'tool'))
    inputs = MachineInputs(_point(ins, 'program_enable', 'discrete_input'),
                           _point(ins, 'threading', 'discrete_input'), _dial(ins), _tool(ins))
    outs = top.child('outputs')
    outs.only(('alarm', 'stop_request'))
    outputs = MachineOutputs(_point(outs, 'alarm', 'coil'), _point(outs, 'stop_request', 'coil'))
    taken = set(modbus.override_coils) if modbus else set()
    for label, point in outputs.points().items():
        if point.address in taken:
            raise ConfigError(f'{source}: outputs.{label}.coil = {point.address}: already used '
                              'by the override or another output')
        taken.add(point.address)
    discrete = inputs.discrete_inputs
    if len(set(discrete)) != len(discrete):
        raise ConfigError(f'{source}: inputs: discrete inputs {list(discrete)}: an address is '
                          'used twice')
    if kind == 'simulated' and (discrete or inputs.operator_dial or outputs.points()):
        raise ConfigError(f'{source}: inputs/outputs need a module: backend.type = '
                          "'modbus_tcp'")
    return Machine(name=name, source=source, table=table, backend=kind, modbus=modbus,
                   inputs=inputs, outputs=outputs,
                   description=str(top.data.get('description', '') or ''))
