"""The compiled loops that run the signal chain: :func:`chain_step` (one block: the machine's
inputs, the estimator, the controller, the gate), :func:`run_core` (the closed loop on the
simulated lathe), :func:`run_core_kept` (the same, keeping every block for ``run --core --out``)
and :func:`replay_blocks` (open loop over recorded currents). Each stage's algorithm is its own
module's (:mod:`turning_force.core.plant.lathe`, :mod:`turning_force.core.estimation.estimator`,
:mod:`turning_force.core.control.update`, :mod:`turning_force.core.pmc.gate`); the loops only call
them, in the graph's order.

Entry points have explicit signatures: each is compiled for it (or loaded from the cache,
``cache=True``, in :func:`turning_force.core.kernel.cache_dir`) at its first call.
"""

from __future__ import annotations

import math

import numpy as np

from turning_force.core.compiled import (
    Arr,
    compiled,
    entry,
)
from turning_force.core.control.drift import DS_ADOPTED, DS_ADOPTED_SIZE, drift_correction
from turning_force.core.control.law import (
    C_REF,
    CS_DRIFT,
    CS_LAW,
    OUT_DRIFT,
    OUT_DRIFT_SIZE,
    OUT_ERR,
    OUT_OSC,
    OUT_PCT,
    OUT_REACH,
    OUT_S,
    OUT_SIZE,
    spindle_speed,
)
from turning_force.core.control.update import (
    controller_applied,
    controller_feed,
    controller_rezeroed,
    controller_tool,
    controller_update,
)
from turning_force.core.estimation.estimator import (
    D_REZEROED,
    ES_DCODE,
    ES_DVAL,
    ES_F,
    ES_FEED,
    ES_IFR,
    ES_IQ,
    ES_R,
    ES_STATUS,
    OK,
    SATURATED,
    estimator_correct,
    estimator_update,
)
from turning_force.core.plant.lathe import P_DT, P_N, P_SPEED_WIRED, TRUTH_ROWS, plant_step
from turning_force.core.pmc.gate import (
    CUT_FIELDS,
    CUT_READY,
    DEC_ALARM,
    DEC_APPLIED,
    DEC_ENGAGED,
    DEC_FIELDS,
    DEC_REASON,
    DEC_STOP,
    G_TEACH_FRACTION,
    GS_ARMED,
    GS_L_LEVEL,
    GS_L_REFUSED,
    GS_LEARNED,
    GS_REQ,
    GS_TOOL,
    LEARN_OK,
    gate_answer,
    gate_arm,
    gate_feed,
    gate_inputs,
    gate_on_command,
    gate_on_estimate,
    gate_tool,
)

# --- chain rows (core/batch.py ChainTrace): the estimate, the command (CH_ACTED 0: silent),
# the decision and the gate's outputs, one row per block
CH_FORCE, CH_RATE, CH_IQ, CH_IFR, CH_STATUS, CH_ACTED, CH_REQ, CH_S, CH_REACH = range(9)
CH_REF, CH_APPLIED, CH_REASON, CH_ARMED, CH_GATE_REQ, CH_ENGAGED, CH_ALARM = range(9, 16)
CH_STOP, CH_ERR, CH_DCODE, CH_DVAL = 16, 17, 18, 19   # the estimate's detail: code, 2 values
CH_FEED = 21   # the block's mean axis feed (the estimate's)
CHAIN_COLUMNS = 22


