"""turning-force pmc-check against a pymodbus server on 127.0.0.1: every level written and read
back, and the failures a commissioning engineer meets, each named by its level."""

from __future__ import annotations

import sys

import pytest

from modbus_helpers import ServerProcess, coil_pattern, local_machine, write_machine
from turning_force.cli import main
from turning_force.core.pmc.overrides import get_table
from turning_force.io.pmc_server import SimulatedPmcServer

TABLE = get_table('fanuc_0t_4bit')


@pytest.fixture
def server():
    with SimulatedPmcServer(local_machine()) as s:
        yield s


def check(capfd, machine) -> tuple[int, str, str]:
    code = main(['pmc-check', str(machine), '--dwell-s', '0'])
    out, err = capfd.readouterr()
    return code, out, err


def test_every_level_is_written_and_read_back(capfd, server, tmp_path):
    machine = write_machine(tmp_path / 'm.yaml', port=server.port, timeout_s=1.0)
    code, out, _ = check(capfd, machine)
    assert code == 0
    lines = out.splitlines()
    assert sum(line.endswith('ok') for line in lines) == 16
    # 100 %: signals 1010 (active low), on the 0-T's inverted wiring coils 0101.
    assert '    100 %    10   0101       0101' in out
    assert 'all 16 levels read back as written' in out
    # The levels in order, each in one request, then the programmed feed left on the PMC.
    patterns = [w.values for w in server.writes if w.address == 0]
    assert patterns == [tuple(coil_pattern(level)) for level in TABLE.levels_pct] + [
        tuple(coil_pattern(100.0))]
    assert server.coils(0, 4) == coil_pattern(100.0)
    # The module's watchdog for this wiring: its time, outputs off, and what the PMC reads
    # then (U6: never a pattern for 150 %).
    assert ("module's watchdog: set its fieldbus timeout to 500 ms (module_watchdog_s) with "
            'every output off on timeout (0000): the PMC then reads 0 %, at or below the '
            'hand-back level (100 %); the bridge faults first, after 40 missed periods (400 ms)'
            in out)
    assert '150 %' not in out.split('all 16 levels')[1]


def test_wiring_unsafe_when_de_energised_is_refused(capfd, server, tmp_path):
    # U6/item 2: direct logic on the 0-T: every output off reads 150 %. Refused before a
    # single write, with the reason.
    machine = write_machine(tmp_path / 'm.yaml', port=server.port, timeout_s=1.0,
                            logic='direct', fail_safe_pct=100.0)
    code, out, err = check(capfd, machine)
    assert code == 2 and out == '' and server.writes == []
    assert err.strip().startswith(f"turning-force: {machine}: backend.logic = 'direct': with "
                                  'every output off (0000: module watchdog, PC or 24 V lost) '
                                  'the PMC reads 150 % on fanuc_0t_4bit, above the hand-back '
                                  'level (100 %)')
    # A miss budget the module's watchdog would not outlast.
    machine = write_machine(tmp_path / 'm.yaml', port=server.port, max_missed_periods=50)
    code, _, err = check(capfd, machine)
    assert code == 2 and 'max_missed_periods = 50: 50 x the 10 ms control period' in err


@pytest.mark.parametrize('option', [['--dwell-s', 'nan'], ['--dwell-s', '-1'],
                                    ['--control-period-s', '0'], ['--hand-back-pct', '150'],
                                    ['--dwell-s', 'x' * 4_000_000]])
def test_bad_option_values_are_one_line(capfd, tmp_path, option):
    machine = write_machine(tmp_path / 'm.yaml', port=1)
    with pytest.raises(SystemExit) as exited:
        main(['pmc-check', str(machine), *option])
    _, err = capfd.readouterr()
    assert exited.value.code == 2 and 'Traceback' not in err
    assert err.splitlines()[-1].endswith('expected a finite number in ' + {
        '--dwell-s': '[0, 60]', '--control-period-s': '(0, 1]',
        '--hand-back-pct': '[0, 100]'}[option[0]])
    assert len(err) < 1000   # a 4 MB value is not echoed


