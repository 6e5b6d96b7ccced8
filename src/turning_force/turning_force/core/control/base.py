"""The controller that runs a law: its parameters and state, one period at a time.

A law is one module (:mod:`.law` says what it holds); what every law shares runs compiled
around its ``step`` in :func:`.update.controller_update`, which :class:`Controller` calls one
period at a time and the compiled loops many periods at once.
"""

from __future__ import annotations

import itertools
import math
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt

from turning_force.core.compiled import activate
from turning_force.core.control import drift, update
from turning_force.core.control.law import (
    C_CONT,
    C_DRIFT,
    C_EF,
    C_EXPONENT,
    C_FEED_RATE,
    C_FEED_REV,
    C_GAP,
    C_KIND,
    C_LAW,
    C_MAX,
    C_MIN,
    C_MODEL_HALF,
    C_OSC_COUNT,
    C_OSC_REACTION,
    C_OSC_SWING,
    C_PERIOD,
    C_REF,
    C_RPM,
    C_RPM_SET,
    C_TAU_C,
    C_UNREACH,
    CS_DRIFT,
    CS_HELD,
    CS_LAW,
    CS_O_ALARMS,
    CS_O_FEED,
    CS_RESETS,
    OSCILLATION_REACTIONS,
    OUT_DRIFT,
    OUT_DRIFT_SIZE,
    OUT_ERR,
    OUT_OSC,
    OUT_PCT,
    OUT_REACH,
    OUT_S,
    OUT_SIZE,
    ControlOutput,
    model_half_period_s,
    set_spindle_speed,
)
from turning_force.core.control.registry import CONTROLLERS, names
from turning_force.core.errors import ConfigError
from turning_force.core.pmc.overrides import OverrideTable, get_table
from turning_force.core.tools import load_tools_file, tool_settings

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
        activate()   # compiled, not interpreted, from the first period
        self.settings = settings
        self.name = settings.controller
        self._table = get_table(settings.override_table)
        self.min_pct, self.max_pct = self._table.min_pct, self._table.max_pct
        self._levels = np.array(self._table.levels_pct, dtype=np.float64)
        self._params, size = _params(settings, self._table)
        self._tools = load_tools_file(settings.tools_file) if settings.tools_file else {}
        self._per_tool = tool_settings(settings, self._tools, settings.tools_file)
        self.tool_table, tool_size = self._tool_table(self._per_tool, self._params.size)
        # Room for the largest state any tool's section needs (its dead time's queue).
        self._state = np.zeros(CS_LAW + max(size, tool_size))
        self._state[CS_DRIFT + drift.DS_APPLIED] = math.nan   # no override applied told yet
        self._state[CS_O_FEED] = math.nan   # no axis feed measured yet
        self._state[CS_HELD] = min(max(settings.initial_override_pct, self.min_pct),
                                   self.max_pct)
        update.controller_start(self._params, self._state)
        self._out = np.zeros(OUT_SIZE)
        self._rpm = math.nan
        self.tool_number = math.nan   # the tool whose settings are in use (NaN: the settings')

    def _tool_table(self, per_tool: dict[int, ControllerSettings], size: int
                    ) -> tuple[FloatArray, int]:
        """Per tool of the tools file (``per_tool``: its settings; the machine's parameters
        are ``size`` long): its number, then the parameters of its settings
        (:func:`.update.controller_tool`), no rows without a tools file; and the largest state
        a tool's law needs (0: none)."""
        built = [(number, *_params(s, self._table)) for number, s in per_tool.items()]
        if any(params.size != size for _, params, _ in built):
            raise ConfigError(f'{self.settings.tools_file}: a tool section changes the size of '
                              f"the {self.name} law's parameters (its horizon or order): not "
                              'a per-tool setting')
        rows = [np.concatenate(([number], params)) for number, params, _ in built]
        table = np.array(rows, dtype=np.float64).reshape(len(rows), size + 1)
        return table, max((need for _, _, need in built), default=0)

    def select_tool(self, number: float) -> bool:
        """The machine's tool input says tool ``number``: its settings from now on, the law
        afresh as at an entry (:func:`.update.controller_tool`); False where the tools file has
        no section for it (the gate hands the feed back then) or none is given."""
        number = float(number)
        if number == self.tool_number:
            return True
        self.tool_number = number
        return update.control_tool(self.tool_table, self._params, self._state, number) >= 0

    @property
    def in_use(self) -> ControllerSettings:
        """The settings the law runs on now: the tool's section laid over the settings where
        the tool input selected one (:meth:`select_tool`), else the settings."""
        if not self.tool_number.is_integer():   # NaN: no tool input yet
            return self.settings
        return self._per_tool.get(int(self.tool_number), self.settings)

    @property
    def arrays(self) -> tuple[FloatArray, FloatArray, FloatArray]:
        """(parameters, state, levels) as ``controller_update`` reads them; the state live (a
        loop that runs it runs this controller)."""
        return self._params, self._state, self._levels

    @property
    def oscillation_alarms(self) -> int:
        """How often the oscillation alarm was raised (:func:`.update.controller_update`)."""
        return int(self._state[CS_O_ALARMS])

    @property
    def drift(self) -> str:
        """The drift alarm in words (:func:`.drift.drift_text`; '' while none holds)."""
        monitor = self._state[CS_DRIFT:CS_LAW]
        return drift.drift_text(self.in_use, *drift.alarm(monitor),
                                adopted=drift.adopted(monitor))

    @property
    def model(self) -> str:
        """The model the law predicts with, in words, where it took a lag drift the drift
        monitor named into it (:func:`.drift.adopted_text`; '': the commissioned model)."""
        return drift.adopted_text(self.in_use, *drift.adopted(self._state[CS_DRIFT:CS_LAW]))

    def rezeroed(self, scale: float) -> None:
        """The estimator re-zeroed the friction in air to ``scale`` x calibrated (the drift
        monitor's measurement of the friction, :func:`.drift.drift_rezeroed`)."""
        update.control_rezeroed(self._params, self._state, float(scale))

    def feed(self, feed_mm_min: float) -> None:
        """The axis feed the DAQ measured over the block the next update answers, its mean
        [mm/min] (ForceEstimate's; NaN: none): the drift monitor's feed test
        (:func:`.drift.drift_feed`) and the oscillation detector's test of the tool's exits
        (:data:`.update.EXIT_FEED_SHARE`)."""
        update.control_feed(self._params, self._state, float(feed_mm_min))

    def friction_correction(self) -> float:
        """The friction [N] the drift monitor read in the cut since the last call, for the
        estimator to take off its estimate (0: none; :func:`.drift.drift_correction`, whose
        request this clears)."""
        monitor = self._state[CS_DRIFT:CS_LAW]
        offset = float(monitor[drift.DS_CORRECT])
        monitor[drift.DS_CORRECT] = 0.0
        return offset

    @property
    def resets(self) -> int:
        """How often the law was reset after a non-finite input or state."""
        return int(self._state[CS_RESETS])

    def retune(self, settings: ControllerSettings) -> None:
        """Take new dynamic settings (reference, gains) from the next update on."""
        params, size = _params(settings, self._table)
        per_tool = tool_settings(settings, self._tools, settings.tools_file)
        table, tool_size = self._tool_table(per_tool, params.size)
        if CS_LAW + max(size, tool_size) > self._state.size:
            raise ConfigError(f"{self.name}: the new settings need a larger state for the law's "
                              'queue (model_dead_time_s) than the one it runs on: not a live '
                              'setting; restart the node with them')
        self.settings, self._per_tool = settings, per_tool
        self._params = params
        set_spindle_speed(self._params, self._rpm)
        self.tool_table = table
        row = np.flatnonzero(self.tool_table[:, 0] == self.tool_number)
        if row.size:   # the tool in use keeps its section over the new settings
            self._params[:] = self.tool_table[row[0], 1:]
            set_spindle_speed(self._params, self._rpm)

    def spindle_speed(self, rpm: float) -> None:
        """The live spindle speed [rpm] from the next update on (NaN: the ``spindle_speed_rpm``
        parameter again): :func:`~turning_force.core.control.law.spindle_speed`."""
        self._rpm = float(rpm)
        set_spindle_speed(self._params, self._rpm)

    @property
    def reference_force_n(self) -> float:
        """The reference the laws regulate to now [N]: the settings', the tool's where a tools
        file gives one (:meth:`select_tool`)."""
        return float(self._params[C_REF])

    @property
    def spindle_speed_rpm(self) -> float:
        """The spindle speed the laws use now [rpm]."""
        return float(self._params[C_RPM])

    def applied(self, applied_pct: float, engaged: bool, reason: int) -> None:
        """The override the PMC applied after the last request, whether the tool is in the
        cut, and the gate's reason (FeedOverride's): the anti-windup of
        :func:`.update.controller_applied`."""
        update.control_applied(self._params, self._state, float(applied_pct), bool(engaged),
                               int(reason))

    def update(self, force_n: float, force_rate_n_s: float) -> ControlOutput:
        """One control period: measured force and force rate in, override request out."""
        out = self._out
        update.control_step(self._params, self._state, self._levels, float(force_n),
                            float(force_rate_n_s), out)
        return ControlOutput(float(out[OUT_PCT]), float(out[OUT_ERR]), float(out[OUT_S]),
                             bool(out[OUT_REACH] != 0.0), bool(out[OUT_OSC] != 0.0),
                             int(out[OUT_DRIFT]), float(out[OUT_DRIFT_SIZE]))


