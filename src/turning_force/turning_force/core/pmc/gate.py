"""The override gate, compiled: what the PMC is written, block by block.

:mod:`turning_force.core.pmc.settings` states the rules and their order (the safety gate first,
then the shop floor's behaviours of :mod:`turning_force.core.pmc.shopfloor`); here they are written
once, as compiled functions (``gate_*``) on a parameter and a state array, which the compiled loops
run (:mod:`turning_force.core.kernel.loops`) and :class:`OverrideGate` runs for the bridge, one
block at a time, putting their codes into words. """

from __future__ import annotations

import dataclasses
import math

import numpy as np
import numpy.typing as npt

from turning_force.core.compiled import (
    Arr,
    activate,
    compiled,
    entry,
    pymax,
    pymin,
    quantise,
    table_row,
)
from turning_force.core.pmc.overrides import OverrideTable, get_table
from turning_force.core.pmc.settings import BridgeSettings, Decision, Reason
from turning_force.core.pmc.shopfloor import NO_INPUTS, CutRecord, InputValues, Learned, TaughtTool
from turning_force.core.tools import (
    NO_TOOL,
    TOOL_BRIDGE_KEYS,
    ToolSections,
    load_tools_file,
    tool_settings,
)

__all__ = ['OverrideGate', 'cut_record']

FloatArray = npt.NDArray[np.float64]

# --- the compiled gate: codes, slots and functions --------------------------------------------
# estimate status (EstimateStatus) and the safety gate's reasons (Reason), as plain numbers
OK, STALE, INVALID_INPUT, SATURATED = 0, 1, 2, 3
NORMAL, DISARMED, WATCHDOG, OVERLOAD_HOLD, INVALID_COMMAND = 0, 1, 2, 3, 5
# --- gate -----------------------------------------------------------------------------------
# Reasons beyond the safety gate's (FeedOverride's REASON_*).
OPERATOR, AIR_CUT, TOOL_BREAKAGE, RISE_LIMIT, FEED_FLOOR, TEACH_IN = 4, 7, 8, 9, 10, 11
FEED_NOT_FOLLOWING = 12
# parameters: the safety gate, then the shop floor (core/shopfloor.py)
G_WATCHDOG, G_SAFE, G_OVERLOAD, G_ARMED, G_CONT, G_MIN, G_MAX, G_PERIOD = range(8)
G_ENGAGE, G_EXIT, G_DEBOUNCE, G_REACT_FRACTION, G_REACT_NEEDED, G_REACTION = range(8, 14)
G_SETTLE, G_WINDOW, G_SPIKE, G_DROP, G_PE_REQUIRED, G_THREAD_SD, G_DIAL_MODE = range(14, 21)
G_RISE, G_FLOOR, G_AIR, G_TEACH, G_TEACH_FRACTION = range(21, 26)
G_RECENT_AT, G_PENDING_AT, G_PENDING_CAP, G_WINDOW_AT = range(26, 30)
# the feed-follow check: how long, how far [% points], the axis's lag, the programmed feed
# [mm/rev] and the spindle_speed_rpm parameter
G_FOLLOW_S, G_FOLLOW_TOL, G_FOLLOW_LAG, G_FEED_REV, G_RPM, G_FOLLOW_OVER = range(30, 36)
G_HAND_BACK = 36
# the entry feed's hold past G_SETTLE: the force's rise it waits out [per s of its level], the
# longest hold [blocks], the slope's window [blocks] and where its ring starts
G_RISE_LIMIT, G_HOLD_MAX, G_SLOPE_N, G_SLOPE_AT = range(37, 41)
G_SIZE = 41
REACTION_NONE, REACTION_ALARM, REACTION_STOP, REACTION_HOLD = 0, 1, 2, 3
DIAL_MIN, DIAL_PRODUCT, DIAL_IGNORE = 0, 1, 2
# hold causes (the overload hold's detail): saturated, not finite, above the limit
HOLD_NONE, HOLD_SATURATED, HOLD_NONFINITE, HOLD_ABOVE = 0, 1, 2, 3
# stand-downs: threading, no program-enable input, program enable clear
STAND_NONE, STAND_THREADING, STAND_NO_PE, STAND_PE_CLEAR = 0, 1, 2, 3
BREAK_NONE, BREAK_SPIKE, BREAK_DROP = 0, 1, 2
# a learning cut refused: too short, not at the programmed feed, overload or breakage, too high
LEARN_OK, LEARN_SHORT, LEARN_FEED, LEARN_UPSET, LEARN_HIGH = 0, 1, 2, 3, 4
# state: the safety gate
GS_ARMED, GS_STARTED, GS_REQ, GS_CMD_T, GS_ARMED_T, GS_LAST_F, GS_LAST_STATUS = range(7)
GS_HOLD, GS_HOLD_F, GS_HOLD_LIMIT, GS_HOLD_AGAIN, GS_REACH = range(7, 12)
# the machine's inputs (NaN: not wired), the shop floor's state
GS_PE, GS_TH, GS_DIAL = range(12, 15)
GS_ENGAGED, GS_RUN, GS_CUT_BLOCKS, GS_ABOVE, GS_IN_EVENT, GS_BLOCK_F, GS_BLOCK_EVENT = \
    range(15, 22)
GS_BREAK, GS_BREAK_F, GS_BREAK_LEVEL, GS_REACTED, GS_REACT_ABOVE, GS_APPLIED, GS_RAMP = \
    range(22, 29)
GS_LEARNING = 29
# what a learning cut taught (GS_LEARNED 1 until taken): level, peak, its length, refusal
GS_LEARNED, GS_L_LEVEL, GS_L_PEAK, GS_L_CUT_S, GS_L_REFUSED, GS_L_LOW = range(30, 36)
# the cut in progress: its blocks' sums (Neumaier-compensated) and extremes
GS_C_INDEX, GS_C_START_T, GS_C_END_T, GS_C_FEED, GS_C_FEED_C, GS_C_MAXF = range(36, 42)
GS_C_SUMF, GS_C_SUMF_C, GS_C_NF, GS_C_MINO, GS_C_EVENTS, GS_C_BREAK = range(42, 48)
GS_C_REACH, GS_C_NCMD, GS_C_N, GS_CUTS = range(48, 52)
# the learning cut's blocks (past cut_settle_s from both ends)
GS_LA_SUMF, GS_LA_SUMF_C, GS_LA_NF, GS_LA_MAXF, GS_LA_N, GS_LA_OFF100, GS_LA_LOW = \
    range(52, 59)
GS_LA_UPSET = 59
# the rings: blocks before the cut (GS_R_*), blocks of the cut not yet summed (GS_P_*), the
# breakage window's forces (GS_W_*): count and next place; their slots from G_*_AT on
GS_R_N, GS_R_NEXT, GS_P_N, GS_P_NEXT, GS_W_N, GS_W_NEXT = range(60, 66)
GS_REACT_LIM = 66     # the reaction's limit when it fired
# the feed-follow check: the envelope of the applied override the axis may lag through, the
# time it has been outside it, whether it tripped, and what it saw then (the axis's override,
# the envelope's edge, the spindle speed)
GS_F_HI, GS_F_LO, GS_F_OFF_S, GS_F_TRIPPED, GS_F_ACTUAL, GS_F_EDGE, GS_F_RPM = range(67, 74)
# the tool in use (the machine's tool input, NaN: not given) and whether it has no section in
# the tools file (the feed handed back until a tool with one comes)
GS_TOOL, GS_TOOL_BAD = 74, 75
# the entry: 1 while the entry feed holds; the ring of its last forces: count and next place
GS_ENTERING, GS_E_N, GS_E_NEXT = 76, 77, 78
GS_FIXED = 79
BLOCK_FIELDS = 6     # a block in a ring: end time, force, applied, reachable, event, breakage
# a cut record (CUT_*): what a finished cut leaves in the gate's output row
CUT_INDEX, CUT_START, CUT_END, CUT_FEED_S, CUT_MAXF, CUT_MEANF, CUT_MINO = range(7)
CUT_EVENTS, CUT_BREAK, CUT_REACH, CUT_LEARNED, CUT_COMPLETE, CUT_READY = range(7, 13)
CUT_TOOL = 13   # the tool that cut (NaN: no tool input)
CUT_FIELDS = 14
# a decision (DEC_*): applied, reason, the pct before quantisation, detail code and values,
# whether the request went through (the rise limit's base), the outputs
DEC_APPLIED, DEC_REASON, DEC_PCT, DEC_DCODE, DEC_DA, DEC_DB, DEC_DC, DEC_DIALLED = range(8)
DEC_SHAPED, DEC_ALARM, DEC_STOP, DEC_ENGAGED = range(8, 12)
DEC_FIELDS = 12
# detail codes of a decision (the gate's one line, in pmc.py's words)
(GD_NONE, GD_HOLD, GD_DISARMED, GD_WAITING, GD_NO_COMMAND, GD_STALE, GD_NONFINITE,
 GD_RANGE, GD_BREAKAGE, GD_REACTION_HOLD, GD_STAND, GD_TEACH, GD_FLOOR, GD_AIR, GD_DIAL,
 GD_RISE, GD_FOLLOW, GD_TOOL) = range(18)


