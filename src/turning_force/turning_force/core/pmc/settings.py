"""What reaches the PMC: the override gate that keeps the machine safe first.

The controller asks; the gate decides what is written, in this order:

1. Overload hold: once the estimated force passes ``overload_force_n`` (or is not finite, or
   comes from a saturated current sensor: a force the sensor cannot read is taken as too
   large), the feed is held (0 %) until the bridge is re-armed with the force back under the
   limit.
2. Disarmed: the programmed feed (100 %), as if the option were off, at most ``hand_back_pct``
   (the level every hand-back is bounded by: docs/safety.md). The bridge starts disarmed.
3. Watchdog: no feed command within ``watchdog_period_s``: the configured safe override.
   Just after arming the controller has that long to send its first command; meanwhile the
   programmed feed stays.
4. Invalid command: a request that is not finite or outside the table's range (a controller
   clips to the range; anything outside it is a fault, not a value to clamp): the safe
   override.
5. The shop-floor behaviours (:mod:`turning_force.core.pmc.shopfloor`), after all of the above:
   a tool-breakage hold and an overload reaction's hold (latched until re-armed), the
   stand-downs to the programmed feed (threading, the program not enabling the option), a
   learning cut at the programmed feed; then the request, shaped: feed floor while cutting,
   air-cut override out of the cut, the operator's dial, the rise limit.
6. Normal: the request, quantised to the table's nearest level.

The operator's dial, where one is read, also caps the programmed feed of 2-5 (it only lowers).
Every decision carries its reason (the ``REASON_*`` of ``FeedOverride``) and a sentence saying why.

Per control block the gate takes the machine's inputs (:meth:`OverrideGate.on_inputs`), the
force estimate (:meth:`OverrideGate.on_estimate`) and the command
(:meth:`OverrideGate.on_command`, :mod:`turning_force.core.pmc.gate`, where the rules are written
once, compiled); :meth:`OverrideGate.answer` decides for the block and moves
the per-block state on (rise limit, cut log). :meth:`OverrideGate.decide` decides without
moving it: the bridge's timer asks it what time alone changes (a stale command).
"""

from __future__ import annotations

import enum
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from turning_force.core import shared
from turning_force.core.pmc.overrides import get_table, override_table
from turning_force.core.pmc.shopfloor import NO_INPUTS, InputValues, ShopFloorSettings
from turning_force.core.settings import setting

__all__ = ['BridgeSettings', 'Decision', 'Reason', 'handed_back']


class Reason(enum.IntEnum):
    """Matches the ``REASON_*`` constants of ``turning_force_msgs/FeedOverride``."""

    NORMAL = 0
    DISARMED = 1
    WATCHDOG = 2
    OVERLOAD_HOLD = 3
    OPERATOR = 4
    INVALID_COMMAND = 5
    IO_FAULT = 6
    AIR_CUT = 7
    TOOL_BREAKAGE = 8
    RISE_LIMIT = 9
    FEED_FLOOR = 10
    TEACH_IN = 11
    FEED_NOT_FOLLOWING = 12


