"""Feedrate-override tables: the levels a CNC's PMC accepts, and how they are written as bits.

A stock CNC takes the controller's feed command only as a feedrate override, in the levels its
PMC interface allows (Park 1998, Sec. 1 and 3):

- FANUC 0-T, four PMC points: 16 levels, 0-150 % in 10 % steps (Park 1998, Sec. 2.1).
- FANUC eight-bit ``*FV0..*FV7`` (Kim): negative logic, bit weights 1, 2, ..., 128 %; all bits 0
  and all bits 1 both mean 0 %, so 0-254 % in 1 % steps.
- ``ideal``: a continuous override (Park 1998, Fig. 7), for simulation only.

A table is data: its levels, the PMC code written for each level, the bit count and the logic.
Machines with other wiring describe theirs in ``config/machines/`` and load it with
:func:`OverrideTable.from_mapping`.
"""

from __future__ import annotations

import bisect
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from turning_force.core.errors import ConfigError
from turning_force.core.settings import setting

__all__ = ['TABLES', 'OverrideTable', 'get_table', 'override_table']


@dataclass(frozen=True)
class OverrideTable:
    """The override levels a machine accepts and their PMC encoding.

    ``codes[i]`` is the integer written for ``levels_pct[i]``; bit ``k`` of the code drives PMC
    signal ``k``. With ``negative_logic`` the signals are active low, so the bits written are the
    complement of the code. ``decode_aliases`` maps further codes a PMC reads (e.g. all bits
    active on an eight-bit FANUC) to the override they mean. A ``continuous`` table has two
    levels, its range, and no PMC code.
    """

    name: str
    levels_pct: tuple[float, ...]
    codes: tuple[int, ...] = ()
    bit_count: int = 0
    negative_logic: bool = False
    continuous: bool = False
    decode_aliases: Mapping[int, float] = field(default_factory=dict)

    def __post_init__(self) -> None:
        where = f'override table {self.name!r}'
        levels = np.asarray(self.levels_pct, dtype=float)
        if levels.size < 2 or not np.all(np.isfinite(levels)):
            raise ConfigError(f'{where}: levels_pct = {self.levels_pct!r}: need finite levels')
        if np.any(np.diff(levels) <= 0):
            raise ConfigError(
                f'{where}: levels_pct = {self.levels_pct!r}: not strictly increasing'
            )
        if levels[0] < 0:
            raise ConfigError(f'{where}: levels_pct = {self.levels_pct!r}: negative override')
        if self.continuous:
            if levels.size != 2 or self.codes:
                raise ConfigError(f'{where}: a continuous table has two levels and no codes')
            return
        if len(self.codes) != levels.size:
            raise ConfigError(
                f'{where}: codes = {self.codes!r}: need one code per level ({levels.size})'
            )
        if not 1 <= self.bit_count <= 16:
            raise ConfigError(f'{where}: bit_count = {self.bit_count!r}: expected 1 to 16')
        all_codes = list(self.codes) + list(self.decode_aliases)
        if len(set(all_codes)) != len(all_codes):
            raise ConfigError(f'{where}: codes = {self.codes!r}: a code is used twice')
        if any(not 0 <= c < 2**self.bit_count for c in all_codes):
            raise ConfigError(
                f'{where}: codes = {self.codes!r}: a code does not fit in {self.bit_count} bits'
            )

    @property
    def min_pct(self) -> float:
        return self.levels_pct[0]

    @property
    def max_pct(self) -> float:
        return self.levels_pct[-1]

    def quantise(self, requested_pct: float) -> float:
        """The level the PMC applies for a requested override: nearest level, saturated.

        A request exactly between two levels takes the lower one: less feed is the safe side.
        A non-finite request is refused (``ValueError``); deciding what to do then is the
        safety layer's job, not the quantiser's.
        """
        if not math.isfinite(requested_pct):
            raise ValueError(f'{self.name}: requested override {requested_pct!r} is not finite')
        levels = self.levels_pct
        pct = min(max(requested_pct, levels[0]), levels[-1])
        if self.continuous:
            return pct
        # Once per control period on the hot path: bisect, not numpy.
        upper = min(max(bisect.bisect_left(levels, pct), 1), len(levels) - 1)
        lo, hi = levels[upper - 1], levels[upper]
        return hi if hi - pct < pct - lo else lo

    def level_at_most(self, pct: float) -> float:
        """The highest level at or below ``pct`` (the lowest level when none is): a bound that
        quantising must not round up past (the hand-back level, the operator's dial)."""
        if self.continuous:
            return min(max(pct, self.min_pct), self.max_pct)
        index = bisect.bisect_right(self.levels_pct, pct)
        return self.levels_pct[max(index - 1, 0)]

    def encode(self, applied_pct: float) -> tuple[int, tuple[bool, ...]]:
        """The PMC code and the signal states (bit 0 first) that set ``applied_pct``."""
        if self.continuous:
            return 0, ()
        try:
            index = self.levels_pct.index(applied_pct)
        except ValueError:
            raise ValueError(
                f'{self.name}: {applied_pct!r} % is not a level; quantise it first'
            ) from None
        code = self.codes[index]
        written = (~code & (2**self.bit_count - 1)) if self.negative_logic else code
        return code, tuple(bool(written >> k & 1) for k in range(self.bit_count))

    def decode(self, bits: tuple[bool, ...]) -> float:
        """The override a PMC reads from signal states (bit 0 first)."""
        if len(bits) != self.bit_count:
            raise ValueError(f'{self.name}: expected {self.bit_count} bits, got {len(bits)}')
        written = sum(1 << k for k, b in enumerate(bits) if b)
        code = (~written & (2**self.bit_count - 1)) if self.negative_logic else written
        if code in self.decode_aliases:
            return self.decode_aliases[code]
        try:
            return self.levels_pct[self.codes.index(code)]
        except ValueError:
            raise ValueError(f'{self.name}: code {code} has no override level') from None

    @classmethod
    def from_mapping(cls, data: Mapping[str, Any], source: str = '') -> OverrideTable:
        """A table from a machine file's ``override_table`` mapping.

        Keys: ``name``, ``levels_pct``, and for a PMC table ``codes``, ``bit_count``,
        ``negative_logic``, optionally ``decode_aliases`` (code -> percent).
        """
        known = {'name', 'levels_pct', 'codes', 'bit_count', 'negative_logic', 'continuous',
                 'decode_aliases'}
        unknown = set(data) - known
        where = source or 'override table'
        if unknown:
            raise ConfigError(f'{where}: unknown keys {sorted(unknown)}; known: {sorted(known)}')
        try:
            return cls(
                name=str(data['name']),
                levels_pct=tuple(float(v) for v in data['levels_pct']),
                codes=tuple(int(c) for c in data.get('codes', ())),
                bit_count=int(data.get('bit_count', 0)),
                negative_logic=bool(data.get('negative_logic', False)),
                continuous=bool(data.get('continuous', False)),
                decode_aliases={
                    int(k): float(v) for k, v in dict(data.get('decode_aliases', {})).items()
                },
            )
        except (KeyError, TypeError, ValueError) as exc:
            if isinstance(exc, ConfigError):
                raise ConfigError(f'{where}: {exc}') from exc
            raise ConfigError(f'{where}: malformed override table: {exc!r}') from exc


