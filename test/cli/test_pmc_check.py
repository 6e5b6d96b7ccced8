"""turning-force pmc-check against a pymodbus server on 127.0.0.1: every level written and read
back, and the failures a commissioning engineer meets, each named by its level."""

from __future__ import annotations

import pytest

from modbus_helpers import local_machine, write_machine
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
    assert '    100 %    10   1010       1010' in out
    assert 'all 16 levels read back as written' in out
    # The levels in order, each in one request, then the programmed feed left on the PMC.
    patterns = [w.values for w in server.writes if w.address == 0]
    assert patterns == [TABLE.encode(level)[1] for level in TABLE.levels_pct] + [
        TABLE.encode(100.0)[1]]
    assert server.coils(0, 4) == list(TABLE.encode(100.0)[1])
    assert "module's watchdog: set its fail-safe outputs to 1010 (coils 0-3)" in out
    # With direct logic the 0-T reads 150 % from a dead module: said, with the remedy.
    assert 'every output off (module unpowered): the PMC reads 150 %  <- not the fail-safe' in out


def test_a_stuck_output_fails_at_the_first_level_it_spoils(capfd, server, tmp_path):
    machine = write_machine(tmp_path / 'm.yaml', port=server.port, timeout_s=1.0)
    server.stuck_coils = {0: True}   # *FV0's relay welded on
    code, out, _ = check(capfd, machine)
    assert code == 1
    # 0 % writes 1111: fine. 10 % writes 0111: read back 1111.
    assert 'FAILED at level 10 % (code 1, coils 0111): modbus_tcp 127.0.0.1:' in out
    assert out.count(' ok\n') == 1 and 'read back 1111, wrote 0111' in out


def test_a_module_that_refuses_writes(capfd, server, tmp_path):
    machine = write_machine(tmp_path / 'm.yaml', port=server.port, timeout_s=1.0)
    server.refuse_writes = True
    code, out, _ = check(capfd, machine)
    assert code == 1
    assert ('FAILED at level 0 % (code 0, coils 1111): modbus_tcp 127.0.0.1:'
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
