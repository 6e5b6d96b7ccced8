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

The law runs compiled (``_staircase`` in :mod:`.laws`); this module
reads its settings into it.
"""

from __future__ import annotations

from types import ModuleType
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt

from turning_force.core.control.law import Law

if TYPE_CHECKING:
    from turning_force.core.control.settings import ControllerSettings

__all__ = ['LAW']

FloatArray = npt.NDArray[np.float64]


def fill(jit: ModuleType, c: ControllerSettings, p: FloatArray) -> tuple[FloatArray, int]:
    """The script: how many commands a level is held, the levels (from ``C_SC_LEVELS`` on)."""
    levels = c.staircase_levels_pct
    p = np.concatenate([p, np.zeros(jit.C_SC_LEVELS + len(levels) - p.size)])
    p[jit.C_SC_PER] = max(round(c.staircase_step_s / c.control_period_s), 1)
    p[jit.C_SC_N] = len(levels)
    p[jit.C_SC_LEVELS:] = levels
    return p, 0


LAW = Law('staircase', lambda jit: int(jit.STAIRCASE), fill,
          "no regulation: a scripted override staircase, the commissioning experiment's "
          'excitation')