@compiled
def chain_step(ep: np.ndarray, es: np.ndarray, cp: np.ndarray, cs: np.ndarray,
               clevels: np.ndarray, gp: np.ndarray, gs: np.ndarray, glevels: np.ndarray,
               ctools: np.ndarray, gtools: np.ndarray, t0: float, dt: float, u: np.ndarray,
               v: np.ndarray, angle: np.ndarray, feed: np.ndarray, work: np.ndarray,
               inputs: np.ndarray, out: np.ndarray, dec: np.ndarray, cut: np.ndarray,
               cuts: np.ndarray, ncuts: np.ndarray) -> bool:
    """One block through the chain (:class:`turning_force.core.kernel.chain.ControlChain` states
    it): the machine's inputs (PE, threading, dial, spindle speed, tool: ``inputs`` (5,), NaN
    where not given; a new tool number selects its rows of the tool tables ``gtools``, the
    gate's, and ``ctools``, the controller's, :mod:`turning_force.core.tools`) -> estimator ->
    gate.on_estimate, gate.on_feed (the axis feed against the override) -> controller (at the
    spindle speed; the friction its drift monitor read in the cut to the estimator,
    :func:`~turning_force.core.estimation.estimator.estimator_correct`) -> gate.on_command ->
    gate.answer (DEC_* into ``dec``) -> the controller told the override applied (its
    anti-windup,
    :func:`~turning_force.core.control.update.controller_applied`: out of the cut, or where the
    gate held or shaped the request); a learning cut that has just been learned sets the
    controller's reference from the next block on; a cut that ended goes to ``cuts`` (row
    ncuts[0], while there is room; ncuts[0] counts them all). Returns whether the controller
    acted (``out`` its command)."""
    t_end = t0 + u.size * dt
    gate_inputs(gs, inputs[0], inputs[1], inputs[2])
    tool = inputs[4]
    if tool == tool and tool != gs[GS_TOOL] and gate_tool(gtools, gp, gs, tool) >= 0:
        controller_tool(ctools, cp, cs, tool)
    status = estimator_update(ep, es, t0, dt, u, v, angle, feed, work)
    if es[ES_DCODE] == D_REZEROED:   # the friction measured in air: the drift monitor's
        controller_rezeroed(cp, cs, es[ES_DVAL])
    force, rate = es[ES_F], es[ES_R]
    gate_on_estimate(gp, gs, force, status, cut)
    gate_feed(gp, gs, np.mean(feed), inputs[3])
    spindle_speed(cp, inputs[3])
    acted = (status == OK or status == SATURATED) and math.isfinite(force)  # noqa: SIM109
    if acted:
        controller_feed(cp, cs, es[ES_FEED])
        controller_update(cp, cs, clevels, force, rate, out)
        gate_on_command(gs, out[OUT_PCT], t_end, out[OUT_REACH])
        # a friction drift the drift monitor read in the cut: the estimator takes it off
        # from the next block on (this block's detail says so)
        offset = drift_correction(cs[CS_DRIFT:CS_LAW])
        if offset != 0.0:
            estimator_correct(ep, es, offset)
    gate_answer(gp, gs, glevels, t_end, dec)
    controller_applied(cp, cs, dec[DEC_APPLIED], dec[DEC_ENGAGED] != 0.0, int(dec[DEC_REASON]))
    if gs[GS_LEARNED] != 0.0:
        gs[GS_LEARNED] = 0.0
        if gs[GS_L_REFUSED] == LEARN_OK:
            cp[C_REF] = gs[GS_L_LEVEL] * gp[G_TEACH_FRACTION]
    if cut[CUT_READY] != 0.0:
        cut[CUT_READY] = 0.0
        i = int(ncuts[0])
        if i < cuts.shape[0]:
            for j in range(CUT_FIELDS):
                cuts[i, j] = cut[j]
        ncuts[0] = i + 1
    return acted


@compiled
def _trace_row(trace: np.ndarray, k: int, t_end: float, truth: np.ndarray, n: int,
               es: np.ndarray, cp: np.ndarray, cs: np.ndarray, last: np.ndarray,
               applied: float, reason: float) -> None:
    """Row k of the core loop's trace (core/simulate.py TRACE_NAMES); the controller's state
    ``cs`` gives the model its law predicts with (the drift monitor's, .control.drift)."""
    trace[k, 0], trace[k, 1], trace[k, 2] = t_end, truth[0, n - 1], es[ES_F]
    trace[k, 3], trace[k, 4], trace[k, 5] = es[ES_R], cp[C_REF], truth[1, n - 1]
    trace[k, 6], trace[k, 7], trace[k, 8] = truth[2, n - 1], last[0], applied
    trace[k, 9], trace[k, 10], trace[k, 11] = last[1], last[2], last[3]
    trace[k, 12], trace[k, 13] = truth[3, n - 1], reason
    trace[k, 14], trace[k, 15] = last[4], last[5]
    trace[k, 16] = cs[CS_DRIFT + DS_ADOPTED]
    trace[k, 17] = cs[CS_DRIFT + DS_ADOPTED_SIZE]


@compiled
def _chain_row(rows: np.ndarray, k: int, es: np.ndarray, acted: bool, out: np.ndarray,
               cp: np.ndarray, gs: np.ndarray, dec: np.ndarray) -> None:
    """Row k of the chain's rows (CH_*): the estimate, the command (where ``acted``), the
    decision and the gate's outputs."""
    rows[k, CH_FORCE], rows[k, CH_RATE] = es[ES_F], es[ES_R]
    rows[k, CH_IQ], rows[k, CH_IFR], rows[k, CH_STATUS] = es[ES_IQ], es[ES_IFR], es[ES_STATUS]
    rows[k, CH_ACTED] = 1.0 if acted else 0.0
    rows[k, CH_REQ], rows[k, CH_S], rows[k, CH_REACH] = out[OUT_PCT], out[OUT_S], out[OUT_REACH]
    rows[k, CH_ERR] = out[OUT_ERR]
    rows[k, CH_DCODE], rows[k, CH_DVAL], rows[k, CH_DVAL + 1] = (es[ES_DCODE], es[ES_DVAL],
                                                                 es[ES_DVAL + 1])
    rows[k, CH_REF] = cp[C_REF]
    rows[k, CH_FEED] = es[ES_FEED]
    rows[k, CH_APPLIED], rows[k, CH_REASON] = dec[DEC_APPLIED], dec[DEC_REASON]
    rows[k, CH_ARMED], rows[k, CH_GATE_REQ] = gs[GS_ARMED], gs[GS_REQ]
    rows[k, CH_ENGAGED], rows[k, CH_ALARM], rows[k, CH_STOP] = (dec[DEC_ENGAGED],
                                                                dec[DEC_ALARM], dec[DEC_STOP])