# --- the gate: the safety gate and the shop floor (core/pmc.py, core/shopfloor.py) ---------

@compiled
def _add(gs: np.ndarray, at: int, x: float) -> None:
    """gs[at] += x, Neumaier-compensated in gs[at + 1] (the sum is gs[at] + gs[at + 1])."""
    total = gs[at]
    t = total + x
    if abs(total) >= abs(x):
        gs[at + 1] += (total - t) + x
    else:
        gs[at + 1] += (x - t) + total
    gs[at] = t


@compiled
def _ring_at(gs: np.ndarray, at: int, cap: int, next_slot: int, age: int) -> int:
    """Where the block ``age`` blocks older than the newest is (0: the newest)."""
    return at + BLOCK_FIELDS * ((int(gs[next_slot]) - 1 - age) % cap)


@compiled
def _ring_put(gs: np.ndarray, at: int, cap: int, n_slot: int, next_slot: int, t: float,
              force: float, applied: float, reach: float, event: float,
              breakage: float) -> None:
    i = int(gs[next_slot])
    base = at + BLOCK_FIELDS * i
    gs[base], gs[base + 1], gs[base + 2] = t, force, applied
    gs[base + 3], gs[base + 4], gs[base + 5] = reach, event, breakage
    gs[next_slot] = (i + 1) % cap
    gs[n_slot] = min(gs[n_slot] + 1.0, float(cap))


@compiled
def _cut_add(gp: np.ndarray, gs: np.ndarray, base: int) -> None:
    """One block into the cut record's sums (core/shopfloor.py CutLog._record)."""
    t, force, applied = gs[base], gs[base + 1], gs[base + 2]
    if gs[GS_C_N] == 0.0:
        gs[GS_C_START_T], gs[GS_C_MINO] = t, applied
    gs[GS_C_END_T] = t
    gs[GS_C_N] += 1.0
    _add(gs, GS_C_FEED, applied / 100.0 * gp[G_PERIOD])
    if math.isfinite(force):
        gs[GS_C_MAXF] = force if gs[GS_C_NF] == 0.0 else pymax(gs[GS_C_MAXF], force)
        _add(gs, GS_C_SUMF, force)
        gs[GS_C_NF] += 1.0
    gs[GS_C_MINO] = pymin(gs[GS_C_MINO], applied)
    gs[GS_C_EVENTS] += gs[base + 4]
    gs[GS_C_BREAK] = pymax(gs[GS_C_BREAK], gs[base + 5])
    if gs[base + 3] >= 0.0:
        gs[GS_C_NCMD] += 1.0
        gs[GS_C_REACH] += gs[base + 3]


@compiled
def _learn_add(gs: np.ndarray, base: int) -> None:
    """One block into the learning cut's sums (ShopFloor._learn)."""
    force, applied = gs[base + 1], gs[base + 2]
    if gs[GS_LA_N] == 0.0:
        gs[GS_LA_LOW] = applied
    gs[GS_LA_N] += 1.0
    if math.isfinite(force):
        gs[GS_LA_MAXF] = force if gs[GS_LA_NF] == 0.0 else pymax(gs[GS_LA_MAXF], force)
        _add(gs, GS_LA_SUMF, force)
        gs[GS_LA_NF] += 1.0
    if applied != 100.0:
        gs[GS_LA_OFF100] = 1.0
    gs[GS_LA_LOW] = pymin(gs[GS_LA_LOW], applied)
    if gs[base + 4] != 0.0 or gs[base + 5] != 0.0:
        gs[GS_LA_UPSET] = 1.0


@compiled
def _cut_push(gp: np.ndarray, gs: np.ndarray, t: float, force: float, applied: float,
              reach: float, event: float, breakage: float) -> None:
    """A block of the cut in progress. The cut's record leaves out the last debounce - 1
    blocks when the tool leaves (they were already out), and the learning cut cut_settle_s more
    at both ends: a block is summed into the record once it is debounce - 1 blocks old, into
    the learning cut once it is debounce - 1 + settle blocks old (and not among the first
    settle). The ring (debounce + settle blocks) holds them until then."""
    cap = int(gp[G_PENDING_CAP])
    trimmed = int(gp[G_DEBOUNCE]) - 1
    settle = int(gp[G_SETTLE])
    index = int(gs[GS_C_INDEX])
    gs[GS_C_INDEX] = index + 1
    at = int(gp[G_PENDING_AT])
    _ring_put(gs, at, cap, GS_P_N, GS_P_NEXT, t, force, applied, reach, event, breakage)
    if gs[GS_P_N] > trimmed:
        _cut_add(gp, gs, _ring_at(gs, at, cap, GS_P_NEXT, trimmed))
    if gs[GS_P_N] > trimmed + settle and index - trimmed - settle >= settle:
        _learn_add(gs, _ring_at(gs, at, cap, GS_P_NEXT, trimmed + settle))


@compiled
def _cut_clear(gs: np.ndarray) -> None:
    for slot in range(GS_C_INDEX, GS_CUTS):
        gs[slot] = 0.0
    for slot in range(GS_LA_SUMF, GS_LA_UPSET + 1):
        gs[slot] = 0.0
    gs[GS_P_N], gs[GS_P_NEXT] = 0.0, 0.0


@compiled
def _cut_record(gp: np.ndarray, gs: np.ndarray, learned: bool, complete: bool,
                cut: np.ndarray) -> None:
    """The cut in progress as a record (CUT_*) into ``cut``, CUT_READY set; then forgotten."""
    if gs[GS_C_N] > 0.0:
        gs[GS_CUTS] += 1.0
        nf, ncmd = gs[GS_C_NF], gs[GS_C_NCMD]
        cut[CUT_INDEX] = gs[GS_CUTS]
        cut[CUT_START] = gs[GS_C_START_T] - gp[G_PERIOD]
        cut[CUT_END] = gs[GS_C_END_T]
        cut[CUT_FEED_S] = gs[GS_C_FEED] + gs[GS_C_FEED_C]
        cut[CUT_MAXF] = gs[GS_C_MAXF] if nf > 0.0 else math.nan
        cut[CUT_MEANF] = (gs[GS_C_SUMF] + gs[GS_C_SUMF_C]) / nf if nf > 0.0 else math.nan
        cut[CUT_MINO], cut[CUT_EVENTS] = gs[GS_C_MINO], gs[GS_C_EVENTS]
        cut[CUT_BREAK] = gs[GS_C_BREAK]
        cut[CUT_REACH] = gs[GS_C_REACH] / ncmd if ncmd > 0.0 else math.nan
        cut[CUT_LEARNED] = 1.0 if learned else 0.0
        cut[CUT_COMPLETE] = 1.0 if complete else 0.0
        cut[CUT_TOOL] = gs[GS_TOOL]
        cut[CUT_READY] = 1.0
    _cut_clear(gs)


