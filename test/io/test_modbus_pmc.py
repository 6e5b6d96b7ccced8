"""The PMC over Modbus/TCP against real pymodbus servers on 127.0.0.1 (in this process and in a
process of its own): every level's bit pattern, one request per write, read-back, inputs and
outputs, and the faults: a server killed and restarted, one that answers late, one that
refuses writes, a read-back that differs."""

from __future__ import annotations

from dataclasses import replace

import pytest

from modbus_helpers import ServerProcess, local_machine, write_machine
from turning_force.core.pmc.machine import DialInput, ToolInput
from turning_force.core.pmc.overrides import get_table
from turning_force.core.tools import NO_TOOL
from turning_force.io.modbus_pmc import CoilReader, ModbusPmc
from turning_force.io.pmc_server import SimulatedPmcServer, Write

# Generous for a loaded CI machine: these tests are about what goes over the wire, not how
# fast. The slow-server test sets its own.
TIMEOUT_S = 1.0


class Clock:
    """The back-off's clock, moved by hand."""

    def __init__(self) -> None:
        self.now = 0.0

    def __call__(self) -> float:
        return self.now


@pytest.fixture
def served():
    """(server, machine_name -> Machine on its port) with the 0-T's read-back image mirrored."""
    server = SimulatedPmcServer(local_machine('fanuc_0t.yaml'))
    port = server.start()
    try:
        yield server, lambda name='fanuc_0t.yaml', **kw: local_machine(
            name, port, **{'timeout_s': TIMEOUT_S, **kw})
    finally:
        server.stop()


def override_writes(server, first_coil: int) -> list[Write]:
    return [w for w in server.writes if w.address == first_coil]


@pytest.mark.parametrize('name', ['fanuc_0t.yaml', 'fanuc_0i_8bit.yaml'])
def test_every_level_reaches_the_coils_in_one_request(served, name):
    server, machine_on = served
    machine = machine_on(name, readback_address=None)   # read back the coils themselves
    table, config = machine.table, machine.modbus
    pmc = ModbusPmc(machine, 0.01)
    assert pmc.connect() == ''
    n = len(config.override_coils)
    for level in table.levels_pct:
        code, bits = table.encode(level)
        result = pmc.write(code, bits)
        assert result.ok, result.fault
        assert result.bits == bits and table.decode(result.bits) == level
        # What the PMC's input image holds, decoded as the PMC would.
        assert table.decode(config.bits_from(server.coils(config.first_coil, n))) == level
    # One write request per level, each exactly a level's pattern: nothing in between.
    writes = override_writes(server, config.first_coil)
    assert [w.values for w in writes] == [tuple(config.coils_for(table.encode(level)[1]))
                                          for level in table.levels_pct]
    pmc.close()


def test_the_read_back_comes_from_the_output_image(served):
    server, machine_on = served
    machine = machine_on()   # fanuc_0t.yaml: written at coils 0-3, read back at 512-515
    pmc = ModbusPmc(machine, 0.01)
    assert pmc.connect() == ''
    code, bits = machine.table.encode(70.0)
    assert pmc.write(code, bits).bits == bits
    assert server.coils(512, 4) == server.coils(0, 4) == machine.modbus.coils_for(bits)


def test_a_read_back_that_differs_is_a_fault(served):
    _, machine_on = served
    # The read-back address points at coils nothing drives (a wrong readback_address).
    machine = machine_on(readback_address=600)
    pmc = ModbusPmc(machine, 0.01)
    assert pmc.connect() == ''
    result = pmc.write(*machine.table.encode(100.0))
    assert not result.ok and result.bits == ()
    # 100 %: code 10, active low: signals 1010 from bit 0; inverted wiring: coils 0101.
    assert result.fault.endswith('read back 0000, wrote 0101') and not pmc.connected