@compiled
def _closed_loop(pp: Arr, ps: Arr, times: Arr, depths: Arr, noise_u: Arr, noise_v: Arr,
                 noise_f: Arr, noise_fr: Arr, ep: Arr, es: Arr, cp: Arr, cs: Arr, clevels: Arr,
                 gp: Arr, gs: Arr, glevels: Arr, ctools: Arr, gtools: Arr, k0: int, k1: int,
                 applied: float, last: Arr,
                 trace: Arr, inputs: Arr, cuts: Arr, ncuts: Arr, keep: bool, t0s: Arr, u: Arr,
                 v: Arr, angle: Arr, feed_rate: Arr, rows: Arr) -> float:
    """The closed loop, the one the core loop and the recorded core run share: blocks k0 ..
    k1 - 1, the plant then :func:`chain_step`, trace rows k0 .. k1 - 1; noise arrays start at
    block k0, ``inputs`` (n, 5) at block 0 (where the plant's spindle speed input is wired, its
    column 3 is written from the plant's speed block by block). ``last`` is the command that
    stands (pct, sliding, reachable, oscillating, drift, drift's size). Where ``keep``, every
    block as well: its first stamp into t0s[k], its samples into row k of u, v, angle and
    feed_rate, the chain's row (CH_*) into rows[k]. Returns the override applied to the next
    block."""
    n = int(pp[P_N])
    dt = pp[P_DT]
    uk, vk, ak, fk = np.empty(n), np.empty(n), np.empty(n), np.empty(n)
    work = np.empty(2 * n)
    truth = np.empty((TRUTH_ROWS, n))
    out = np.full(OUT_SIZE, math.nan)
    dec = np.empty(DEC_FIELDS)
    cut = np.zeros(CUT_FIELDS)
    for k in range(k0, k1):
        lo = (k - k0) * n
        if keep:
            uk, vk, ak, fk = u[k], v[k], angle[k], feed_rate[k]
        t0 = plant_step(pp, ps, times, depths, applied, noise_u, noise_v, noise_f, noise_fr,
                        lo, uk, vk, ak, fk, truth)
        if pp[P_SPEED_WIRED] != 0.0:   # the spindle encoder's speed at the block's end
            inputs[k, 3] = truth[3, n - 1]
        acted = chain_step(ep, es, cp, cs, clevels, gp, gs, glevels, ctools, gtools, t0, dt, uk,
                           vk, ak, fk, work, inputs[k], out, dec, cut, cuts, ncuts)
        if acted:
            last[0], last[1], last[2], last[3] = (out[OUT_PCT], out[OUT_S], out[OUT_REACH],
                                                  out[OUT_OSC])
            last[4], last[5] = out[OUT_DRIFT], out[OUT_DRIFT_SIZE]
        if keep:
            t0s[k] = t0
            _chain_row(rows, k, es, acted, out, cp, gs, dec)
        _trace_row(trace, k, t0 + n * dt, truth, n, es, cp, cs, last, applied,
                   dec[DEC_REASON])
        applied = dec[DEC_APPLIED]
    return applied


@entry('float64(float64[::1], float64[::1], float64[::1], float64[::1], float64[::1], '
       'float64[::1], float64[::1], float64[::1], float64[::1], float64[::1], float64[::1], '
       'float64[::1], float64[::1], float64[::1], float64[::1], float64[::1], '
       'float64[:, ::1], float64[:, ::1], int64, int64, '
       'float64, float64[::1], float64[:, ::1], float64[:, ::1], float64[:, ::1], '
       'float64[::1])')