@compiled
def _learn(gp: np.ndarray, gs: np.ndarray) -> None:
    """A learning cut is over (ShopFloor._learn): its level, the mean force between
    cut_settle_s after the entry and cut_settle_s before the exit; refused where it cannot be
    the tool's level (then the next cut is tried)."""
    nf = gs[GS_LA_NF]
    level = (gs[GS_LA_SUMF] + gs[GS_LA_SUMF_C]) / nf if nf > 0.0 else math.nan
    refused = LEARN_OK
    if nf == 0.0:
        refused = LEARN_SHORT
    elif gs[GS_LA_OFF100] != 0.0:
        refused = LEARN_FEED
    elif gs[GS_LA_UPSET] != 0.0 or gs[GS_REACTED] != 0.0 or gs[GS_BREAK] != 0.0:
        refused = LEARN_UPSET
    elif level * gp[G_TEACH_FRACTION] >= gp[G_OVERLOAD]:
        refused = LEARN_HIGH
    gs[GS_LEARNING] = 1.0 if refused != LEARN_OK else 0.0
    gs[GS_LEARNED], gs[GS_L_LEVEL] = 1.0, level
    gs[GS_L_PEAK] = gs[GS_LA_MAXF] if nf > 0.0 else math.nan
    gs[GS_L_CUT_S] = gs[GS_LA_N] * gp[G_PERIOD]
    gs[GS_L_REFUSED], gs[GS_L_LOW] = refused, gs[GS_LA_LOW]


@compiled
def _engagement(gp: np.ndarray, gs: np.ndarray, force: float, cut: np.ndarray) -> None:
    """The cut detector (ShopFloor._engagement): in after ``debounce`` blocks above
    engage_force_n, out after as many below exit_force_n; a cut's record from the first block
    of the run that engaged to the last before the run that left."""
    debounce = gp[G_DEBOUNCE]
    if gs[GS_ENGAGED] == 0.0:
        gs[GS_RUN] = gs[GS_RUN] + 1.0 if force > gp[G_ENGAGE] else 0.0
        if gs[GS_RUN] >= debounce:
            gs[GS_ENGAGED], gs[GS_CUT_BLOCKS] = 1.0, gs[GS_RUN]
            gs[GS_ENTERING], gs[GS_E_N], gs[GS_E_NEXT] = 1.0, 0.0, 0.0
            back = min(int(gs[GS_RUN]) - 1, int(gs[GS_R_N]))
            at, cap = int(gp[G_RECENT_AT]), int(debounce)
            for age in range(back - 1, -1, -1):
                b = _ring_at(gs, at, cap, GS_R_NEXT, age)
                _cut_push(gp, gs, gs[b], gs[b + 1], gs[b + 2], gs[b + 3], gs[b + 4],
                          gs[b + 5])
            gs[GS_R_N], gs[GS_R_NEXT], gs[GS_RUN] = 0.0, 0.0, 0.0
        return
    gs[GS_CUT_BLOCKS] += 1.0
    gs[GS_RUN] = gs[GS_RUN] + 1.0 if force < gp[G_EXIT] else 0.0
    if gs[GS_RUN] >= debounce:
        gs[GS_ENGAGED], gs[GS_ENTERING] = 0.0, 0.0
        learned = False
        if gs[GS_LEARNING] != 0.0:
            _learn(gp, gs)
            learned = gs[GS_L_REFUSED] == LEARN_OK
        _cut_record(gp, gs, learned, True, cut)
        gs[GS_RUN] = 0.0


@compiled
def _push(gs: np.ndarray, at: int, size: int, count: int, value: float) -> None:
    """``value`` into the ring of ``size`` places at ``at``; its count of values in
    ``gs[count]`` (at most ``size``), its next place in ``gs[count + 1]``."""
    i = int(gs[count + 1])
    gs[at + i] = value
    gs[count + 1] = (i + 1) % size
    gs[count] = min(gs[count] + 1.0, float(size))


@compiled
def _entry(gp: np.ndarray, gs: np.ndarray, force: float) -> None:
    """Whether the entry feed still holds (``GS_ENTERING``): for cut_settle_s after the
    engagement, then while the force still rises faster than entry_rise_limit_per_s of its
    level, the cut not yet established, for at most entry_hold_max_s. The rise is the least
    squares slope of the force over the last ``ENTRY_WINDOW_S``, the level its mean there.
    Once ended, the hold does not come back within the cut.

    A fixed hold ended the entry feed on a slow cut with its force still rising
    (``bench_entries.py``, seed 15 #7: tau_c 0.19 s, the force at 316 N and climbing at
    0.3 s): the predictive law learned its process gain ``F / z^g`` from it, too low, sent
    150 % and entered 113 N over the reference (70 N now). The rise waited out is the
    axis feed's too, where an underdamped servo still swings back to the entry feed after
    an exit: the predictive law's model rests on the entry level the gate holds, and the
    ringing axis was at 13 % where the model held 30 % (seed 7 #17: 150 N over, 24 N now).
    A law without that model pays for the wait in time only: on population seed 42's #138
    (a servo damped at 0.34 and slowed x1.39) PI reached the reference after the 1 s settle
    window at each re-entry, 9.5 N steady against 4.3 N. Leaving the feed's share of the
    rise out of the wait gave that PI 3.9 N and brought 7 #17's 150 N back."""
    if gs[GS_ENTERING] == 0.0:
        return
    size, at = int(gp[G_SLOPE_N]), int(gp[G_SLOPE_AT])
    _push(gs, at, size, GS_E_N, force)
    blocks = gs[GS_CUT_BLOCKS]
    if blocks <= gp[G_SETTLE]:
        return
    if gp[G_RISE_LIMIT] <= 0.0 or blocks > gp[G_HOLD_MAX]:
        gs[GS_ENTERING] = 0.0
        return
    n = int(gs[GS_E_N])
    if n < 2:
        return
    # least squares over j = 0..n-1: slope sum (j - mid) y_j / sum (j - mid)^2, the latter
    # n (n^2 - 1) / 12
    oldest = (int(gs[GS_E_NEXT]) - n) % size
    total, moment, middle = 0.0, 0.0, 0.5 * (n - 1)
    for j in range(n):
        y = gs[at + (oldest + j) % size]
        total += y
        moment += (j - middle) * y
    slope = moment * 12.0 / (n * (n * n - 1.0)) / gp[G_PERIOD]
    if slope <= gp[G_RISE_LIMIT] * total / n:
        gs[GS_ENTERING] = 0.0


@compiled
def _stand_down(gp: np.ndarray, gs: np.ndarray) -> int:
    """Why the option stands down to the programmed feed (STAND_*), from the inputs."""
    if gp[G_THREAD_SD] != 0.0 and gs[GS_TH] == 1.0:
        return STAND_THREADING
    if gp[G_PE_REQUIRED] != 0.0:
        if math.isnan(gs[GS_PE]):
            return STAND_NO_PE
        if gs[GS_PE] == 0.0:
            return STAND_PE_CLEAR
    return STAND_NONE


@compiled
def _dial(gp: np.ndarray, gs: np.ndarray) -> float:
    """The operator's dial in force, NaN where it is not read or is ignored."""
    dial = gs[GS_DIAL]
    if gp[G_DIAL_MODE] == DIAL_IGNORE or not math.isfinite(dial):
        return math.nan
    return pymax(dial, 0.0)


@compiled
def _window_level(gp: np.ndarray, gs: np.ndarray) -> float:
    at, n = int(gp[G_WINDOW_AT]), int(gs[GS_W_N])
    total, c = 0.0, 0.0
    for i in range(n):
        x = gs[at + i]
        t = total + x
        c += (total - t) + x if abs(total) >= abs(x) else (x - t) + total
        total = t
    return (total + c) / n


