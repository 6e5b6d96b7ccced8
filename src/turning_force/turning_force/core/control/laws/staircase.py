"""A scripted override staircase: the commissioning experiment's excitation.

Plays ``staircase_levels_pct`` in turn, each for ``staircase_step_s``, and repeats them.

It ignores the force: it is the commissioning experiment's input, the override steps up and
down from which ``turning-force identify`` measures the PMC dead time, the feed servo and the
cutting process (El-Sinawi 2011's identification from recordings, on our plant). It runs as
a law like the others, so its requests go through the same gate, quantiser, graph and
recording as a regulating run's.

The script's clock counts the periods the law was asked for a command (one per block whose
estimate it may act on), so a level is held for ``round(staircase_step_s /
control_period_s)`` commands. A non-finite force does not restart the script: its place is
not state a bad sample can spoil.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from turning_force.core.compiled import compiled
from turning_force.core.control.law import (
    C_LAW,
    C_REF,
    CS_LAW,
    OUT_ERR,
    OUT_PCT,
    OUT_S,
    ControllerBase,
    Law,
    clip,
)
from turning_force.core.pmc.overrides import get_table
from turning_force.core.settings import setting

__all__ = ['LAW', 'Settings']


@dataclass(frozen=True)
class Settings(ControllerBase):
    """The staircase's script."""

    staircase_levels_pct: tuple[float, ...] = setting(
        [50.0, 100.0, 20.0, 130.0, 70.0, 150.0, 30.0, 110.0, 80.0, 120.0],
        'Override levels the staircase plays in turn, then repeats (commissioning: steps up and '
        'down of several sizes)', '%', low=0.0, high=255.0)
    staircase_step_s: float = setting(1.0, 'How long the staircase holds each level; a whole '
                                      'number of control periods', 's', low=0.0, low_open=True,
                                      high=600.0)

    def check(self) -> None:
        super().check()
        if self.controller != 'staircase':
            return
        table = get_table(self.override_table)
        levels = self.staircase_levels_pct
        if not levels:
            self.fail('staircase_levels_pct', 'needs at least one level')
        outside = [level for level in levels if not table.min_pct <= level <= table.max_pct]
        if outside:
            self.fail('staircase_levels_pct', f'{outside} outside the {table.name} range '
                                              f'[{table.min_pct:g}, {table.max_pct:g}] %')
        periods = self.staircase_step_s / self.control_period_s
        if periods < 1.0 - 1e-9 or abs(periods - round(periods)) > 1e-6 * periods:
            self.fail('staircase_step_s', f'not a whole number of control periods '
                                          f'({self.control_period_s} s)')


# Parameters: commands a level is held, how many levels, the levels.
P_PERIODS, P_COUNT, P_LEVELS = C_LAW, C_LAW + 1, C_LAW + 2
S_COMMANDS = CS_LAW   # commands asked for so far


def fill(settings: ControllerBase) -> tuple[Sequence[float], int]:
    assert isinstance(settings, Settings)
    levels = settings.staircase_levels_pct
    periods = max(round(settings.staircase_step_s / settings.control_period_s), 1)
    return [periods, len(levels), *levels], 1


@compiled
def reset(cp: np.ndarray, cs: np.ndarray) -> None:
    """Nothing: the place in the script is no state a bad sample spoils."""


@compiled
def step(cp: np.ndarray, cs: np.ndarray, force: float, rate: float, out: np.ndarray) -> None:
    commands = int(cs[S_COMMANDS])
    index = (commands // int(cp[P_PERIODS])) % int(cp[P_COUNT])
    cs[S_COMMANDS] = commands + 1
    out[OUT_PCT] = clip(cp, cp[P_LEVELS + index])
    out[OUT_ERR], out[OUT_S] = force - cp[C_REF], 0.0


LAW = Law('staircase', Settings, fill,
          "no regulation: a scripted override staircase, the commissioning experiment's "
          'excitation', closed_loop=False)
