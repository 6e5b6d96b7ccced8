"""What every control law shares: the controller that runs it, its output, the guard on its
state, the error-feedback quantiser and the reachability flag.

A law is a module of this package with a :class:`.law.Law` entry in :mod:`.registry`: its name, its
number in the compiled dispatch, and the function that reads its settings into the compiled
parameters. Its arithmetic is written once, as a compiled function of
:mod:`turning_force.core.control.laws` (``controller_update`` and the law's own function beside
it); :class:`Controller` runs it one period at a time, the compiled loops many periods at once.
"""

from __future__ import annotations

import itertools
from types import ModuleType
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt

from turning_force.core.control import laws
from turning_force.core.control.law import ControlOutput
from turning_force.core.control.registry import CONTROLLERS
from turning_force.core.overrides import OverrideTable, get_table

if TYPE_CHECKING:
    from turning_force.core.control.settings import ControllerSettings

__all__ = ['Controller']

FloatArray = npt.NDArray[np.float64]


class Controller:
    """The force controller: once per control period :meth:`update` takes the estimated force
    and force rate and returns the override the law ``settings.controller`` asks for.

    The request is continuous, in percent of the programmed feed, inside the override table's
    range; the PMC's quantisation happens after it, as on a real CNC, except that with
    ``quantiser: error_feedback`` the controller sends the level itself (first-order noise
    shaping, as a sigma-delta converter does it: the level nearest to the request plus the
    rounding error carried from the last period, so that the levels sent average to the
    request and the rounding error moves to high frequencies, which the servo filters out).

    The state of a law is guarded once for all laws: a non-finite input, or an update that
    leaves the law's state or output non-finite (a force of 1e300 N squared in a recursive
    least-squares update), resets the law (:attr:`resets` counts it), and the request holds the
    last finite one. A law never asks for a non-finite override, and never stays broken.

    Reachability: the reference is unreachable once the law's request has sat at one end of
    the table (within half a level: the PMC applies the end level) with the force on the far
    side of the reference for ``unreachable_after_s``. A dip of the request from the end on
    sensor noise does not restart the clock; the force reaching the reference, or the request
    leaving the end by a whole level, does.

    ``settings`` may be replaced while cutting (:meth:`retune`); the next :meth:`update` uses the
    new values. Fixed settings (``dynamic=False``) are not to change after construction.
    """

    def __init__(self, settings: ControllerSettings) -> None:
        jit = laws
        self.settings = settings
        self.name = settings.controller
        self._table = get_table(settings.override_table)
        self.min_pct, self.max_pct = self._table.min_pct, self._table.max_pct
        self._levels = np.array(self._table.levels_pct, dtype=np.float64)
        self._params, queue = _params(jit, settings, self._table)
        self._state = np.zeros(jit.CS_QUEUE + queue)
        self._state[jit.CS_HELD] = min(max(settings.initial_override_pct, self.min_pct),
                                       self.max_pct)
        jit.controller_start(self._params, self._state)
        self._out = np.zeros(4)

    @property
    def arrays(self) -> tuple[FloatArray, FloatArray, FloatArray]:
        """(parameters, state, levels) as ``controller_update`` reads them; the state live (a
        loop that runs it runs this controller)."""
        return self._params, self._state, self._levels

    @property
    def resets(self) -> int:
        """How often the law was reset after a non-finite input or state."""
        return int(self._state[laws.CS_RESETS])

    def retune(self, settings: ControllerSettings) -> None:
        """Take new dynamic settings (reference, gains) from the next update on."""
        self.settings = settings
        self._params = _params(laws, settings, self._table)[0]

    def update(self, force_n: float, force_rate_n_s: float) -> ControlOutput:
        """One control period: measured force and force rate in, override request out."""
        jit, out = laws, self._out
        jit.control_step(self._params, self._state, self._levels, float(force_n),
                         float(force_rate_n_s), out)
        return ControlOutput(float(out[jit.OUT_PCT]), float(out[jit.OUT_ERR]),
                             float(out[jit.OUT_S]), bool(out[jit.OUT_REACH] != 0.0))


def _params(jit: ModuleType, c: ControllerSettings,
            table: OverrideTable) -> tuple[FloatArray, int]:
    """The compiled controller's parameters (``C_*``) and its queue's length."""
    law = CONTROLLERS[c.controller]
    p = np.zeros(jit.C_SIZE)
    p[jit.C_KIND] = law.kind(jit)
    p[jit.C_REF], p[jit.C_PERIOD] = c.reference_force_n, c.control_period_s
    levels = table.levels_pct
    p[jit.C_MIN], p[jit.C_MAX] = table.min_pct, table.max_pct
    p[jit.C_GAP] = max(b - a for a, b in itertools.pairwise(levels))
    p[jit.C_EF] = c.quantiser == 'error_feedback'
    p[jit.C_UNREACH], p[jit.C_FEED_RATE] = c.unreachable_after_s, c.programmed_feed_rate_mm_min
    p[jit.C_CONT] = table.continuous
    return law.fill(jit, c, p)