@compiled
def _observe(gp: np.ndarray, gs: np.ndarray, force: float, armed: bool, hold_started: bool,
             cut: np.ndarray) -> None:
    """ShopFloor.observe: a valid, finite force estimate of the current block: the cut
    detector, overload events, the overload reaction, tool breakage."""
    gs[GS_BLOCK_F] = force
    _engagement(gp, gs, force, cut)
    _entry(gp, gs, force)
    acting = armed and _stand_down(gp, gs) == STAND_NONE
    limit = gp[G_REACT_FRACTION] * gp[G_OVERLOAD]
    if force > limit and gs[GS_IN_EVENT] == 0.0:
        gs[GS_IN_EVENT], gs[GS_BLOCK_EVENT] = 1.0, 1.0
    elif force < 0.9 * limit:   # shopfloor.EVENT_RESET_FRACTION
        gs[GS_IN_EVENT] = 0.0
    if hold_started:
        gs[GS_BLOCK_EVENT] = 1.0
    gs[GS_ABOVE] = gs[GS_ABOVE] + 1.0 if force > limit and acting else 0.0
    if gp[G_REACTION] != REACTION_NONE and gs[GS_REACTED] == 0.0 \
            and gs[GS_ABOVE] >= gp[G_REACT_NEEDED]:
        gs[GS_REACTED], gs[GS_REACT_ABOVE], gs[GS_REACT_LIM] = 1.0, gs[GS_ABOVE], limit
    if gs[GS_ENGAGED] == 0.0:
        gs[GS_W_N], gs[GS_W_NEXT] = 0.0, 0.0
        return
    settled = gs[GS_CUT_BLOCKS] > gp[G_SETTLE]
    size = int(gp[G_WINDOW])
    if settled and int(gs[GS_W_N]) == size and acting and gs[GS_BREAK] == BREAK_NONE:
        level = _window_level(gp, gs)
        if level > 0.0:
            if gp[G_SPIKE] > 0.0 and force > (1.0 + gp[G_SPIKE]) * level:
                gs[GS_BREAK] = BREAK_SPIKE
            elif gp[G_DROP] > 0.0 and gs[GS_PE] == 1.0 and force < (1.0 - gp[G_DROP]) * level:
                gs[GS_BREAK] = BREAK_DROP
            gs[GS_BREAK_F], gs[GS_BREAK_LEVEL] = force, level
    if settled:
        _push(gs, int(gp[G_WINDOW_AT]), size, GS_W_N, force)


@compiled
def _over_code(gp: np.ndarray, force: float, status: float) -> int:
    """Why a force holds the feed (HOLD_*): a saturated sensor, a force that is not finite,
    or above overload_force_n."""
    if status == SATURATED:
        return HOLD_SATURATED
    if not math.isfinite(force):
        return HOLD_NONFINITE
    if force > gp[G_OVERLOAD]:
        return HOLD_ABOVE
    return HOLD_NONE


@compiled
def gate_on_estimate(gp: np.ndarray, gs: np.ndarray, force: float, status: int,
                     cut: np.ndarray) -> bool:
    """OverrideGate.on_estimate: a force estimate; True where it has just started an overload
    hold. A saturated or non-finite force counts as over the limit; an invalid or stale
    estimate (it repeats the last good force) says nothing new and is not judged. A cut that
    ends writes its record into ``cut``."""
    if status == INVALID_INPUT or status == STALE:   # noqa: SIM109 -- numba: no tuple ``in``
        return False
    gs[GS_LAST_F], gs[GS_LAST_STATUS] = force, status
    code = _over_code(gp, force, status)
    started = code != HOLD_NONE and gs[GS_HOLD] == HOLD_NONE
    if started:
        gs[GS_HOLD], gs[GS_HOLD_F], gs[GS_HOLD_LIMIT] = code, force, gp[G_OVERLOAD]
        gs[GS_HOLD_AGAIN] = 0.0
    if math.isfinite(force):
        _observe(gp, gs, force, gs[GS_ARMED] != 0.0, started, cut)
    return started


@compiled
def gate_arm(gp: np.ndarray, gs: np.ndarray, t: float) -> None:
    """OverrideGate.arm: armed at ``t``; the latched reactions cleared; the overload hold
    cleared, unless the last force estimate is still over the limit."""
    gs[GS_ARMED], gs[GS_ARMED_T] = 1.0, t
    gs[GS_BREAK], gs[GS_REACTED], gs[GS_ABOVE] = BREAK_NONE, 0.0, 0.0
    gs[GS_F_TRIPPED], gs[GS_F_OFF_S] = 0.0, 0.0
    code = _over_code(gp, gs[GS_LAST_F], gs[GS_LAST_STATUS])
    if code != HOLD_NONE:
        gs[GS_HOLD_AGAIN] = 1.0 if gs[GS_HOLD] != HOLD_NONE else 0.0
        gs[GS_HOLD], gs[GS_HOLD_F], gs[GS_HOLD_LIMIT] = code, gs[GS_LAST_F], gp[G_OVERLOAD]
    else:
        gs[GS_HOLD] = HOLD_NONE


@compiled
def gate_on_command(gs: np.ndarray, requested: float, t: float, reachable: float) -> None:
    """OverrideGate.on_command: the controller's request at ``t``; ``reachable`` its flag
    (1, 0; -1: none) for the cut log."""
    gs[GS_REQ], gs[GS_CMD_T], gs[GS_REACH] = requested, t, reachable


@compiled
def gate_feed(gp: np.ndarray, gs: np.ndarray, feed_mm_min: float, rpm: float) -> None:
    """OverrideGate.on_feed: the axis feed rate the DAQ measured over the block [mm/min]
    (its mean), against the override the PMC applied during it. The axis lags the override
    (the PMC's dead time, the servo): it may run anywhere inside an envelope of the applied
    override that takes a rise or a fall at once on one side and follows it on the other with
    the lag ``feed_follow_lag_s``, give or take ``feed_follow_tolerance_pct`` and
    ``feed_follow_overshoot`` of the envelope's width (an underdamped servo overshoots a large
    swing of the override by a share of it). Outside it for
    ``feed_follow_time_s`` while the tool is in the cut and the gate regulates (armed, not
    stood down), the feed does not follow the override (override cancel, a feed hold, a dry
    run, a ladder that does not copy the override): the gate stops regulating and hands the
    feed back until re-armed. The feed of the 100 % override is the programmed feed at the
    spindle speed ``rpm`` (NaN: the spindle_speed_rpm parameter); a feed not measured (NaN)
    is not judged."""
    applied = gs[GS_APPLIED]
    follow = pymin(gp[G_PERIOD] / gp[G_FOLLOW_LAG], 1.0)
    hi, lo = gs[GS_F_HI], gs[GS_F_LO]
    gs[GS_F_HI] = applied if applied >= hi else hi + (applied - hi) * follow
    gs[GS_F_LO] = applied if applied <= lo else lo + (applied - lo) * follow
    if gp[G_FOLLOW_S] <= 0.0 or gs[GS_F_TRIPPED] != 0.0 or not math.isfinite(feed_mm_min):
        return
    if not (rpm > 0.0 and math.isfinite(rpm)):
        rpm = gp[G_RPM]
    actual = 100.0 * feed_mm_min / (gp[G_FEED_REV] * rpm)
    tolerance = gp[G_FOLLOW_TOL] + gp[G_FOLLOW_OVER] * (gs[GS_F_HI] - gs[GS_F_LO])
    above, below = actual > gs[GS_F_HI] + tolerance, actual < gs[GS_F_LO] - tolerance
    judged = (gs[GS_ARMED] != 0.0 and gs[GS_ENGAGED] != 0.0
              and _stand_down(gp, gs) == STAND_NONE)
    if not (judged and (above or below)):
        gs[GS_F_OFF_S] = 0.0
        return
    gs[GS_F_OFF_S] += gp[G_PERIOD]
    if gs[GS_F_OFF_S] >= gp[G_FOLLOW_S] - 1e-9:
        gs[GS_F_TRIPPED], gs[GS_F_ACTUAL], gs[GS_F_RPM] = 1.0, actual, rpm
        gs[GS_F_EDGE] = gs[GS_F_HI] if above else gs[GS_F_LO]