@dataclass(frozen=True)
class BridgeSettings(ShopFloorSettings):
    """The PMC bridge (``pmc_bridge`` parameters), the shop-floor behaviours' included."""

    SECTION = 'pmc_bridge'

    override_table: str = override_table()
    control_period_s: float = shared.control_period_s()
    max_feed_force_n: float = shared.max_feed_force_n()
    spindle_speed_rpm: float = shared.spindle_speed_rpm()
    spindle_speed_stale_s: float = shared.spindle_speed_stale_s()
    programmed_feed_mm_rev: float = shared.programmed_feed_mm_rev()
    tools_file: str = shared.tools_file()
    feed_follow_time_s: float = setting(
        0.3, 'The axis feed the DAQ measures outside what the applied override allows this long '
        'while cutting (override cancel M49, feed hold, dry run, a ladder that does not copy the '
        'override): regulation stops and the feed is handed back until re-armed; 0: off', 's',
        low=0.0, high=60.0, dynamic=True)
    feed_follow_tolerance_pct: float = setting(
        15.0, 'How far the axis feed may run from what the applied override allows, in % of the '
        'programmed feed (servo overshoot, feed-rate noise)', '%', low=1.0, high=200.0,
        dynamic=True)
    feed_follow_overshoot: float = setting(
        0.5, "How far beyond the override's recent swing the axis may run, as a share of it (a "
        'second-order servo with damping 0.3 overshoots a step by 37 %)', '-', low=0.0,
        high=5.0, dynamic=True)
    feed_follow_lag_s: float = setting(
        0.5, 'How slowly the axis may follow a change of the override (PMC dead time and servo '
        'lag together, with margin)', 's', low=0.01, high=10.0, dynamic=True)
    armed: bool = setting(False, "Write the controller's override (true) or the programmed "
                          'feed (false); arming also clears an overload hold', dynamic=True)
    watchdog_period_s: float = setting(0.05, 'A feed command older than this is stale', 's',
                                       low=0.0, low_open=True, high=10.0, dynamic=True)
    safe_override_pct: float = setting(0.0, 'Override written when the command is stale or '
                                       'invalid: a feed hold (0) or a reduced feed, below 100',
                                       '%', low=0.0, high=100.0, high_open=True, dynamic=True)
    overload_force_n: float = setting(2000.0, 'Estimated force that holds the feed until '
                                      're-armed; at most max_feed_force_n', 'N', low=0.0,
                                      low_open=True, high=1e5, dynamic=True)
    hand_back_pct: float = setting(100.0, 'The highest override the bridge hands back when it '
                                   'is disarmed, stopped, faulted or signalled, whatever the '
                                   "operator's dial reads (docs/safety.md); a level of the table",
                                   '%', low=0.0, high=100.0)
    backend: str = setting('simulated', 'Where the PMC bits go: simulated, or the Modbus/TCP '
                           'module machine_file describes', choices=('simulated', 'modbus_tcp'))
    machine_file: str = setting('', 'Machine file (config/machines/<machine>.yaml): override '
                                'table, PMC wiring, inputs and outputs; empty: the simulated '
                                'PMC with override_table')

    def check(self) -> None:
        super().check()
        table = get_table(self.override_table)
        for name in ('air_cut_override_pct', 'min_cut_override_pct'):
            if getattr(self, name) > table.max_pct:
                self.fail(name, f'above the {table.name} range [{table.min_pct:g}, '
                                f'{table.max_pct:g}] %')
        if not table.min_pct <= self.safe_override_pct <= table.max_pct:
            self.fail('safe_override_pct', f'outside the {table.name} range '
                                           f'[{table.min_pct:g}, {table.max_pct:g}] %')
        if table.quantise(self.safe_override_pct) >= 100.0:
            self.fail('safe_override_pct', f'the {table.name} PMC would apply '
                      f'{table.quantise(self.safe_override_pct):g} %: the safe override must '
                      'hold or reduce the feed')
        if self.hand_back_pct not in table.levels_pct and not table.continuous:
            below = max(level for level in table.levels_pct if level <= self.hand_back_pct)
            self.fail('hand_back_pct', f'not a level of {table.name}: the PMC would apply '
                      f'{table.quantise(self.hand_back_pct):g} %; give {below:g}')
        if self.overload_force_n > self.max_feed_force_n:
            self.fail('overload_force_n', f'above max_feed_force_n ({self.max_feed_force_n:g} '
                                          'N), the force the feed axis is rated for')
        if self.watchdog_period_s < self.control_period_s:
            self.fail('watchdog_period_s', f'shorter than control_period_s '
                                           f'({self.control_period_s}): every command would be '
                                           'stale')


def handed_back(t_s: npt.ArrayLike, reasons: npt.ArrayLike) -> str:
    """A line saying when the feed-follow check stopped regulation in a run (the block times
    ``t_s`` and the reason of each block's decision), '' where it did not."""
    t, why = np.asarray(t_s, dtype=np.float64), np.asarray(reasons, dtype=np.float64)
    stopped = np.flatnonzero(why == Reason.FEED_NOT_FOLLOWING)
    if not stopped.size:
        return ''
    return (f'regulation stopped at {t[stopped[0]]:.2f} s: the axis feed did not follow the '
            'override (override cancel M49, feed hold, dry run, or a ladder that does not copy '
            'the override?); the feed was handed back until re-armed')


@dataclass(frozen=True)
class Decision:
    """One write to the PMC (the core side of ``FeedOverride``)."""

    applied_pct: float
    requested_pct: float
    code: int
    bits: tuple[bool, ...]
    armed: bool
    reason: Reason
    detail: str
    inputs: InputValues = NO_INPUTS       # the machine's inputs the decision saw
    engaged: bool = False                 # the tool in the cut
    alarm: bool = False                   # the alarm output
    stop_request: bool = False            # the stop/retract request output