def test_a_module_lost_in_the_middle_of_the_check(capfd, tmp_path):
    server = ServerProcess()
    machine = write_machine(tmp_path / 'm.yaml', port=server.port, timeout_s=1.0,
                            readback_address=None)
    writes = 0

    def sleep(_: float) -> None:   # the operator reads a level; the module dies at the fourth
        nonlocal writes
        writes += 1
        if writes == 4:
            server.kill()

    from turning_force.core.pmc.machine import load_machine
    from turning_force.io.pmc_check import check_pmc
    try:
        assert not check_pmc(load_machine(machine), sys.stdout, dwell_s=0.0, sleep=sleep)
    finally:
        server.stop()
    out, _ = capfd.readouterr()
    assert 'FAILED at level 40 % (code 4, coils' in out and 'connection lost' in out
    assert ('the module was lost in the middle of the check: the PMC holds the last level read '
            "back, 30 %, until the module's watchdog turns the outputs off (0 %)") in out
    assert 'could not leave the programmed feed' in out


def test_a_stuck_output_fails_at_the_first_level_it_spoils(capfd, server, tmp_path):
    machine = write_machine(tmp_path / 'm.yaml', port=server.port, timeout_s=1.0)
    server.stuck_coils = {0: False}   # *FV0's relay that never closes
    code, out, _ = check(capfd, machine)
    assert code == 1
    # Inverted wiring: 0 % writes 0000: fine. 10 % writes 1000: read back 0000.
    assert 'FAILED at level 10 % (code 1, coils 1000): modbus_tcp 127.0.0.1:' in out
    assert out.count(' ok\n') == 1 and 'read back 0000, wrote 1000' in out


def test_a_module_that_refuses_writes(capfd, server, tmp_path):
    machine = write_machine(tmp_path / 'm.yaml', port=server.port, timeout_s=1.0)
    server.refuse_writes = True
    code, out, _ = check(capfd, machine)
    assert code == 1
    assert ('FAILED at level 0 % (code 0, coils 0000): modbus_tcp 127.0.0.1:'
            f'{server.port} unit 1: write override: refused, exception code 4 (device failure)'
            in out)
    assert 'could not leave the programmed feed' in out


def test_an_unreachable_module_is_one_line(capfd, tmp_path):
    machine = write_machine(tmp_path / 'm.yaml', port=1, timeout_s=1.0)
    code, _, err = check(capfd, machine)
    assert code == 2
    assert err.strip() == ('turning-force: modbus_tcp 127.0.0.1:1 unit 1: cannot connect to '
                           '127.0.0.1:1')


def test_a_machine_without_a_module(capfd, tmp_path):
    machine = tmp_path / 'desk.yaml'
    machine.write_text('override_table: fanuc_0t_4bit\n')
    code, _, err = check(capfd, machine)
    assert code == 2 and "backend.type = 'simulated': no module to check" in err


@pytest.mark.parametrize('fault', ['short', 'wrong_function', 'empty', 'exception'])
def test_a_malformed_answer_is_a_failed_level_not_a_traceback(capfd, tmp_path, fault):
    # pyModbusTCP's server behind the fault proxy: the fifth answer malformed.
    from faultproxy import FaultProxy, Module

    module = Module()
    proxy = FaultProxy(module.start(), lambda index, code: fault if index == 5 else 'pass')
    try:
        machine = write_machine(tmp_path / 'm.yaml', port=proxy.start(), timeout_s=0.2,
                                readback_address=None, max_missed_periods=1)
        code, out, err = check(capfd, machine)
    finally:
        proxy.stop()
        module.stop()
    assert code == 1 and 'Traceback' not in out + err
    failed = [line for line in out.splitlines() if line.startswith('FAILED at level')]
    assert len(failed) == 1 and any(word in failed[0] for word in (
        'malformed answer', 'refused, exception code 4', 'no answer within', 'read back'))