@compiled
def gate_inputs(gs: np.ndarray, program_enable: float, threading: float,
                dial: float) -> None:
    """OverrideGate.on_inputs: the machine's inputs (1 set, 0 clear, NaN not wired)."""
    gs[GS_PE], gs[GS_TH], gs[GS_DIAL] = program_enable, threading, dial


# The gate's per-tool parameters (tools file, ``pmc_bridge`` keys of a tool's section), in
# the order of TOOL_BRIDGE_KEYS (core/tools.py) and of a tool table's columns after its number.
TOOL_GATE = (G_AIR, G_FLOOR, G_OVERLOAD, G_ENGAGE, G_EXIT, G_RISE)


@compiled
def gate_tool(tools: np.ndarray, gp: np.ndarray, gs: np.ndarray, number: float) -> int:
    """The machine's tool input says tool ``number``: its row of ``tools`` (number, then the
    TOOL_GATE parameters) into the parameters, returned; -1 where the table has no row for it
    (and a table is given: the feed is handed back until a tool with one comes, never another
    tool's settings used) or no table is given (the settings serve every tool)."""
    gs[GS_TOOL] = number
    if tools.shape[0] == 0:
        gs[GS_TOOL_BAD] = 0.0
        return -1
    row = table_row(tools, number)
    gs[GS_TOOL_BAD] = 1.0 if row < 0 else 0.0
    if row >= 0:
        for j in range(len(TOOL_GATE)):
            gp[TOOL_GATE[j]] = tools[row, j + 1]
    return row


@entry('int64(float64[:, ::1], float64[::1], float64[::1], float64)')
def gate_tool_change(tools: Arr, gp: Arr, gs: Arr, number: float) -> int:
    """:func:`gate_tool` from Python (:class:`OverrideGate`)."""
    return gate_tool(tools, gp, gs, number)


@compiled
def _dialled(gp: np.ndarray, gs: np.ndarray, dec: np.ndarray, pct: float, reason: int,
             code: int) -> None:
    """A decision other than the request: the operator's dial, where read, only lowers it."""
    dial = _dial(gp, gs)
    dec[DEC_REASON], dec[DEC_DCODE], dec[DEC_DIALLED] = reason, code, math.nan
    if math.isfinite(dial) and dial < pct:
        pct = dial
        dec[DEC_DIALLED] = dial
    dec[DEC_PCT] = pct


@compiled
def _judge(gp: np.ndarray, gs: np.ndarray, t: float, dec: np.ndarray) -> None:
    """OverrideGate._judge: the override before quantisation (DEC_PCT), its reason and detail,
    and whether the request went through (DEC_SHAPED), in the gate's order: the overload hold,
    disarmed, the watchdog, an invalid command, the shop floor's holds and stand-downs, then
    the request shaped (feed floor, air cut, dial, rise limit)."""
    requested = gs[GS_REQ]
    dec[DEC_SHAPED], dec[DEC_DA], dec[DEC_DB], dec[DEC_DC] = 0.0, math.nan, math.nan, math.nan
    if gs[GS_HOLD] != HOLD_NONE:
        dec[DEC_PCT], dec[DEC_REASON], dec[DEC_DCODE] = 0.0, OVERLOAD_HOLD, GD_HOLD
        dec[DEC_DIALLED] = math.nan
        return
    if gs[GS_ARMED] == 0.0:
        _dialled(gp, gs, dec, gp[G_HAND_BACK], DISARMED, GD_DISARMED)
        return
    if gs[GS_TOOL_BAD] != 0.0:
        _dialled(gp, gs, dec, gp[G_HAND_BACK], OPERATOR, GD_TOOL)
        return
    if gs[GS_CMD_T] < gs[GS_ARMED_T]:   # nothing since arming
        waited = t - gs[GS_ARMED_T]
        dec[DEC_DA] = waited
        if waited <= gp[G_WATCHDOG]:
            _dialled(gp, gs, dec, 100.0, WATCHDOG, GD_WAITING)
        else:
            _dialled(gp, gs, dec, gp[G_SAFE], WATCHDOG, GD_NO_COMMAND)
        return
    age = t - gs[GS_CMD_T]
    if age > gp[G_WATCHDOG]:
        dec[DEC_DA] = age
        _dialled(gp, gs, dec, gp[G_SAFE], WATCHDOG, GD_STALE)
        return
    dec[DEC_DA] = requested
    if not math.isfinite(requested):
        _dialled(gp, gs, dec, gp[G_SAFE], INVALID_COMMAND, GD_NONFINITE)
        return
    if not gp[G_MIN] <= requested <= gp[G_MAX]:
        _dialled(gp, gs, dec, gp[G_SAFE], INVALID_COMMAND, GD_RANGE)
        return
    if gs[GS_BREAK] != BREAK_NONE:
        _dialled(gp, gs, dec, 0.0, TOOL_BREAKAGE, GD_BREAKAGE)
        return
    if gs[GS_REACTED] != 0.0 and gp[G_REACTION] == REACTION_HOLD:
        _dialled(gp, gs, dec, 0.0, OVERLOAD_HOLD, GD_REACTION_HOLD)
        return
    if gs[GS_F_TRIPPED] != 0.0:
        _dialled(gp, gs, dec, 100.0, FEED_NOT_FOLLOWING, GD_FOLLOW)
        return
    stand = _stand_down(gp, gs)
    if stand != STAND_NONE:
        dec[DEC_DA] = stand
        _dialled(gp, gs, dec, 100.0, OPERATOR, GD_STAND)
        return
    if gs[GS_LEARNING] != 0.0:
        _dialled(gp, gs, dec, 100.0, TEACH_IN, GD_TEACH)
        return
    # The request, shaped (ShopFloor.shape).
    pct, reason, code = requested, NORMAL, GD_NONE
    engaged = gs[GS_ENGAGED] != 0.0
    if engaged and gp[G_FLOOR] > 0.0 and pct < gp[G_FLOOR]:
        pct, reason, code = gp[G_FLOOR], FEED_FLOOR, GD_FLOOR
    entering = engaged and gs[GS_ENTERING] != 0.0
    if (not engaged or entering) and gp[G_AIR] > 0.0 and pct > gp[G_AIR]:
        pct, reason, code = gp[G_AIR], AIR_CUT, GD_AIR
    dial = _dial(gp, gs)
    if math.isfinite(dial):
        if gp[G_DIAL_MODE] == DIAL_PRODUCT:
            dialled = pct * (pymin(dial, 100.0) / 100.0)
        else:
            dialled = pymin(pct, dial)
        if dialled < pct:
            pct, reason, code = dialled, OPERATOR, GD_DIAL
            dec[DEC_DB] = dial
    ceiling = gs[GS_RAMP] + gp[G_RISE] * gp[G_PERIOD]
    if gp[G_RISE] > 0.0 and pct > ceiling:
        pct, reason, code = ceiling, RISE_LIMIT, GD_RISE
    dec[DEC_PCT], dec[DEC_REASON], dec[DEC_DCODE] = pct, reason, code
    dec[DEC_DIALLED], dec[DEC_SHAPED] = math.nan, 1.0


@compiled
def _hold_ignored(gp: np.ndarray, gs: np.ndarray) -> bool:
    """The gate holds the feed (an overload, a tool breakage, the overload reaction's hold)
    and the axis does not follow the override (the feed-follow check has tripped): the
    override cannot stop it (override cancel M49, a ladder that does not copy it), and the
    stop request, a feed hold the PMC takes apart from the override, is what is left. On
    population seed 42's #34 (override cancel from 5 s, a x3.5 depth step then) the overload
    hold wrote 0 % and the force stayed at 2,305 N, over the 2,000 N limit, to the end."""
    holding = (gs[GS_HOLD] != HOLD_NONE or gs[GS_BREAK] != BREAK_NONE
               or (gs[GS_REACTED] != 0.0 and gp[G_REACTION] == REACTION_HOLD))
    return holding and gs[GS_F_TRIPPED] != 0.0


