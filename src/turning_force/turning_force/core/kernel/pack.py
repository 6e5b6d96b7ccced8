"""The gate as the kernel's arrays: parameters and state, read from the live Python
:class:`OverrideGate`, so that a run can start in Python and go on in the kernel at any block
with the same numbers. Reading its private fields is deliberate: this module is the one place
that knows both sides, and the kernel-equals-reference tests hold it to them. (The estimator and
the controllers hold the kernel's arrays themselves.)"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from turning_force.core.kernel import jit as K
from turning_force.core.loop import ControlChain
from turning_force.core.overrides import OverrideTable
from turning_force.core.pmc import OverrideGate

__all__ = ['chain_arrays', 'gate_arrays', 'levels']

FloatArray = npt.NDArray[np.float64]


def levels(table: OverrideTable) -> FloatArray:
    return np.array(table.levels_pct, dtype=np.float64)


# --- gate -----------------------------------------------------------------------------------

_REACTIONS = {'alarm': K.REACTION_ALARM, 'stop': K.REACTION_STOP}   # 'hold' runs in Python


def gate_arrays(gate: OverrideGate) -> tuple[FloatArray, FloatArray, FloatArray]:
    """(params, state, levels) of the gate now."""
    s = gate.settings
    p = np.zeros(K.G_SIZE)
    p[K.G_WATCHDOG], p[K.G_SAFE] = s.watchdog_period_s, s.safe_override_pct
    p[K.G_OVERLOAD], p[K.G_ARMED] = s.overload_force_n, s.armed
    p[K.G_CONT] = gate.table.continuous
    shop = gate.shop
    p[K.G_ENGAGE], p[K.G_EXIT] = s.engage_force_n, s.exit_force_n
    p[K.G_DEBOUNCE], p[K.G_REACT_LIMIT] = shop._debounce, shop.reaction_limit_n
    p[K.G_REACT_NEEDED] = math.ceil(s.reaction_delay_s / shop.period_s - 1e-9)
    p[K.G_REACTION] = _REACTIONS.get(s.overload_reaction, K.REACTION_NONE)
    state = np.zeros(K.GS_SIZE)
    state[K.GS_ARMED], state[K.GS_STARTED] = gate.armed, gate.started
    state[K.GS_REQ], state[K.GS_CMD_T] = gate._requested, gate._command_t_s
    state[K.GS_ARMED_T], state[K.GS_HOLD] = gate._armed_t_s, bool(gate._overload)
    state[K.GS_LAST_F], state[K.GS_LAST_STATUS] = gate._last_force_n, int(gate._last_status)
    state[K.GS_ENGAGED], state[K.GS_RUN] = shop.engaged, shop._run
    state[K.GS_ABOVE], state[K.GS_REACTED] = shop._above, bool(shop._reaction)
    return p, state, levels(gate.table)


def chain_arrays(chain: ControlChain, dt_s: float) -> tuple[FloatArray, ...]:
    """(estimator params, state, controller params, state, levels, gate params, state, levels)
    of a chain of Python objects now, the estimator's filter set up for blocks sampled at
    ``dt_s`` (where that is a sample period). The estimator's and the controller's arrays are
    their own (live); the gate's are copies."""
    ep, es = chain.estimator.arrays_for(dt_s)
    cp, cs, clevels = chain.controller.arrays
    gp, gs, glevels = gate_arrays(chain.gate)
    return ep, es, cp, cs, clevels, gp, gs, glevels