def test_a_pattern_that_is_not_a_level_is_never_sent(served):
    server, machine_on = served
    pmc = ModbusPmc(machine_on(), 0.01)
    assert pmc.connect() == ''
    before = len(server.writes)
    with pytest.raises(ValueError, match=r'code 3 with bits .* is not a level of fanuc_0t_4bit'):
        pmc.write(3, get_table('fanuc_0t_4bit').encode(40.0)[1])
    eight = machine_on('fanuc_0i_8bit.yaml', readback_address=None)
    pmc8 = ModbusPmc(eight, 0.01)
    assert pmc8.connect() == ''
    with pytest.raises(ValueError, match='not a level of fanuc_8bit'):
        pmc8.write(255, (False,) * 8)   # all signals active: the PMC reads 0 %, not a level
    assert len(server.writes) == before


def test_inputs_are_read_and_outputs_written(served):
    server, machine_on = served
    machine = machine_on()
    pmc = ModbusPmc(machine, 0.01)
    assert pmc.connect() == ''
    # Program enable on, no threading, the dial at 70 % (code 7 on *OV, active low: 0001).
    server.set_discrete_inputs(0, [True, False, False, False, False, True])
    pmc.set_output('alarm', True)
    result = pmc.write(*machine.table.encode(50.0))
    assert result.ok
    assert (result.inputs.program_enable, result.inputs.threading,
            result.inputs.operator_dial_pct) == (True, False, 70.0)
    assert server.coils(4, 2) == [True, False]   # alarm on, stop request off
    writes = len(server.writes)
    pmc.write(*machine.table.encode(50.0))
    assert len(server.writes) == writes + 1      # outputs go out when they change only


def test_a_dial_in_a_register(served):
    server, machine_on = served
    machine = machine_on('fanuc_0i_8bit.yaml', readback_address=None)
    dial = DialInput('input_register', (3,), scale_pct=0.5)
    machine = replace(machine, inputs=replace(machine.inputs, operator_dial=dial))
    server.set_input_register(3, 174)
    pmc = ModbusPmc(machine, 0.01)
    assert pmc.connect() == ''
    assert pmc.write(*machine.table.encode(10.0)).inputs.operator_dial_pct == 87.0


def test_a_server_that_refuses_writes(served):
    server, machine_on = served
    pmc = ModbusPmc(machine_on(), 0.01)
    assert pmc.connect() == ''
    server.refuse_writes = True
    result = pmc.write(*get_table('fanuc_0t_4bit').encode(60.0))
    assert not result.ok
    assert result.fault.endswith('write override: refused, exception code 4 (device failure)')
    assert not pmc.connected and pmc.faults == 1


def test_a_server_that_answers_late(served):
    server, machine_on = served
    clock = Clock()
    pmc = ModbusPmc(machine_on(timeout_s=0.05, max_missed_periods=3), 0.01, clock=clock)
    assert pmc.connect() == ''
    table = get_table('fanuc_0t_4bit')
    assert pmc.write(*table.encode(60.0)).ok
    server.latency_s = 0.5   # ten times the timeout
    # A miss is not a fault: the next period tries again on a fresh connection (a late answer
    # must not answer the next request), until three in a row.
    for k in (1, 2):
        result = pmc.write(*table.encode(70.0))
        assert not result.ok and result.fault == '' and result.bits == ()
        assert result.missed.endswith(f': no answer within 50.0 ms (miss {k} of 3 allowed in a '
                                      'row)')
    result = pmc.write(*table.encode(70.0))
    assert result.fault.endswith(': no answer within 50.0 ms; 3 periods in a row')
    assert not pmc.connected and (pmc.misses, pmc.retries, pmc.faults) == (3, 2, 1)
    # Answering in time again: after the back-off, a new connection, whose answers are its own
    # (the late answer went with the old connection).
    server.latency_s = 0.0
    assert not pmc.reconnect_due()
    clock.now = 0.1
    assert pmc.reconnect_due() and pmc.connect() == ''
    assert pmc.write(*table.encode(80.0)).bits == table.encode(80.0)[1]
    assert pmc.missed_in_row == 0