@compiled
def gate_decide(gp: np.ndarray, gs: np.ndarray, levels: np.ndarray, t: float,
                dec: np.ndarray) -> None:
    """OverrideGate.decide: the override for now (DEC_*), the state as it is."""
    _judge(gp, gs, t, dec)
    dec[DEC_APPLIED] = quantise(levels, gp[G_CONT] != 0.0, dec[DEC_PCT])
    dec[DEC_ALARM] = 1.0 if (gs[GS_BREAK] != BREAK_NONE or gs[GS_REACTED] != 0.0
                             or gs[GS_HOLD] != HOLD_NONE or gs[GS_F_TRIPPED] != 0.0
                             or gs[GS_TOOL_BAD] != 0.0) else 0.0
    dec[DEC_STOP] = 1.0 if ((gs[GS_REACTED] != 0.0 and gp[G_REACTION] == REACTION_STOP)
                            or _hold_ignored(gp, gs)) else 0.0
    dec[DEC_ENGAGED] = gs[GS_ENGAGED]


@compiled
def gate_answer(gp: np.ndarray, gs: np.ndarray, levels: np.ndarray, t: float,
                dec: np.ndarray) -> None:
    """OverrideGate.answer: the decision answering the block that ends at ``t`` (the PMC's
    from the next block on); the block goes to the cut log, the rise limit takes its base."""
    gate_decide(gp, gs, levels, t, dec)
    applied = dec[DEC_APPLIED]
    force, event = gs[GS_BLOCK_F], gs[GS_BLOCK_EVENT]
    breakage = 1.0 if gs[GS_BREAK] != BREAK_NONE else 0.0
    if gs[GS_ENGAGED] != 0.0:
        _cut_push(gp, gs, t, force, gs[GS_APPLIED], gs[GS_REACH], event, breakage)
    else:
        _ring_put(gs, int(gp[G_RECENT_AT]), int(gp[G_DEBOUNCE]), GS_R_N, GS_R_NEXT, t,
                  force, gs[GS_APPLIED], gs[GS_REACH], event, breakage)
    gs[GS_APPLIED] = applied
    gs[GS_RAMP] = dec[DEC_PCT] if dec[DEC_SHAPED] != 0.0 else applied
    gs[GS_BLOCK_F], gs[GS_BLOCK_EVENT], gs[GS_REACH] = math.nan, 0.0, -1.0


@compiled
def gate_close(gp: np.ndarray, gs: np.ndarray, cut: np.ndarray) -> None:
    """OverrideGate.close: the session ends; the cut still open, if any, as an incomplete
    record (every block of it, the last ones included)."""
    if gs[GS_ENGAGED] != 0.0:
        at, cap = int(gp[G_PENDING_AT]), int(gp[G_PENDING_CAP])
        untapped = min(int(gp[G_DEBOUNCE]) - 1, int(gs[GS_P_N]))
        for age in range(untapped - 1, -1, -1):
            _cut_add(gp, gs, _ring_at(gs, at, cap, GS_P_NEXT, age))
        _cut_record(gp, gs, False, False, cut)
    gs[GS_ENGAGED] = 0.0


@entry('void(float64[::1], float64[::1], float64, float64, float64[::1], float64[::1])')
def gate_block(gp: Arr, gs: Arr, force: float, status: float, cut: Arr, started: Arr) -> None:
    """:func:`gate_on_estimate` from Python (:class:`turning_force.core.pmc.gate.OverrideGate`);
    started[0] 1 where a hold has just started."""
    started[0] = 1.0 if gate_on_estimate(gp, gs, force, int(status), cut) else 0.0


@entry('void(float64[::1], float64[::1], float64, float64)')
def gate_feed_block(gp: Arr, gs: Arr, feed_mm_min: float, rpm: float) -> None:
    """:func:`gate_feed` from Python (:class:`OverrideGate`)."""
    gate_feed(gp, gs, feed_mm_min, rpm)


@entry('void(float64[::1], float64[::1], float64[::1], float64, float64[::1], int64)')
def gate_step(gp: Arr, gs: Arr, levels: Arr, t: float, dec: Arr, answer: int) -> None:
    """From Python: :func:`gate_answer` (``answer`` 1) or :func:`gate_decide`."""
    if answer != 0:
        gate_answer(gp, gs, levels, t, dec)
    else:
        gate_decide(gp, gs, levels, t, dec)


@entry('void(float64[::1], float64[::1], float64, int64, float64[::1])')
def gate_control(gp: Arr, gs: Arr, t: float, what: int, cut: Arr) -> None:
    """From Python: arm at ``t`` (``what`` 0), start (1), close (2)."""
    if what == 0:
        gate_arm(gp, gs, t)
    elif what == 1:
        gs[GS_STARTED] = 1.0
        if gp[G_ARMED] != 0.0:
            gate_arm(gp, gs, t)
    else:
        gate_close(gp, gs, cut)


# --- for Python: the gate one block at a time (the bridge) ---------------------------------

def _state_flag(slot: int, doc: str) -> property:
    """A read-only flag of the gate's state: ``bool(state[slot])``."""
    return property(lambda gate: bool(gate._state[slot]), doc=doc)