TABLES: Mapping[str, OverrideTable] = {t.name: t for t in (
    # FANUC 0-T, four PMC points *FV0..*FV3: 0-150 % in 10 % steps (Park 1998, Sec. 2.1).
    OverrideTable('fanuc_0t_4bit', tuple(10.0 * k for k in range(16)), tuple(range(16)), 4,
                  negative_logic=True),
    # *FV0..*FV7 are active low; the code is the sum of the weights of the active signals.
    # All signals active (code 255) is read as 0 %, like none active.
    OverrideTable('fanuc_8bit', tuple(float(k) for k in range(255)), tuple(range(255)), 8,
                  negative_logic=True, decode_aliases={255: 0.0}),
    OverrideTable('ideal', (0.0, 150.0), continuous=True),
)}


def get_table(name: str) -> OverrideTable:
    """A built-in table by name; a :class:`ConfigError` names the known ones otherwise."""
    try:
        return TABLES[name]
    except KeyError:
        raise ConfigError(
            f'override_table = {name!r}: unknown; known: {", ".join(sorted(TABLES))}'
        ) from None


def override_table() -> Any:
    """The setting that names the machine's table (the plant, the controller and the bridge
    each have it, under ``/**`` in a file)."""
    return setting('fanuc_0t_4bit', "Override table of the machine's PMC; its range bounds the "
                   'command', choices=tuple(TABLES))
