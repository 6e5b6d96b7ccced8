"""Machine files (config/machines): the shipped wiring, the coil patterns of every level, and
errors that name the file, the key and the value."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from turning_force.core.errors import ConfigError
from turning_force.core.pmc.machine import DigitalPoint, load_machine, parse_machine
from turning_force.core.pmc.overrides import get_table

MACHINES = Path(__file__).resolve().parents[2] / 'config' / 'machines'


def machine_data(**backend) -> dict:
    data = {'name': 'test', 'override_table': 'fanuc_0t_4bit',
            'backend': {'type': 'modbus_tcp', 'host': '127.0.0.1', 'port': 5020,
                        'override_coils': [0, 1, 2, 3], 'module_watchdog_s': 0.1}}
    data['backend'].update(backend)
    return data


def test_the_shipped_machines_load():
    zero_t = load_machine(MACHINES / 'fanuc_0t.yaml')
    assert zero_t.table is get_table('fanuc_0t_4bit') and zero_t.backend == 'modbus_tcp'
    assert zero_t.modbus.override_coils == (0, 1, 2, 3) and zero_t.modbus.logic == 'inverted'
    assert zero_t.modbus.readback_first == 512   # a WAGO 750-352's output image
    assert zero_t.inputs.operator_dial.table is get_table('fanuc_0t_4bit')
    assert zero_t.outputs.points() == {'alarm': DigitalPoint(4), 'stop_request': DigitalPoint(5)}
    eight = load_machine(MACHINES / 'fanuc_0i_8bit.yaml')
    assert eight.table is get_table('fanuc_8bit') and len(eight.modbus.override_coils) == 8
    assert eight.inputs.operator_dial is None
    for machine in (zero_t, eight):
        machine.check_table(machine.table.name)
        assert not machine.modbus.is_loopback and machine.modbus.timeout_s is None
        assert machine.modbus.timeout_for(0.01) == 0.01   # default: one control period


@pytest.mark.parametrize('table_name', ['fanuc_0t_4bit', 'fanuc_8bit'])
@pytest.mark.parametrize('logic', ['direct', 'inverted'])
def test_every_level_goes_to_the_coils_and_back(table_name, logic):
    table = get_table(table_name)
    n = table.bit_count
    coils = list(range(10, 10 + n))[::-1]   # wired in reverse order: bit 0 on the last coil
    machine = parse_machine(machine_data(override_coils=coils, logic=logic) | {
        'override_table': table_name}, 'm.yaml')
    config = machine.modbus
    for level in table.levels_pct:
        _, bits = table.encode(level)
        values = config.coils_for(bits)
        assert len(values) == n and config.first_coil == 10
        # The coil of bit k (address coils[k]) holds the signal, complemented when inverted.
        for k in range(n):
            assert values[coils[k] - 10] == (bits[k] != (logic == 'inverted'))
        assert table.decode(config.bits_from(values)) == level


def test_a_machine_with_a_module_on_this_machine_is_loopback():
    assert parse_machine(machine_data(), 'm.yaml').modbus.is_loopback
    assert parse_machine(machine_data(host='localhost'), 'm.yaml').modbus.is_loopback
    assert not parse_machine(machine_data(host='10.0.0.7'), 'm.yaml').modbus.is_loopback


def test_an_inline_table_equal_to_the_experiments_is_accepted():
    inline = {'name': 'my_0t', 'levels_pct': [10.0 * k for k in range(16)],
              'codes': list(range(16)), 'bit_count': 4, 'negative_logic': True}
    machine = parse_machine(machine_data() | {'override_table': inline}, 'm.yaml')
    assert machine.table.name == 'my_0t'
    machine.check_table('fanuc_0t_4bit')
    with pytest.raises(ConfigError, match=r"m.yaml: override_table = 'my_0t': differs from the "
                                          r"experiment's override_table = 'fanuc_8bit'"):
        machine.check_table('fanuc_8bit')


def test_a_simulated_machine_has_only_a_table():
    machine = parse_machine({'override_table': 'ideal'}, 'config/machines/desk.yaml')
    assert machine.name == 'desk' and machine.backend == 'simulated' and machine.modbus is None


@pytest.mark.parametrize(('change', 'message'), [
    ({'port': 70000}, r'backend.port = 70000: expected an integer 1 to 65535'),
    ({'unit_id': True}, r'backend.unit_id = True: expected an integer 0 to 255'),
    ({'override_coils': [0, 1, 3, 4]},
     r'backend.override_coils = \[0, 1, 3, 4\]: not one contiguous block'),
    ({'override_coils': [0, 1, 2]},
     r'backend.override_coils = \[0, 1, 2\]: table fanuc_0t_4bit has 4 bits'),
    ({'override_coils': [0, 1, 1, 2]},
     r'backend.override_coils = \[0, 1, 1, 2\]: an address is used twice'),
    ({'logic': 'negative'}, r"backend.logic = 'negative': expected one of direct, inverted"),
    ({'fail_safe_pct': 105.0}, r'backend.fail_safe_pct = 105.0: expected a finite number in '
                               r'\[0, 100\]'),
    # U6: the module's watchdog level cannot be set above the programmed feed.
    ({'fail_safe_pct': 150.0}, r'backend.fail_safe_pct = 150.0: expected a finite number in '
                               r'\[0, 100\]'),
    ({'fail_safe_pct': 55.0}, r'backend.fail_safe_pct = 55.0: not a level of fanuc_0t_4bit'),
    ({'module_watchdog_s': None}, r"backend.module_watchdog_s = None: missing: the module's own"),
    ({'module_watchdog_s': 5.0},
     r'backend.module_watchdog_s = 5.0: expected a finite number in \(0, 1\]'),
    ({'max_missed_periods': 0}, r'backend.max_missed_periods = 0: expected an integer 1 to 100'),
    # A 4 MB value is named by its start and length, never echoed whole.
    ({'logic': 'x' * 4_000_000}, r"backend.logic = 'x{50,60}\.\.\. \(4000000 long\): expected one "
                                 r'of direct, inverted$'),
    ({'timeout_s': 0.0}, r'backend.timeout_s = 0.0: expected a finite number in \(0, 10\]'),
    ({'reconnect_max_s': 0.01}, r'backend.reconnect_max_s = 0.01: below reconnect_min_s'),
    ({'hots': 'x'}, r"backend: unknown keys \['hots'\]"),
    ({'type': 'profinet'}, r"backend.type = 'profinet': expected one of simulated, modbus_tcp"),
])
def test_a_bad_backend_is_named(change, message):
    with pytest.raises(ConfigError, match=r'^m\.yaml: ' + message):
        parse_machine(machine_data(**change), 'm.yaml')


def test_bad_inputs_and_outputs_are_named():
    overlap = machine_data() | {'outputs': {'alarm': {'coil': 2}}}
    with pytest.raises(ConfigError, match=r'outputs.alarm.coil = 2: already used by the '
                                          'override'):
        parse_machine(overlap, 'm.yaml')
    twice = machine_data() | {'inputs': {'program_enable': {'discrete_input': 1},
                                         'threading': {'discrete_input': 1}}}
    with pytest.raises(ConfigError, match=r'discrete inputs \[1, 1\]: an address is used twice'):
        parse_machine(twice, 'm.yaml')
    dial = machine_data() | {'inputs': {'operator_dial': {'discrete_inputs': [4, 5],
                                                          'table': 'fanuc_0t_4bit'}}}
    with pytest.raises(ConfigError, match=r'inputs.operator_dial.discrete_inputs = \[4, 5\]: '
                                          'table fanuc_0t_4bit reads 4 bits'):
        parse_machine(dial, 'm.yaml')
    no_module = {'override_table': 'fanuc_0t_4bit', 'outputs': {'alarm': {'coil': 4}}}
    with pytest.raises(ConfigError, match='inputs/outputs need a module'):
        parse_machine(no_module, 'm.yaml')
    with pytest.raises(ConfigError, match=r"m.yaml: override_table = 'fanuc_9t': unknown; "
                                          'known: fanuc_0t_4bit, fanuc_8bit, ideal'):
        parse_machine(machine_data() | {'override_table': 'fanuc_9t'}, 'm.yaml')


def test_the_dial_reads_bits_or_a_register():
    bits = parse_machine(machine_data() | {'inputs': {'operator_dial': {
        'discrete_inputs': [4, 5, 6, 7], 'table': 'fanuc_0t_4bit'}}}, 'm.yaml')
    dial = bits.inputs.operator_dial
    # 70 %: code 7, its signals active low: 0001 (bit 0 first), read as wired (direct).
    assert dial.decode_bits([False, False, False, True]) == 70.0
    register = parse_machine(machine_data() | {'inputs': {'operator_dial': {
        'input_register': 3, 'scale_pct': 0.5}}}, 'm.yaml').inputs.operator_dial
    assert register.kind == 'input_register' and register.decode_register(140) == 70.0


def test_a_missing_or_broken_file_is_named(tmp_path):
    with pytest.raises(ConfigError, match=r'nowhere.yaml: cannot read machine file'):
        load_machine(tmp_path / 'nowhere.yaml')
    bad = tmp_path / 'bad.yaml'
    bad.write_text('override_table: [1, 2')
    with pytest.raises(ConfigError, match=r'bad.yaml: not valid YAML'):
        load_machine(bad)
    bad.write_text(yaml.safe_dump(['not', 'a', 'mapping']))
    with pytest.raises(ConfigError, match=r'bad.yaml: expected a mapping, got list'):
        load_machine(bad)


def test_the_shipped_wiring_is_safe_when_de_energised():
    # Every output off (the module's watchdog, a dead PC, lost 24 V): the PMC reads 0 % on
    # both shipped machines, at or below any hand-back level.
    for name in ('fanuc_0t.yaml', 'fanuc_0i_8bit.yaml'):
        machine = load_machine(MACHINES / name)
        assert machine.all_off_pct() == 0.0
        machine.check_de_energised(0.0)
        # The module's watchdog must outlast the miss budget at the 10 ms period.
        machine.modbus.check_miss_budget(0.01, name)


def test_direct_logic_on_the_four_bit_table_is_refused_with_the_reason():
    # U1/item 2: on fanuc_0t_4bit every signal off is the code for 150 %: with direct logic a
    # module that drops its outputs would run the feed at 150 %.
    machine = parse_machine(machine_data(logic='direct'), 'm.yaml')
    assert machine.all_off_pct() == 150.0
    with pytest.raises(ConfigError, match=r"^m.yaml: backend.logic = 'direct': with every output "
                                          r'off \(0000: module watchdog, PC or 24 V lost\) the '
                                          r'PMC reads 150 % on fanuc_0t_4bit, above the hand-back '
                                          r'level \(100 %\); wire it so that off is safe '
                                          r'\(logic: inverted'):
        machine.check_de_energised(100.0)
    inverted = parse_machine(machine_data(logic='inverted', fail_safe_pct=0.0), 'm.yaml')
    inverted.check_de_energised(0.0)
    with pytest.raises(ConfigError, match=r'backend.fail_safe_pct = 100: above the hand-back '
                                          r'level \(50 %\)'):
        parse_machine(machine_data(logic='inverted'), 'm.yaml').check_de_energised(50.0)


def test_the_miss_budget_stays_inside_the_modules_watchdog():
    machine = parse_machine(machine_data(max_missed_periods=10), 'm.yaml')
    with pytest.raises(ConfigError, match=r'^m.yaml: backend.max_missed_periods = 10: 10 x the '
                                          r'10 ms control period = 100 ms, not below '
                                          r'backend.module_watchdog_s = 100 ms$'):
        machine.modbus.check_miss_budget(0.01, 'm.yaml')
    machine.modbus.check_miss_budget(0.005, 'm.yaml')   # 50 ms < 100 ms


def test_the_tool_in_use_reads_bcd_or_binary_inputs():
    # FANUC puts the T code's number out on PMC signals; the ladder copies them to the module.
    bcd = parse_machine(machine_data() | {'inputs': {'tool': {
        'discrete_inputs': [8, 9, 10, 11, 12, 13, 14, 15]}}}, 'm.yaml').inputs.tool
    assert bcd.code == 'bcd'   # the default: FANUC's T code signals
    # T12: units 2 (0100, bit 0 first), tens 1 (1000).
    assert bcd.decode([False, True, False, False, True, False, False, False]) == 12
    with pytest.raises(ValueError, match='BCD digit 0 reads 12: not a tool number'):
        bcd.decode([False, False, True, True, False, False, False, False])
    binary = parse_machine(machine_data() | {'inputs': {'tool': {
        'discrete_inputs': [8, 9, 10, 11, 12], 'code': 'binary', 'logic': 'inverted'}}},
        'm.yaml').inputs.tool
    assert binary.decode([True, False, True, True, True]) == 2   # inverted: 01000
    assert parse_machine(machine_data() | {'inputs': {'tool': {
        'discrete_inputs': [8, 9, 10, 11]}}}, 'm.yaml').inputs.discrete_inputs == (8, 9, 10, 11)


@pytest.mark.parametrize(('tool', 'message'), [
    ({'discrete_inputs': [8, 9, 10, 11, 12, 13]},
     r'inputs.tool.discrete_inputs = \[8, 9, 10, 11, 12, 13\]: 6 bits: a bcd tool number takes '
     'four bits a digit'),
    ({'discrete_inputs': [8, 9, 10, 11], 'code': 'gray'},
     r"inputs.tool.code = 'gray': expected one of bcd, binary"),
    ({'discrete_inputs': [0, 9, 10, 11], 'strobe': 3}, r"inputs.tool: unknown keys \['strobe'\]"),
])
def test_a_bad_tool_input_is_named(tool, message):
    with pytest.raises(ConfigError, match=message):
        parse_machine(machine_data() | {'inputs': {'tool': tool}}, 'm.yaml')