class OverrideGate:
    """Decides the override written to the PMC from commands, force estimates and time.

    Its rules, and the shop floor's behaviours after them, are written once (``gate_*``
    above, compiled): this class holds their parameters and state, puts their codes into
    words, and turns a finished cut into a :class:`CutRecord` and a learning cut into a
    :class:`Learned` (the teach-in file stays the bridge's)."""

    def __init__(self, settings: BridgeSettings, t_s: float | None = None) -> None:
        activate()   # compiled, not interpreted, from the first block
        self.settings = settings
        self.table: OverrideTable = get_table(settings.override_table)
        self._params = _gate_params(settings, self.table)
        self._state = _gate_state(settings, self._params)
        self._levels = np.array(self.table.levels_pct, dtype=np.float64)
        self._dec = np.zeros(DEC_FIELDS)
        self._cut = np.zeros(CUT_FIELDS)
        self._started = np.zeros(1)
        self.inputs = NO_INPUTS
        self._cuts: list[CutRecord] = []
        self._learned: Learned | None = None
        self._tools = load_tools_file(settings.tools_file) if settings.tools_file else {}
        self.tool_table = _tool_table(settings, self._tools)
        if t_s is not None:
            self.start(t_s)

    armed = _state_flag(GS_ARMED, 'Whether the gate is armed.')
    started = _state_flag(GS_STARTED, 'Whether the gate has started (its first callback).')
    engaged = _state_flag(GS_ENGAGED, 'Whether the cut detector has the tool in the cut.')
    tool_unknown = _state_flag(GS_TOOL_BAD, 'Whether the tool in use has no section in the tools '
                               'file (the feed handed back).')
    feed_not_following = _state_flag(GS_F_TRIPPED, 'Whether the feed-follow check has stopped '
                                     'regulation (until re-armed).')

    def start(self, t_s: float) -> None:
        """Begin at ``t_s`` (armed if the settings say so). A node starts its gate at its first
        callback, when its clock runs: in a lock-step run sim time only starts then."""
        gate_control(self._params, self._state, float(t_s), 1, self._cut)

    def restart(self) -> None:
        """Not started: the next :meth:`start` begins again (a lifecycle node activated anew)."""
        self._state[GS_STARTED] = 0.0

    def reconfigure(self, settings: BridgeSettings, t_s: float) -> None:
        """New dynamic settings; arming through the settings clears an overload hold."""
        was_armed = self.settings.armed
        self.settings = settings   # first: re-arming judges the force by the new limit
        self._params = _gate_params(settings, self.table)
        self.tool_table = _tool_table(settings, self._tools)
        tool = float(self._state[GS_TOOL])
        if math.isfinite(tool):   # the tool in use keeps its section over the new settings
            gate_tool_change(self.tool_table, self._params, self._state, tool)
        if settings.armed and not was_armed:
            self.arm(t_s)
        elif not settings.armed:
            self.disarm()

    def arm(self, t_s: float) -> str:
        """Arm at ``t_s``; arming clears an overload hold, unless the last force estimate is
        still over the limit. Returns why the hold stays, or ''."""
        gate_control(self._params, self._state, float(t_s), 0, self._cut)
        return self._hold_text()

    def disarm(self) -> None:
        self._state[GS_ARMED] = 0.0

    def on_inputs(self, inputs: InputValues) -> None:
        """The machine's inputs as last read (program enable, threading, operator dial; the
        spindle speed is :meth:`on_feed`'s, and left out of the decisions, as FeedOverride
        leaves it out)."""
        self.inputs = dataclasses.replace(inputs, spindle_speed_rpm=None)
        dial = inputs.operator_dial_pct
        self._state[[GS_PE, GS_TH, GS_DIAL]] = (_flag(inputs.program_enable),
                                                _flag(inputs.threading),
                                                math.nan if dial is None else float(dial))
        if inputs.tool_number is not None and inputs.tool_number != self._state[GS_TOOL]:
            gate_tool_change(self.tool_table, self._params, self._state,
                             float(inputs.tool_number))

    @property
    def tool_number(self) -> int | None:
        """The tool in use, as the machine's tool input last said (None: not given)."""
        tool = float(self._state[GS_TOOL])
        return int(tool) if math.isfinite(tool) else None

    def on_feed(self, feed_rate_mm_min: float, spindle_speed_rpm: float = math.nan) -> None:
        """The axis feed rate the DAQ measured over the last block (its mean) [mm/min], and
        the spindle speed [rpm] (NaN: spindle_speed_rpm): :func:`gate_feed`."""
        gate_feed_block(self._params, self._state, float(feed_rate_mm_min),
                        float(spindle_speed_rpm))

    def on_command(self, requested_pct: float, t_s: float, reachable: bool | None = None) -> None:
        """The controller's request; ``reachable``, its flag, goes to the cut log."""
        self._state[[GS_REQ, GS_CMD_T, GS_REACH]] = (
            float(requested_pct), float(t_s), -1.0 if reachable is None else float(reachable))

    def on_estimate(self, force_n: float, status: int = OK) -> bool:
        """Take a force estimate; True when it has just started an overload hold.

        A saturated or non-finite force counts as over the limit. An invalid or stale estimate
        (it repeats the last good force) says nothing new and is not judged.
        """
        gate_block(self._params, self._state, float(force_n), float(int(status)), self._cut,
                   self._started)
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
        gate_control(self._params, self._state, 0.0, 2, self._cut)
        return self._collect()

    def arrays(self) -> tuple[FloatArray, FloatArray, FloatArray]:
        """(parameters, state, levels) of this gate now, as the compiled loops take them:
        copies, from which a loop goes on with the same decisions."""
        return self._params.copy(), self._state.copy(), self._levels.copy()

    def _step(self, t_s: float, answer: int) -> Decision:
        dec = self._dec
        gate_step(self._params, self._state, self._levels, float(t_s), dec, answer)
        applied = float(dec[DEC_APPLIED])
        code, bits = self.table.encode(applied)
        state = self._state
        return Decision(applied, float(state[GS_REQ]), code, bits, self.armed,
                        Reason(int(dec[DEC_REASON])), self._detail(dec), self.inputs,
                        bool(dec[DEC_ENGAGED]), bool(dec[DEC_ALARM]),
                        bool(dec[DEC_STOP]))

    def _collect(self) -> CutRecord | None:
        """A cut and a learning cut the last call finished, into the log and the lesson."""
        cut, state, s = self._cut, self._state, self.settings
        record = None
        if cut[CUT_READY] != 0.0:
            cut[CUT_READY] = 0.0
            record = cut_record(cut, s.tool)
            self._cuts.append(record)
        if state[GS_LEARNED] != 0.0:
            state[GS_LEARNED] = 0.0
            level = float(state[GS_L_LEVEL])
            taught = TaughtTool(level, s.teach_fraction, level * s.teach_fraction,
                                float(state[GS_L_PEAK]), float(state[GS_L_CUT_S]))
            self._learned = Learned(s.tool, taught, _refusal(
                int(state[GS_L_REFUSED]), s, level, float(state[GS_L_LOW])))
        return record

    def _hold_text(self) -> str:
        """Why the overload hold holds ('' where it does not)."""
        state = self._state
        code, force = int(state[GS_HOLD]), float(state[GS_HOLD_F])
        if code == HOLD_SATURATED:
            text = f'current sensor saturated (force {force:.0f} N or more)'
        elif code == HOLD_NONFINITE:
            text = f'force estimate {force!r} N is not finite'
        elif code == HOLD_ABOVE:
            text = (f'force {force:.0f} N above overload_force_n '
                    f'{float(state[GS_HOLD_LIMIT]):g} N')
        else:
            return ''
        if state[GS_HOLD_AGAIN]:
            text += '; re-armed while still over the limit'
        return text

    def _detail(self, dec: FloatArray) -> str:
        """The decision's one line, from its detail code and values."""
        s, state, table = self.settings, self._state, self.table
        code, a, b = int(dec[DEC_DCODE]), float(dec[DEC_DA]), float(dec[DEC_DB])
        requested = float(state[GS_REQ])
        again = '; re-arm to resume'
        if code == GD_HOLD:
            return self._hold_text() + self._ignored_text() + again
        texts = {
            GD_NONE: '',
            GD_DISARMED: ('not armed: programmed feed' if s.hand_back_pct >= 100.0
                          else f'not armed: the hand-back level ({s.hand_back_pct:g} %)'),
            GD_WAITING: 'armed, waiting for the first feed command',
            GD_NO_COMMAND: f'no feed command in {a:.3f} s since arming',
            GD_STALE: f'feed command {a:.3f} s old (watchdog {s.watchdog_period_s:g} s)',
            GD_NONFINITE: f'feed command {a!r} % is not finite',
            GD_RANGE: (f'feed command {a:.6g} % outside the {table.name} range '
                           f'[{table.min_pct:g}, {table.max_pct:g}] %'),
            GD_TEACH: f'teach-in: learning cut for {s.tool} at the programmed feed',
            GD_FLOOR: (f'request {requested:.4g} % raised to the feed floor '
                           f'({s.min_cut_override_pct:g} %) while cutting'),
            GD_AIR: (f'tool out of the cut or entering it: air-cut override '
                     f'{s.air_cut_override_pct:g} %'),
            GD_DIAL: (f"the operator's dial at {b:g} % "
                          f'({"times" if s.operator_dial == "product" else "below"} the '
                          f'request {requested:.4g} %)'),
            GD_RISE: f'rising at most {s.rise_rate_pct_s:g} %/s toward {requested:.4g} %',
            GD_TOOL: ((f'tool {self.tool_number} has no section in the tools file '
                       f'{s.tools_file}' if self.tool_number != NO_TOOL else
                       'the tool input reads no tool number (a BCD digit above 9)')
                      + ": not run on another tool's settings; feed handed back until a tool "
                      'with a section comes'),
        }
        if code == GD_BREAKAGE:
            text = self._breakage_text() + self._ignored_text() + again
        elif code == GD_REACTION_HOLD:
            text = self._reaction_text() + self._ignored_text() + again
        elif code == GD_STAND:
            text = _STAND_DOWNS[int(a)]
        elif code == GD_FOLLOW:
            text = self._follow_text() + again
        else:
            text = texts[code]
        dial = float(dec[DEC_DIALLED])
        if math.isfinite(dial):
            text += f"; the operator's dial at {dial:g} %"
        return text

    def _breakage_text(self) -> str:
        state = self._state
        force, level = float(state[GS_BREAK_F]), float(state[GS_BREAK_LEVEL])
        if state[GS_BREAK] == BREAK_SPIKE:
            return (f'tool breakage: force {force:.0f} N is {force / level - 1.0:.0%} above its '
                    f'recent level {level:.0f} N')
        return (f'tool breakage: force {force:.0f} N is {1.0 - force / level:.0%} below its '
                f'recent level {level:.0f} N while the program says the tool cuts')

    def _ignored_text(self) -> str:
        """A hold the axis does not obey, as the decision's detail says it ('' if obeyed)."""
        if not _hold_ignored(self._params, self._state):
            return ''
        return (f'; the axis does not stop (at {float(self._state[GS_F_ACTUAL]):.0f} % of the '
                'programmed feed, override cancel or a ladder that does not copy the '
                'override?): stop request set')

    def _follow_text(self) -> str:
        s, state = self.settings, self._state
        actual, edge = float(state[GS_F_ACTUAL]), float(state[GS_F_EDGE])
        return (f'the feed does not follow the override: the axis ran at {actual:.0f} % of the '
                f'programmed feed ({s.programmed_feed_mm_rev:g} mm/rev at '
                f'{float(state[GS_F_RPM]):.0f} rpm) where the override applied allows '
                f'{edge:.0f} +/- {s.feed_follow_tolerance_pct:g} %, for '
                f'{s.feed_follow_time_s:g} s (override cancel M49, feed hold, dry run, or a '
                'ladder that does not copy the override?): regulation stopped, feed handed back')

    def _reaction_text(self) -> str:
        s, state = self.settings, self._state
        limit, above = float(state[GS_REACT_LIM]), float(state[GS_REACT_ABOVE])
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


