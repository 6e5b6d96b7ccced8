"""What reaches the PMC: the override gate that keeps the machine safe first.

The controller asks; the gate decides what is written, in this order:

1. Overload hold: once the estimated force passes ``overload_force_n`` (or is not finite, or
   comes from a saturated current sensor: a force the sensor cannot read is taken as too
   large), the feed is held (0 %) until the bridge is re-armed with the force back under the
   limit.
2. Disarmed: the programmed feed (100 %), as if the option were off. The bridge starts disarmed.
3. Watchdog: no feed command within ``watchdog_period_s``: the configured safe override.
   Just after arming the controller has that long to send its first command; meanwhile the
   programmed feed stays.
4. Invalid command: a request that is not finite or outside the table's range (a controller
   clips to the range; anything outside it is a fault, not a value to clamp): the safe
   override.
5. The shop-floor behaviours (:mod:`turning_force.core.shopfloor`), after all of the above:
   a tool-breakage hold and an overload reaction's hold (latched until re-armed), the
   stand-downs to the programmed feed (threading, the program not enabling the option), a
   learning cut at the programmed feed; then the request, shaped: feed floor while cutting,
   air-cut override out of the cut, the operator's dial, the rise limit.
6. Normal: the request, quantised to the table's nearest level.

The operator's dial, where one is read, also caps the programmed feed of 2-5 (it only lowers).
Every decision carries its reason (the ``REASON_*`` of ``FeedOverride``) and a sentence saying why.

Per control block the gate takes the machine's inputs (:meth:`OverrideGate.on_inputs`), the
force estimate (:meth:`OverrideGate.on_estimate`) and the command
(:meth:`OverrideGate.on_command`); :meth:`OverrideGate.answer` decides for the block and moves
the per-block state on (rise limit, cut log). :meth:`OverrideGate.decide` decides without
moving it: the bridge's timer asks it what time alone changes (a stale command).
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from turning_force.core import kernel, shared
from turning_force.core.estimation import EstimateStatus
from turning_force.core.overrides import OverrideTable, get_table
from turning_force.core.settings import setting
from turning_force.core.shopfloor import (
    NO_INPUTS,
    SHAPED,
    CutRecord,
    InputValues,
    Learned,
    ShopFloor,
    ShopFloorSettings,
    Verdict,
)

__all__ = ['BridgeSettings', 'Decision', 'OverrideGate', 'Reason']

FloatArray = npt.NDArray[np.float64]


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


@dataclass(frozen=True)
class BridgeSettings(ShopFloorSettings):
    """The PMC bridge (``pmc_bridge`` parameters), the shop-floor behaviours' included."""

    SECTION = 'pmc_bridge'

    override_table: str = shared.override_table()
    control_period_s: float = shared.control_period_s()
    max_feed_force_n: float = shared.max_feed_force_n()
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
        if self.overload_force_n > self.max_feed_force_n:
            self.fail('overload_force_n', f'above max_feed_force_n ({self.max_feed_force_n:g} '
                                          'N), the force the feed axis is rated for')
        if self.watchdog_period_s < self.control_period_s:
            self.fail('watchdog_period_s', f'shorter than control_period_s '
                                           f'({self.control_period_s}): every command would be '
                                           'stale')


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