def run_core(pp: Arr, ps: Arr, times: Arr, depths: Arr, noise_u: Arr, noise_v: Arr,
             noise_f: Arr, noise_fr: Arr, ep: Arr, es: Arr, cp: Arr, cs: Arr, clevels: Arr,
             gp: Arr, gs: Arr, glevels: Arr, ctools: Arr, gtools: Arr, k0: int, k1: int,
             applied: float, last: Arr, trace: Arr, inputs: Arr, cuts: Arr,
             ncuts: Arr) -> float:
    """:func:`_closed_loop`, keeping the trace only (the core loop)."""
    nothing = np.empty((0, 0))
    return _closed_loop(pp, ps, times, depths, noise_u, noise_v, noise_f, noise_fr, ep, es, cp,
                        cs, clevels, gp, gs, glevels, ctools, gtools, k0, k1, applied, last,
                        trace, inputs, cuts, ncuts, False, np.empty(0), nothing, nothing,
                        nothing, nothing, nothing)


@entry('float64(float64[::1], float64[::1], float64[::1], float64[::1], float64[::1], '
       'float64[::1], float64[::1], float64[::1], float64[::1], float64[::1], float64[::1], '
       'float64[::1], float64[::1], float64[::1], float64[::1], float64[::1], '
       'float64[:, ::1], float64[:, ::1], int64, int64, '
       'float64, float64[::1], float64[:, ::1], float64[:, ::1], float64[:, ::1], '
       'float64[::1], float64[::1], float64[:, ::1], float64[:, ::1], float64[:, ::1], '
       'float64[:, ::1], float64[:, ::1])')
def run_core_kept(pp: Arr, ps: Arr, times: Arr, depths: Arr, noise_u: Arr, noise_v: Arr,
                  noise_f: Arr, noise_fr: Arr, ep: Arr, es: Arr, cp: Arr, cs: Arr,
                  clevels: Arr, gp: Arr, gs: Arr, glevels: Arr, ctools: Arr, gtools: Arr,
                  k0: int, k1: int, applied: float, last: Arr, trace: Arr, inputs: Arr,
                  cuts: Arr, ncuts: Arr, t0s: Arr, u: Arr, v: Arr, angle: Arr, feed_rate: Arr,
                  rows: Arr) -> float:
    """:func:`_closed_loop`, keeping every block (``run --core --out``)."""
    return _closed_loop(pp, ps, times, depths, noise_u, noise_v, noise_f, noise_fr, ep, es, cp,
                        cs, clevels, gp, gs, glevels, ctools, gtools, k0, k1, applied, last,
                        trace, inputs, cuts, ncuts, True, t0s, u, v, angle, feed_rate, rows)


@entry('int64(float64[::1], float64[::1], float64[::1], float64[::1], float64[::1], '
       'float64[::1], float64[::1], float64[::1], float64[:, ::1], float64[:, ::1], '
       'float64[::1], float64, float64[:, ::1], '
       'float64[:, ::1], float64[:, ::1], float64[:, ::1], float64[::1], float64[::1], int64, '
       'float64[:, ::1], float64[:, ::1], float64[:, ::1], float64[::1])')
def replay_blocks(ep: Arr, es: Arr, cp: Arr, cs: Arr, clevels: Arr, gp: Arr, gs: Arr,
                  glevels: Arr, ctools: Arr, gtools: Arr, t0s: Arr, dt: float, u: Arr, v: Arr,
                  angle: Arr, feed: Arr,
                  arm_times: Arr, arm_states: Arr, change: int, rows: Arr, inputs: Arr,
                  cuts: Arr, ncuts: Arr) -> int:
    """Replay (session/replay.py): blocks of recorded currents (n, m) through
    :func:`chain_step`, open loop, each decision at the block's end, with the machine's
    recorded inputs (n, 5); before each block, the gate armed (at the change's time) or
    disarmed for every change (arm_times, arm_states 1/0, in order, from index ``change`` on)
    up to the block's end. The chain's rows (CH_*) into rows; returns the index of the first
    change not made (where the next stretch of blocks goes on)."""
    n, m = u.shape
    work = np.empty(2 * m)
    out = np.full(OUT_SIZE, math.nan)
    dec = np.empty(DEC_FIELDS)
    cut = np.zeros(CUT_FIELDS)
    for k in range(n):
        t0 = t0s[k]
        t_end = t0 + m * dt
        while change < arm_times.size and arm_times[change] <= t_end:
            if arm_states[change] != 0.0 and gs[GS_ARMED] == 0.0:
                gate_arm(gp, gs, arm_times[change])
            elif arm_states[change] == 0.0 and gs[GS_ARMED] != 0.0:
                gs[GS_ARMED] = 0.0
            change += 1
        acted = chain_step(ep, es, cp, cs, clevels, gp, gs, glevels, ctools, gtools, t0, dt,
                           u[k], v[k], angle[k], feed[k], work, inputs[k], out, dec, cut, cuts,
                           ncuts)
        _chain_row(rows, k, es, acted, out, cp, gs, dec)
    return change