def cut_record(row: FloatArray, tool: str) -> CutRecord:
    """A cut the compiled gate recorded (``CUT_*``) as a :class:`CutRecord`; its tool the
    number the machine's tool input gave while it cut (``T2``), else ``tool``."""
    number = float(row[CUT_TOOL])
    return CutRecord(
        index=int(row[CUT_INDEX]), tool=f'T{number:.0f}' if math.isfinite(number) else tool,
        start_s=float(row[CUT_START]),
        end_s=float(row[CUT_END]), programmed_feed_s=float(row[CUT_FEED_S]),
        max_force_n=float(row[CUT_MAXF]), mean_force_n=float(row[CUT_MEANF]),
        min_override_pct=float(row[CUT_MINO]), overload_events=int(row[CUT_EVENTS]),
        breakage=bool(row[CUT_BREAK]), reachable_fraction=float(row[CUT_REACH]),
        learned=bool(row[CUT_LEARNED]), complete=bool(row[CUT_COMPLETE]))


def _flag(value: bool | None) -> float:
    return math.nan if value is None else float(bool(value))


def _refusal(code: int, s: BridgeSettings, level: float, low: float) -> str:
    """Why a learning cut was not learned ('' where it was)."""
    if code == LEARN_SHORT:
        return (f'the cut was not longer than twice cut_settle_s ({s.cut_settle_s:g} s): '
                'nothing settled to learn')
    if code == LEARN_FEED:
        return (f'the cut did not run at the programmed feed throughout (down to {low:g} %): '
                "its force is not the tool's level")
    if code == LEARN_UPSET:
        return 'the cut had an overload or a breakage: not a level to regulate to'
    if code == LEARN_HIGH:
        return (f'{s.teach_fraction:g} x {level:.0f} N is not below overload_force_n '
                f'({s.overload_force_n:g} N)')
    return ''


# The entry's rise is the force's least squares slope over this window [s]: short beside the
# slow cuts' tau_c (0.1-0.4 s) the hold waits out. A noise of sigma in the estimate moves the
# slope by sigma / sqrt(sum (j - mean j)^2) / T, about 11 sigma per s over 10 blocks; it can
# only end the hold sooner (the first slope under the limit ends it), back to cut_settle_s.
ENTRY_WINDOW_S = 0.1


def _gate_params(s: BridgeSettings, table: OverrideTable) -> FloatArray:
    """The compiled gate's parameters (``G_*``), the places of its rings among them."""
    period = s.control_period_s
    debounce = s.debounce_blocks(period)
    settle = math.ceil(s.cut_settle_s / period - 1e-9)
    window = max(1, round(s.breakage_window_s / period))
    p = np.zeros(G_SIZE)
    p[G_WATCHDOG], p[G_SAFE] = s.watchdog_period_s, s.safe_override_pct
    p[G_OVERLOAD], p[G_ARMED] = s.overload_force_n, s.armed
    p[G_CONT], p[G_MIN], p[G_MAX] = table.continuous, table.min_pct, table.max_pct
    p[G_PERIOD] = period
    p[G_ENGAGE], p[G_EXIT], p[G_DEBOUNCE] = s.engage_force_n, s.exit_force_n, debounce
    p[G_REACT_FRACTION] = s.reaction_force_fraction
    p[G_REACT_NEEDED] = math.ceil(s.reaction_delay_s / period - 1e-9)
    p[G_REACTION] = _REACTIONS[s.overload_reaction]
    p[G_SETTLE], p[G_WINDOW] = settle, window
    p[G_SPIKE], p[G_DROP] = s.breakage_spike_fraction, s.breakage_drop_fraction
    p[G_PE_REQUIRED], p[G_THREAD_SD] = s.program_enable_required, s.threading_stand_down
    p[G_DIAL_MODE] = _DIAL_MODES[s.operator_dial]
    p[G_RISE], p[G_FLOOR] = s.rise_rate_pct_s, s.min_cut_override_pct
    p[G_AIR], p[G_TEACH] = s.air_cut_override_pct, s.teach_in
    p[G_TEACH_FRACTION] = s.teach_fraction
    p[G_FOLLOW_S], p[G_FOLLOW_TOL] = s.feed_follow_time_s, s.feed_follow_tolerance_pct
    p[G_FOLLOW_LAG], p[G_FOLLOW_OVER] = s.feed_follow_lag_s, s.feed_follow_overshoot
    p[G_FEED_REV], p[G_RPM] = s.programmed_feed_mm_rev, s.spindle_speed_rpm
    p[G_HAND_BACK] = s.hand_back_pct
    p[G_RISE_LIMIT] = s.entry_rise_limit_per_s
    p[G_HOLD_MAX] = math.ceil(s.entry_hold_max_s / period - 1e-9)
    p[G_SLOPE_N] = max(2, round(ENTRY_WINDOW_S / period))
    p[G_RECENT_AT] = GS_FIXED
    p[G_PENDING_AT] = GS_FIXED + BLOCK_FIELDS * debounce
    p[G_PENDING_CAP] = debounce + settle
    p[G_WINDOW_AT] = p[G_PENDING_AT] + BLOCK_FIELDS * (debounce + settle)
    p[G_SLOPE_AT] = p[G_WINDOW_AT] + window
    return p


def _tool_table(s: BridgeSettings, tools: ToolSections) -> FloatArray:
    """Per tool of the tools file: its number, then its TOOL_GATE parameters (the bridge's
    settings with its section's :data:`~turning_force.core.tools.TOOL_BRIDGE_KEYS`)."""
    per_tool = tool_settings(s, tools, s.tools_file, TOOL_BRIDGE_KEYS)
    rows = [[number, *_gate_params(settings, get_table(s.override_table))[list(TOOL_GATE)]]
            for number, settings in per_tool.items()]
    return np.array(rows, dtype=np.float64).reshape(len(rows), 1 + len(TOOL_GATE))


def _gate_state(s: BridgeSettings, p: FloatArray) -> FloatArray:
    """The compiled gate's first state (``GS_*``, then its rings)."""
    state = np.zeros(int(p[G_SLOPE_AT] + p[G_SLOPE_N]))
    state[GS_REQ] = state[GS_BLOCK_F] = math.nan
    state[GS_CMD_T] = state[GS_ARMED_T] = -math.inf
    state[GS_LAST_STATUS] = OK
    state[GS_REACH] = -1.0
    state[GS_PE] = state[GS_TH] = state[GS_DIAL] = state[GS_TOOL] = math.nan
    state[GS_APPLIED] = state[GS_RAMP] = 100.0
    state[GS_F_HI] = state[GS_F_LO] = 100.0
    state[GS_LEARNING] = s.teach_in
    return state