class OverrideGate:
    """Decides the override written to the PMC from commands, force estimates and time."""

    def __init__(self, settings: BridgeSettings, t_s: float | None = None) -> None:
        self.settings = settings
        self.table: OverrideTable = get_table(settings.override_table)
        self.armed = False
        self.started = False
        self._requested = math.nan
        self._command_t_s = -math.inf
        self._armed_t_s = -math.inf
        self._overload = ''
        self._last_force_n = 0.0
        self._last_status = EstimateStatus.OK
        self._reachable: bool | None = None
        self.shop = ShopFloor(settings, settings.overload_force_n, settings.control_period_s)
        if t_s is not None:
            self.start(t_s)

    def start(self, t_s: float) -> None:
        """Begin at ``t_s`` (armed if the settings say so). A node starts its gate at its first
        callback, when its clock runs: in a lock-step run sim time only starts then."""
        self.started = True
        if self.settings.armed:
            self.arm(t_s)

    def reconfigure(self, settings: BridgeSettings, t_s: float) -> None:
        """New dynamic settings; arming through the settings clears an overload hold."""
        was_armed = self.settings.armed
        self.settings = settings   # first: re-arming judges the force by the new limit
        self.shop.overload_force_n = settings.overload_force_n
        if settings.armed and not was_armed:
            self.arm(t_s)
        elif not settings.armed:
            self.armed = False

    def arm(self, t_s: float) -> str:
        """Arm at ``t_s``; arming clears an overload hold, unless the last force estimate is
        still over the limit. Returns why the hold stays, or ''."""
        self.armed = True
        self._armed_t_s = t_s
        self.shop.rearm()
        still = self._over_limit(self._last_force_n, self._last_status)
        if still and self._overload:
            self._overload = f'{still}; re-armed while still over the limit'
        elif still:
            self._overload = still
        else:
            self._overload = ''
        return self._overload

    def disarm(self) -> None:
        self.armed = False

    @property
    def holding(self) -> bool:
        """Whether an overload hold is in force."""
        return bool(self._overload)

    def on_inputs(self, inputs: InputValues) -> None:
        """The machine's inputs as last read (program enable, threading, operator dial)."""
        self.shop.inputs = inputs

    def on_command(self, requested_pct: float, t_s: float, reachable: bool | None = None) -> None:
        """The controller's request; ``reachable``, its flag, goes to the cut log."""
        self._requested = requested_pct
        self._command_t_s = t_s
        self._reachable = reachable

    def _over_limit(self, force_n: float, status: EstimateStatus) -> str:
        limit = self.settings.overload_force_n
        if status == EstimateStatus.SATURATED:
            return f'current sensor saturated (force {force_n:.0f} N or more)'
        if not math.isfinite(force_n):
            return f'force estimate {force_n!r} N is not finite'
        if force_n > limit:
            return f'force {force_n:.0f} N above overload_force_n {limit:g} N'
        return ''

    def on_estimate(self, force_n: float, status: EstimateStatus = EstimateStatus.OK) -> bool:
        """Take a force estimate; True when it has just started an overload hold.

        A saturated or non-finite force counts as over the limit. An invalid or stale estimate
        (it repeats the last good force) says nothing new and is not judged.
        """
        if status in (EstimateStatus.INVALID_INPUT, EstimateStatus.STALE):
            return False
        self._last_force_n, self._last_status = force_n, status
        over = self._over_limit(force_n, status)
        started = bool(over and not self._overload)
        if started:
            self._overload = over
        if math.isfinite(force_n):
            self.shop.observe(force_n, self.armed, started)
        return started

    def decide(self, t_s: float) -> Decision:
        """The override for now; the per-block state stays as it is."""
        return self._decision(*self._judge(t_s)[:3])

    def answer(self, t_s: float) -> Decision:
        """The override answering the block that ends at ``t_s``, the PMC's from the next block
        on; moves the per-block state on (rise limit, cut log, teach-in)."""
        pct, reason, detail, verdict = self._judge(t_s)
        decision = self._decision(pct, reason, detail)
        self.shop.commit(t_s, decision.applied_pct, verdict, self._reachable)
        self._reachable = None
        return decision

    def take_cuts(self) -> list[CutRecord]:
        """Cuts that ended since the last call (the cut log)."""
        return self.shop.take_cuts()

    def take_learned(self) -> Learned | None:
        """What a learning cut has just taught, once."""
        return self.shop.take_learned()

    def close(self) -> CutRecord | None:
        """The session ends: the cut still open, if any, marked incomplete."""
        return self.shop.close()

    def _judge(self, t_s: float) -> tuple[float, Reason, str, Verdict | None]:
        """The override (before quantisation), its reason and why, and the shop-floor verdict
        when the request went through (the rise limit's base)."""
        s = self.settings
        requested = self._requested
        if self._overload:
            return 0.0, Reason.OVERLOAD_HOLD, self._overload + '; re-arm to resume', None
        if not self.armed:
            return self._dialled(100.0, Reason.DISARMED, 'not armed: programmed feed')
        if self._command_t_s < self._armed_t_s:  # nothing since arming
            waited = t_s - self._armed_t_s
            if waited <= s.watchdog_period_s:
                return self._dialled(100.0, Reason.WATCHDOG,
                                     'armed, waiting for the first feed command')
            return self._dialled(s.safe_override_pct, Reason.WATCHDOG,
                                 f'no feed command in {waited:.3f} s since arming')
        age = t_s - self._command_t_s
        if age > s.watchdog_period_s:
            return self._dialled(s.safe_override_pct, Reason.WATCHDOG,
                                 f'feed command {age:.3f} s old (watchdog '
                                 f'{s.watchdog_period_s:g} s)')
        if not math.isfinite(requested):
            return self._dialled(s.safe_override_pct, Reason.INVALID_COMMAND,
                                 f'feed command {requested!r} % is not finite')
        table = self.table
        if not table.min_pct <= requested <= table.max_pct:
            return self._dialled(s.safe_override_pct, Reason.INVALID_COMMAND,
                                 f'feed command {requested:.6g} % outside the {table.name} '
                                 f'range [{table.min_pct:g}, {table.max_pct:g}] %')
        held = self.shop.verdict()
        if held is not None:
            return self._dialled(held.pct, Reason(held.reason), held.detail)
        shaped = self.shop.shape(requested)
        assert shaped.reason in SHAPED
        return shaped.pct, Reason(shaped.reason), shaped.detail, shaped

    def _dialled(self, pct: float, reason: Reason,
                 detail: str) -> tuple[float, Reason, str, Verdict | None]:
        """A decision other than the request: the operator's dial, where read, only lowers it."""
        dial = self.shop.dial_pct
        if dial is not None and dial < pct:
            return dial, reason, f"{detail}; the operator's dial at {dial:g} %", None
        return pct, reason, detail, None

    def arrays(self) -> tuple[FloatArray, FloatArray, FloatArray]:
        """(parameters, state, levels) of this gate now, as the kernel's gate (``gate_decide``
        and its neighbours in :mod:`turning_force.core.kernel.jit`) takes them: copies, from
        which a compiled loop goes on with the same decisions. The kernel's gate runs the
        safety gate, the cut detector and the overload reaction's outputs; where a shop-floor
        behaviour it does not run is on, :func:`turning_force.core.kernel.why_python` says so
        and the loop stays on this one."""
        jit = kernel.load()
        s, shop = self.settings, self.shop
        p = np.zeros(jit.G_SIZE)
        p[jit.G_WATCHDOG], p[jit.G_SAFE] = s.watchdog_period_s, s.safe_override_pct
        p[jit.G_OVERLOAD], p[jit.G_ARMED] = s.overload_force_n, s.armed
        p[jit.G_CONT] = self.table.continuous
        p[jit.G_ENGAGE], p[jit.G_EXIT] = s.engage_force_n, s.exit_force_n
        p[jit.G_DEBOUNCE], p[jit.G_REACT_LIMIT] = shop._debounce, shop.reaction_limit_n
        p[jit.G_REACT_NEEDED] = math.ceil(s.reaction_delay_s / shop.period_s - 1e-9)
        reactions = {'alarm': jit.REACTION_ALARM, 'stop': jit.REACTION_STOP}
        p[jit.G_REACTION] = reactions.get(s.overload_reaction, jit.REACTION_NONE)
        state = np.zeros(jit.GS_SIZE)
        state[jit.GS_ARMED], state[jit.GS_STARTED] = self.armed, self.started
        state[jit.GS_REQ], state[jit.GS_CMD_T] = self._requested, self._command_t_s
        state[jit.GS_ARMED_T], state[jit.GS_HOLD] = self._armed_t_s, bool(self._overload)
        state[jit.GS_LAST_F] = self._last_force_n
        state[jit.GS_LAST_STATUS] = int(self._last_status)
        state[jit.GS_ENGAGED], state[jit.GS_RUN] = shop.engaged, shop._run
        state[jit.GS_ABOVE], state[jit.GS_REACTED] = shop._above, bool(shop._reaction)
        return p, state, np.array(self.table.levels_pct, dtype=np.float64)

    def _decision(self, pct: float, reason: Reason, detail: str) -> Decision:
        applied = self.table.quantise(pct)
        code, bits = self.table.encode(applied)
        shop = self.shop
        return Decision(applied, self._requested, code, bits, self.armed, reason, detail,
                        shop.inputs, shop.engaged, shop.alarm or bool(self._overload),
                        shop.stop_request)
