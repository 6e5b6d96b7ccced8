"""Override tables: levels, quantisation and PMC bit encoding (Park 1998 Sec. 1; Kim Sec. 4)."""

import math

import pytest

from turning_force.core.errors import ConfigError
from turning_force.core.pmc.overrides import TABLES, OverrideTable, get_table


def test_fanuc_0t_has_sixteen_levels_of_ten_percent():
    table = get_table('fanuc_0t_4bit')
    assert table.levels_pct == tuple(10.0 * k for k in range(16))
    assert (table.min_pct, table.max_pct) == (0.0, 150.0)


@pytest.mark.parametrize(('requested', 'applied'), [
    (114.0, 110.0),
    (116.0, 120.0),
    (115.0, 110.0),   # a tie takes the lower level: less feed is the safe side
    (-5.0, 0.0),      # saturates
    (400.0, 150.0),
    (0.0, 0.0),
    (150.0, 150.0),
])
def test_quantise_nearest_level_saturated(requested, applied):
    assert get_table('fanuc_0t_4bit').quantise(requested) == applied


def test_quantise_refuses_non_finite():
    with pytest.raises(ValueError, match='not finite'):
        get_table('fanuc_0t_4bit').quantise(math.nan)


def test_ideal_table_only_saturates():
    ideal = get_table('ideal')
    assert ideal.quantise(113.7) == 113.7
    assert ideal.quantise(151.0) == 150.0


def test_four_bit_signals_are_active_low():
    table = get_table('fanuc_0t_4bit')
    assert table.encode(0.0) == (0, (True, True, True, True))
    assert table.encode(150.0) == (15, (False, False, False, False))
    assert table.encode(10.0) == (1, (False, True, True, True))


def test_eight_bit_weights_and_both_zero_codes():
    table = get_table('fanuc_8bit')
    assert table.max_pct == 254.0
    # 1 % activates *FV0 only (active low: bit 0 written 0, the rest 1).
    assert table.encode(1.0) == (1, (False,) + (True,) * 7)
    assert table.encode(128.0)[1] == (True,) * 7 + (False,)
    # All signals inactive and all active both read as 0 %.
    assert table.decode((True,) * 8) == 0.0
    assert table.decode((False,) * 8) == 0.0


@pytest.mark.parametrize('name', ['fanuc_0t_4bit', 'fanuc_8bit'])
def test_every_level_round_trips_through_the_bits(name):
    table = TABLES[name]
    for level in table.levels_pct:
        _, bits = table.encode(level)
        assert len(bits) == table.bit_count
        assert table.decode(bits) == level


def test_encode_refuses_a_value_that_is_not_a_level():
    with pytest.raises(ValueError, match='quantise it first'):
        get_table('fanuc_0t_4bit').encode(113.0)


def test_table_must_be_strictly_increasing():
    with pytest.raises(ConfigError,
                       match=r'levels_pct = \(0.0, 20.0, 10.0\).*strictly increasing'):
        OverrideTable('bad', (0.0, 20.0, 10.0), (0, 1, 2), 2)


def test_table_codes_must_fit_the_bits():
    with pytest.raises(ConfigError, match='does not fit in 2 bits'):
        OverrideTable('bad', (0.0, 10.0), (0, 4), 2)


def test_table_from_machine_file_mapping():
    table = OverrideTable.from_mapping(
        {'name': 'lathe7', 'levels_pct': [0, 50, 100], 'codes': [0, 1, 2], 'bit_count': 2},
        'config/machines/lathe7.yaml')
    assert table.quantise(70.0) == 50.0
    with pytest.raises(ConfigError, match=r"lathe7.yaml: unknown keys \['level'\]"):
        OverrideTable.from_mapping({'name': 'x', 'level': [0, 1]}, 'config/machines/lathe7.yaml')


def test_unknown_table_names_the_known_ones():
    with pytest.raises(ConfigError, match=r"override_table = 'fanuc_16bit'.*fanuc_0t_4bit"):
        get_table('fanuc_16bit')