def test_the_default_timeout_is_one_control_period(served):
    _, machine_on = served
    assert ModbusPmc(machine_on(timeout_s=None), 0.02).timeout_s == 0.02


def test_a_server_killed_and_restarted_in_its_own_process(tmp_path):
    clock = Clock()
    server = ServerProcess()
    try:
        machine = local_machine('fanuc_0t.yaml', server.port, readback_address=None,
                                timeout_s=TIMEOUT_S)
        table = machine.table
        pmc = ModbusPmc(machine, 0.01, clock=clock)
        reader = CoilReader(machine)
        assert pmc.connect() == ''
        for level in table.levels_pct:   # every level, as the PMC reads it
            assert pmc.write(*table.encode(level)).ok
            assert reader.read_pct() == level
        server.kill()
        result = pmc.write(*table.encode(50.0))
        assert not result.ok and 'connection lost' in result.fault
        # Back-off: 0.1 s, then doubling while the module stays away.
        clock.now = 0.099
        assert not pmc.reconnect_due()
        clock.now = 0.1
        assert pmc.reconnect_due()
        assert pmc.connect().endswith(f'cannot connect to 127.0.0.1:{server.port}')
        clock.now = 0.29   # 0.1 + 0.2
        assert not pmc.reconnect_due()
        clock.now = 0.31
        assert pmc.reconnect_due()
        server = ServerProcess(port=server.port)   # the module is back, on the same port
        assert pmc.connect() == ''
        assert pmc.write(*table.encode(50.0)).ok
        assert reader.read_pct() == 50.0   # the reader reconnects too
        pmc.close()
        reader.close()
    finally:
        server.stop()


def test_a_machine_file_served_by_a_separate_process_mirrors_its_read_back(tmp_path):
    path = write_machine(tmp_path / 'm.yaml', 'fanuc_0t.yaml', 5020)
    server = ServerProcess(machine_file=path)
    try:
        machine = local_machine('fanuc_0t.yaml', server.port, timeout_s=TIMEOUT_S)
        pmc = ModbusPmc(machine, 0.01)
        assert pmc.connect() == ''
        for level in (0.0, 30.0, 150.0):
            assert pmc.write(*machine.table.encode(level)).ok   # read back from 512
            assert CoilReader(machine).read_pct() == level
    finally:
        server.stop()


def test_the_pmc_server_says_where_it_listens_and_refuses_bad_ports_in_one_line():
    import subprocess
    import sys

    server = ServerProcess()
    try:
        assert server.line.strip() == f'port {server.port}: listening on 127.0.0.1:{server.port}'
    finally:
        server.stop()
    for port in ('-5', '99999', 'x' * 100_000):
        done = subprocess.run([sys.executable, '-m', 'turning_force.io.pmc_server', '--port',
                               port], capture_output=True, text=True, timeout=60)
        assert done.returncode == 2 and 'Traceback' not in done.stderr
        assert done.stderr.strip().endswith('expected a port, 0 to 65535')
        assert len(done.stderr) < 1000


def test_the_tool_in_use_is_read_from_the_module(served):
    # T12 in BCD on discrete inputs 8-15, as the ladder copies FANUC's T code signals; a
    # pattern that is no number (a turret indexing) reads as no tool (NO_TOOL), which no
    # tools-file section has: the bridge hands back rather than guess.
    server, machine_on = served
    machine = machine_on()
    machine = replace(machine, inputs=replace(machine.inputs, tool=ToolInput(tuple(range(8, 16)))))
    server.set_discrete_inputs(8, [False, True, False, False, True, False, False, False])
    pmc = ModbusPmc(machine, 0.01)
    assert pmc.connect() == ''
    assert pmc.write(*machine.table.encode(50.0)).inputs.tool_number == 12
    server.set_discrete_inputs(8, [True, True, True, True, False, False, False, False])
    result = pmc.write(*machine.table.encode(50.0))
    assert result.ok and result.inputs.tool_number == NO_TOOL