def _params(c: ControllerSettings, table: OverrideTable) -> tuple[FloatArray, int]:
    """The compiled controller's parameters (``C_*``, then the law's own) and the size of the
    law's own state."""
    law = CONTROLLERS[c.controller]
    own, size = law.fill(c)
    p = np.zeros(C_LAW + len(own))
    p[C_KIND] = names().index(law.name)
    p[C_REF], p[C_PERIOD] = c.reference_force_n, c.control_period_s
    levels = table.levels_pct
    p[C_MIN], p[C_MAX] = table.min_pct, table.max_pct
    p[C_GAP] = max(b - a for a, b in itertools.pairwise(levels))
    p[C_EF] = c.quantiser == 'error_feedback'
    p[C_UNREACH], p[C_FEED_RATE] = c.unreachable_after_s, c.programmed_feed_rate_mm_min
    p[C_OSC_SWING] = c.oscillation_swing_n if law.closed_loop else 0.0   # 0: not watched
    p[C_OSC_COUNT] = c.oscillation_swings
    p[C_OSC_REACTION] = OSCILLATION_REACTIONS.index(c.oscillation_reaction)
    p[C_CONT] = table.continuous
    p[C_FEED_REV] = c.programmed_feed_mm_rev
    p[C_RPM_SET] = p[C_RPM] = c.spindle_speed_rpm
    p[C_EXPONENT] = c.model_cutting_exponent
    p[C_MODEL_HALF] = model_half_period_s(c)
    p[C_TAU_C] = c.model_cutting_time_constant_s
    p[C_DRIFT:C_LAW] = drift.drift_fill(c)
    p[C_LAW:] = own
    return p, size
