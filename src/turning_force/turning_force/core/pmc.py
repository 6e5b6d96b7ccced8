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
from types import ModuleType

import numpy as np
import numpy.typing as npt

from turning_force.core import kernel, shared
from turning_force.core.estimation import EstimateStatus
from turning_force.core.overrides import OverrideTable, get_table
from turning_force.core.settings import setting
from turning_force.core.shopfloor import (
    NO_INPUTS,
    CutRecord,
    InputValues,
    Learned,
    ShopFloorSettings,
    TaughtTool,
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
    """Decides the override written to the PMC from commands, force estimates and time.

    Its rules, and the shop floor's behaviours after them, are written once, compiled
    (``gate_*`` in :mod:`turning_force.core.kernel.jit`): this class holds their parameters and
    state, puts their codes into words, and turns a finished cut into a :class:`CutRecord`
    and a learning cut into a :class:`Learned` (the teach-in file stays the bridge's)."""

    def __init__(self, settings: BridgeSettings, t_s: float | None = None) -> None:
        jit = kernel.load()
        self.settings = settings
        self.table: OverrideTable = get_table(settings.override_table)
        self._params = _gate_params(jit, settings, self.table)
        self._state = _gate_state(jit, settings, self._params)
        self._levels = np.array(self.table.levels_pct, dtype=np.float64)
        self._dec = np.zeros(jit.DEC_FIELDS)
        self._cut = np.zeros(jit.CUT_FIELDS)
        self._started = np.zeros(1)
        self.inputs = NO_INPUTS
        self._cuts: list[CutRecord] = []
        self._learned: Learned | None = None
        if t_s is not None:
            self.start(t_s)

    @property
    def armed(self) -> bool:
        return bool(self._state[kernel.load().GS_ARMED])

    @property
    def started(self) -> bool:
        return bool(self._state[kernel.load().GS_STARTED])

    @property
    def engaged(self) -> bool:
        """Whether the cut detector has the tool in the cut."""
        return bool(self._state[kernel.load().GS_ENGAGED])

    def start(self, t_s: float) -> None:
        """Begin at ``t_s`` (armed if the settings say so). A node starts its gate at its first
        callback, when its clock runs: in a lock-step run sim time only starts then."""
        kernel.load().gate_control(self._params, self._state, float(t_s), 1, self._cut)

    def restart(self) -> None:
        """Not started: the next :meth:`start` begins again (a lifecycle node activated anew)."""
        self._state[kernel.load().GS_STARTED] = 0.0

    def reconfigure(self, settings: BridgeSettings, t_s: float) -> None:
        """New dynamic settings; arming through the settings clears an overload hold."""
        jit = kernel.load()
        was_armed = self.settings.armed
        self.settings = settings   # first: re-arming judges the force by the new limit
        self._params = _gate_params(jit, settings, self.table)
        if settings.armed and not was_armed:
            self.arm(t_s)
        elif not settings.armed:
            self.disarm()

    def arm(self, t_s: float) -> str:
        """Arm at ``t_s``; arming clears an overload hold, unless the last force estimate is
        still over the limit. Returns why the hold stays, or ''."""
        kernel.load().gate_control(self._params, self._state, float(t_s), 0, self._cut)
        return self._hold_text()

    def disarm(self) -> None:
        self._state[kernel.load().GS_ARMED] = 0.0

    @property
    def holding(self) -> bool:
        """Whether an overload hold is in force."""
        return bool(self._state[kernel.load().GS_HOLD])

    def on_inputs(self, inputs: InputValues) -> None:
        """The machine's inputs as last read (program enable, threading, operator dial)."""
        jit = kernel.load()
        self.inputs = inputs
        jit.gate_inputs_from_python(self._state, _flag(inputs.program_enable),
                                    _flag(inputs.threading),
                                    math.nan if inputs.operator_dial_pct is None
                                    else float(inputs.operator_dial_pct))

    def on_command(self, requested_pct: float, t_s: float, reachable: bool | None = None) -> None:
        """The controller's request; ``reachable``, its flag, goes to the cut log."""
        jit = kernel.load()
        jit.gate_command_from_python(self._state, float(requested_pct), float(t_s),
                                     -1.0 if reachable is None else float(reachable))

    def on_estimate(self, force_n: float, status: EstimateStatus = EstimateStatus.OK) -> bool:
        """Take a force estimate; True when it has just started an overload hold.

        A saturated or non-finite force counts as over the limit. An invalid or stale estimate
        (it repeats the last good force) says nothing new and is not judged.
        """
        kernel.load().gate_block(self._params, self._state, float(force_n), float(int(status)),
                                 self._cut, self._started)
        self._collect()
        return bool(self._started[0])

    def decide(self, t_s: float) -> Decision:
        """The override for now; the per-block state stays as it is."""
        return self._step(t_s, 0)

    def answer(self, t_s: float) -> Decision:
        """The override answering the block that ends at ``t_s``, the PMC's from the next block
        on; moves the per-block state on (rise limit, cut log, teach-in)."""
        return self._step(t_s, 1)

    def take_cuts(self) -> list[CutRecord]:
        """Cuts that ended since the last call (the cut log)."""
        cuts, self._cuts = self._cuts, []
        return cuts

    def take_learned(self) -> Learned | None:
        """What a learning cut has just taught, once."""
        learned, self._learned = self._learned, None
        return learned

    def close(self) -> CutRecord | None:
        """The session ends: the cut still open, if any, marked incomplete."""
        kernel.load().gate_control(self._params, self._state, 0.0, 2, self._cut)
        return self._collect()

    def arrays(self) -> tuple[FloatArray, FloatArray, FloatArray]:
        """(parameters, state, levels) of this gate now, as the compiled loops take them:
        copies, from which a loop goes on with the same decisions."""
        return self._params.copy(), self._state.copy(), self._levels.copy()

    def _step(self, t_s: float, answer: int) -> Decision:
        jit, dec = kernel.load(), self._dec
        jit.gate_step(self._params, self._state, self._levels, float(t_s), dec, answer)
        applied = float(dec[jit.DEC_APPLIED])
        code, bits = self.table.encode(applied)
        state = self._state
        return Decision(applied, float(state[jit.GS_REQ]), code, bits, self.armed,
                        Reason(int(dec[jit.DEC_REASON])), self._detail(jit, dec), self.inputs,
                        bool(dec[jit.DEC_ENGAGED]), bool(dec[jit.DEC_ALARM]),
                        bool(dec[jit.DEC_STOP]))

    def _collect(self) -> CutRecord | None:
        """A cut and a learning cut the last call finished, into the log and the lesson."""
        jit, cut, state, s = kernel.load(), self._cut, self._state, self.settings
        record = None
        if cut[jit.CUT_READY] != 0.0:
            cut[jit.CUT_READY] = 0.0
            record = CutRecord(
                index=int(cut[jit.CUT_INDEX]), tool=s.tool, start_s=float(cut[jit.CUT_START]),
                end_s=float(cut[jit.CUT_END]), programmed_feed_s=float(cut[jit.CUT_FEED_S]),
                max_force_n=float(cut[jit.CUT_MAXF]), mean_force_n=float(cut[jit.CUT_MEANF]),
                min_override_pct=float(cut[jit.CUT_MINO]),
                overload_events=int(cut[jit.CUT_EVENTS]), breakage=bool(cut[jit.CUT_BREAK]),
                reachable_fraction=float(cut[jit.CUT_REACH]),
                learned=bool(cut[jit.CUT_LEARNED]), complete=bool(cut[jit.CUT_COMPLETE]))
            self._cuts.append(record)
        if state[jit.GS_LEARNED] != 0.0:
            state[jit.GS_LEARNED] = 0.0
            level = float(state[jit.GS_L_LEVEL])
            taught = TaughtTool(level, s.teach_fraction, level * s.teach_fraction,
                                float(state[jit.GS_L_PEAK]), float(state[jit.GS_L_CUT_S]))
            self._learned = Learned(s.tool, taught, _refusal(
                jit, int(state[jit.GS_L_REFUSED]), s, level, float(state[jit.GS_L_LOW])))
        return record

    def _hold_text(self) -> str:
        """Why the overload hold holds ('' where it does not)."""
        jit, state = kernel.load(), self._state
        code, force = int(state[jit.GS_HOLD]), float(state[jit.GS_HOLD_F])
        if code == jit.HOLD_SATURATED:
            text = f'current sensor saturated (force {force:.0f} N or more)'
        elif code == jit.HOLD_NONFINITE:
            text = f'force estimate {force!r} N is not finite'
        elif code == jit.HOLD_ABOVE:
            text = (f'force {force:.0f} N above overload_force_n '
                    f'{float(state[jit.GS_HOLD_LIMIT]):g} N')
        else:
            return ''
        if state[jit.GS_HOLD_AGAIN]:
            text += '; re-armed while still over the limit'
        return text

    def _detail(self, jit: ModuleType, dec: FloatArray) -> str:
        """The decision's one line, from its detail code and values."""
        s, state, table = self.settings, self._state, self.table
        code, a, b = int(dec[jit.DEC_DCODE]), float(dec[jit.DEC_DA]), float(dec[jit.DEC_DB])
        requested = float(state[jit.GS_REQ])
        again = '; re-arm to resume'
        if code == jit.GD_HOLD:
            return self._hold_text() + again
        texts = {
            jit.GD_NONE: '',
            jit.GD_DISARMED: 'not armed: programmed feed',
            jit.GD_WAITING: 'armed, waiting for the first feed command',
            jit.GD_NO_COMMAND: f'no feed command in {a:.3f} s since arming',
            jit.GD_STALE: f'feed command {a:.3f} s old (watchdog {s.watchdog_period_s:g} s)',
            jit.GD_NONFINITE: f'feed command {a!r} % is not finite',
            jit.GD_RANGE: (f'feed command {a:.6g} % outside the {table.name} range '
                           f'[{table.min_pct:g}, {table.max_pct:g}] %'),
            jit.GD_TEACH: f'teach-in: learning cut for {s.tool} at the programmed feed',
            jit.GD_FLOOR: (f'request {requested:.4g} % raised to the feed floor '
                           f'({s.min_cut_override_pct:g} %) while cutting'),
            jit.GD_AIR: f'tool out of the cut: air-cut override {s.air_cut_override_pct:g} %',
            jit.GD_DIAL: (f"the operator's dial at {b:g} % "
                          f'({"times" if s.operator_dial == "product" else "below"} the '
                          f'request {requested:.4g} %)'),
            jit.GD_RISE: f'rising at most {s.rise_rate_pct_s:g} %/s toward {requested:.4g} %',
        }
        if code == jit.GD_BREAKAGE:
            text = self._breakage_text(jit) + again
        elif code == jit.GD_REACTION_HOLD:
            text = self._reaction_text(jit) + again
        elif code == jit.GD_STAND:
            text = _STAND_DOWNS[int(a)]
        else:
            text = texts[code]
        dial = float(dec[jit.DEC_DIALLED])
        if math.isfinite(dial):
            text += f"; the operator's dial at {dial:g} %"
        return text

    def _breakage_text(self, jit: ModuleType) -> str:
        state = self._state
        force, level = float(state[jit.GS_BREAK_F]), float(state[jit.GS_BREAK_LEVEL])
        if state[jit.GS_BREAK] == jit.BREAK_SPIKE:
            return (f'tool breakage: force {force:.0f} N is {force / level - 1.0:.0%} above its '
                    f'recent level {level:.0f} N')
        return (f'tool breakage: force {force:.0f} N is {1.0 - force / level:.0%} below its '
                f'recent level {level:.0f} N while the program says the tool cuts')

    def _reaction_text(self, jit: ModuleType) -> str:
        s, state = self.settings, self._state
        limit, above = float(state[jit.GS_REACT_LIM]), float(state[jit.GS_REACT_ABOVE])
        return (f'overload reaction ({s.overload_reaction}): force above {limit:g} N '
                f'({s.reaction_force_fraction:g} x overload_force_n) for '
                f'{above * s.control_period_s:.2f} s')


_STAND_DOWNS = {
    1: ('thread cutting or tapping (threading input): FANUC runs the programmed feed; stood '
        'down'),
    2: 'program_enable_required, but no program-enable input is wired or read: programmed feed',
    3: ('the part program has not enabled adaptive feed (program-enable input clear): '
        'programmed feed'),
}
_REACTIONS = {'none': 0, 'alarm': 1, 'stop': 2, 'hold': 3}
_DIAL_MODES = {'min': 0, 'product': 1, 'ignore': 2}


def _flag(value: bool | None) -> float:
    return math.nan if value is None else float(bool(value))


def _refusal(jit: ModuleType, code: int, s: BridgeSettings, level: float, low: float) -> str:
    """Why a learning cut was not learned ('' where it was)."""
    if code == jit.LEARN_SHORT:
        return (f'the cut was not longer than twice cut_settle_s ({s.cut_settle_s:g} s): '
                'nothing settled to learn')
    if code == jit.LEARN_FEED:
        return (f'the cut did not run at the programmed feed throughout (down to {low:g} %): '
                "its force is not the tool's level")
    if code == jit.LEARN_UPSET:
        return 'the cut had an overload or a breakage: not a level to regulate to'
    if code == jit.LEARN_HIGH:
        return (f'{s.teach_fraction:g} x {level:.0f} N is not below overload_force_n '
                f'({s.overload_force_n:g} N)')
    return ''


def _gate_params(jit: ModuleType, s: BridgeSettings, table: OverrideTable) -> FloatArray:
    """The compiled gate's parameters (``G_*``), the places of its rings among them."""
    period = s.control_period_s
    debounce = s.debounce_blocks(period)
    settle = math.ceil(s.cut_settle_s / period - 1e-9)
    window = max(1, round(s.breakage_window_s / period))
    p = np.zeros(jit.G_SIZE)
    p[jit.G_WATCHDOG], p[jit.G_SAFE] = s.watchdog_period_s, s.safe_override_pct
    p[jit.G_OVERLOAD], p[jit.G_ARMED] = s.overload_force_n, s.armed
    p[jit.G_CONT], p[jit.G_MIN], p[jit.G_MAX] = table.continuous, table.min_pct, table.max_pct
    p[jit.G_PERIOD] = period
    p[jit.G_ENGAGE], p[jit.G_EXIT], p[jit.G_DEBOUNCE] = s.engage_force_n, s.exit_force_n, debounce
    p[jit.G_REACT_FRACTION] = s.reaction_force_fraction
    p[jit.G_REACT_NEEDED] = math.ceil(s.reaction_delay_s / period - 1e-9)
    p[jit.G_REACTION] = _REACTIONS[s.overload_reaction]
    p[jit.G_SETTLE], p[jit.G_WINDOW] = settle, window
    p[jit.G_SPIKE], p[jit.G_DROP] = s.breakage_spike_fraction, s.breakage_drop_fraction
    p[jit.G_PE_REQUIRED], p[jit.G_THREAD_SD] = s.program_enable_required, s.threading_stand_down
    p[jit.G_DIAL_MODE] = _DIAL_MODES[s.operator_dial]
    p[jit.G_RISE], p[jit.G_FLOOR] = s.rise_rate_pct_s, s.min_cut_override_pct
    p[jit.G_AIR], p[jit.G_TEACH] = s.air_cut_override_pct, s.teach_in
    p[jit.G_TEACH_FRACTION] = s.teach_fraction
    p[jit.G_RECENT_AT] = jit.GS_FIXED
    p[jit.G_PENDING_AT] = jit.GS_FIXED + jit.BLOCK_FIELDS * debounce
    p[jit.G_PENDING_CAP] = debounce + settle
    p[jit.G_WINDOW_AT] = p[jit.G_PENDING_AT] + jit.BLOCK_FIELDS * (debounce + settle)
    return p


def _gate_state(jit: ModuleType, s: BridgeSettings, p: FloatArray) -> FloatArray:
    """The compiled gate's first state (``GS_*``, then its rings)."""
    state = np.zeros(int(p[jit.G_WINDOW_AT] + p[jit.G_WINDOW]))
    state[jit.GS_REQ] = state[jit.GS_BLOCK_F] = math.nan
    state[jit.GS_CMD_T] = state[jit.GS_ARMED_T] = -math.inf
    state[jit.GS_LAST_STATUS] = EstimateStatus.OK
    state[jit.GS_REACH] = -1.0
    state[jit.GS_PE] = state[jit.GS_TH] = state[jit.GS_DIAL] = math.nan
    state[jit.GS_APPLIED] = state[jit.GS_RAMP] = 100.0
    state[jit.GS_LEARNING] = s.teach_in
    return state
