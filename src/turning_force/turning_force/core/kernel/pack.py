"""The reference objects as the kernel's arrays: parameters and state, read from the live
Python objects (the controllers,
:class:`OverrideGate`), so that a run can start in Python and go on in the kernel at any block
with the same numbers. Reading their private fields is deliberate: this module is the one
place that knows both sides, and the kernel-equals-reference tests hold it to them."""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from turning_force.core.control import (
    AdaptiveController,
    AdaptiveSlidingModeController,
    Controller,
    PIController,
    PolePlacementAdaptiveController,
    SlidingModeController,
)
from turning_force.core.control.smc import ENGAGED_FRACTION
from turning_force.core.control.staircase import StaircaseController
from turning_force.core.kernel import jit as K
from turning_force.core.loop import ControlChain
from turning_force.core.overrides import OverrideTable
from turning_force.core.pmc import OverrideGate

__all__ = ['chain_arrays', 'controller_params', 'controller_state', 'gate_arrays', 'levels']

FloatArray = npt.NDArray[np.float64]


def levels(table: OverrideTable) -> FloatArray:
    return np.array(table.levels_pct, dtype=np.float64)


# --- controllers ----------------------------------------------------------------------------

_KINDS: dict[type[Controller], int] = {
    SlidingModeController: K.SMC, AdaptiveController: K.ADAPTIVE,
    AdaptiveSlidingModeController: K.ASMC, PolePlacementAdaptiveController: K.POLE_PLACEMENT,
    PIController: K.PI, StaircaseController: K.STAIRCASE,
}
_SURFACES = {'park1998': K.PARK, 'integral': K.INTEGRAL, 'nonlinear': K.NONLINEAR}


def controller_params(controller: Controller) -> FloatArray:
    """A controller's parameters: its settings and what its reset derived from them."""
    c = controller.settings
    levels = c.staircase_levels_pct if isinstance(controller, StaircaseController) else ()
    p = np.zeros(K.C_SIZE + len(levels))
    p[K.C_KIND] = _KINDS[type(controller)]
    p[K.C_REF], p[K.C_PERIOD] = c.reference_force_n, c.control_period_s
    p[K.C_MIN], p[K.C_MAX], p[K.C_GAP] = (controller.min_pct, controller.max_pct,
                                          controller._max_gap_pct)
    p[K.C_EF] = c.quantiser == 'error_feedback'
    p[K.C_UNREACH], p[K.C_FEED_RATE] = c.unreachable_after_s, c.programmed_feed_rate_mm_min
    p[K.C_CONT] = controller._table.continuous
    if isinstance(controller, SlidingModeController):
        p[K.C_LAM], p[K.C_ETA], p[K.C_EPS] = c.smc_lambda_per_s, c.smc_eta, c.smc_epsilon_n
        p[K.C_KSD_MIN], p[K.C_KSD_MAX] = c.smc_ksd_min_n_mm, c.smc_ksd_max_n_mm
        p[K.C_SURFACE] = _SURFACES[c.smc_surface]
        p[K.C_FAR], p[K.C_NEAR] = c.smc_damping_far, c.smc_damping_near
        p[K.C_ESCALE], p[K.C_RPM] = c.smc_damping_error_n, c.spindle_speed_rpm
        p[K.C_TAU_C], p[K.C_DTAU] = c.model_cutting_time_constant_s, controller._design_tau_s
        p[K.C_ENGAGED] = ENGAGED_FRACTION
        predictor = controller._predictor
        if predictor is not None:
            p[K.C_PRED] = 1.0
            for model, nx, phi, gamma in ((predictor.machine, K.C_MNX, K.C_MPHI, K.C_MGAM),
                                          (predictor.design, K.C_DNX, K.C_DPHI, K.C_DGAM)):
                size = len(model.x)
                p[nx] = size
                for i in range(size):
                    p[phi + 3 * i:phi + 3 * i + size] = model.phi[i]
                p[gamma:gamma + size] = model.gamma
            if predictor.design.queue:
                raise ValueError('the design model has a dead time: not one the kernel runs')
            p[K.C_QLEN] = len(predictor.machine.queue)
            p[K.C_STEPS], p[K.C_WEIGHT] = predictor.steps, predictor.weight
            p[K.C_GAIN0] = predictor.initial_gain_n_per_pct
            p[K.C_MTAU_C] = predictor.machine.tau_c
    elif isinstance(controller, AdaptiveController):
        p[K.C_MODEL_TAU] = c.model_servo_time_constant_s
        p[K.C_LOOP_GAIN] = c.adaptive_loop_gain_per_s
        p[K.C_EST_TAU] = c.adaptive_estimate_time_constant_s
    elif isinstance(controller, AdaptiveSlidingModeController | PolePlacementAdaptiveController):
        rls = controller.rls
        p[K.C_THETA0:K.C_THETA0 + 4] = rls._theta0
        p[K.C_P0], p[K.C_ST], p[K.C_FMIN] = rls._p0, rls._s_t, rls._f_min
        p[K.C_DEADZONE], p[K.C_RESET_TRACE] = rls._dead_zone, rls._reset_trace
        p[K.C_ACCEPT] = rls._accept is not None
        p[K.C_POLE], p[K.C_BMIN], p[K.C_FREEZE] = c.asmc_pole, c.asmc_b_min, c.asmc_freeze_limit
        p[K.C_PP_W], p[K.C_PP_Z] = c.pp_natural_freq_rad_s, c.pp_damping
    elif isinstance(controller, PIController):
        p[K.C_KP], p[K.C_KI] = c.pi_kp_pct_per_n, c.pi_ki_pct_per_n_s
    else:   # the staircase (StaircaseController.level_index)
        p[K.C_SC_PER] = max(round(c.staircase_step_s / c.control_period_s), 1)
        p[K.C_SC_N] = len(levels)
        p[K.C_SC_LEVELS:] = levels
    return p


def controller_state(controller: Controller) -> FloatArray:
    """A controller's state now."""
    queue: list[float] = []
    if isinstance(controller, SlidingModeController) and controller._predictor is not None:
        queue = list(controller._predictor.machine.queue)   # oldest first
    s = np.zeros(K.CS_QUEUE + len(queue))
    s[K.CS_HELD], s[K.CS_CARRY] = controller._held_pct, controller._carry_pct
    s[K.CS_PINNED], s[K.CS_RESETS] = controller._pinned_s, controller.resets
    s[K.CS_SIDE] = controller._pinned_side
    if isinstance(controller, SlidingModeController):
        s[K.CS_INT] = controller._error_integral_n_s
        predictor = controller._predictor
        if predictor is not None:
            s[K.CS_PGAIN] = predictor.gain_n_per_pct
            s[K.CS_MX:K.CS_MX + len(predictor.machine.x)] = predictor.machine.x
            s[K.CS_DX:K.CS_DX + len(predictor.design.x)] = predictor.design.x
            s[K.CS_QIDX] = 0.0     # the list's oldest entry first
            s[K.CS_QUEUE:] = queue
    elif isinstance(controller, AdaptiveController):
        s[K.CS_AD_CMD], s[K.CS_AD_MODEL] = controller._pct_cmd, controller._feed_model_pct
        s[K.CS_AD_GAIN] = controller._gain_n_per_pct
    elif isinstance(controller, AdaptiveSlidingModeController | PolePlacementAdaptiveController):
        rls = controller.rls
        s[K.CS_THETA:K.CS_THETA + 4] = rls.theta
        s[K.CS_P:K.CS_P + 16] = np.asarray(rls.p).ravel()
        s[K.CS_F], s[K.CS_RLS_RESTARTS] = rls.forgetting_factor, rls.restarts
        s[K.CS_Y:K.CS_Y + 2] = controller._y
        s[K.CS_U:K.CS_U + 2] = controller._u
        if isinstance(controller, AdaptiveSlidingModeController):
            s[K.CS_STARTED], s[K.CS_SLIDING] = controller._started, controller._sliding
        else:
            s[K.CS_DU] = controller._du
    elif isinstance(controller, PIController):
        s[K.CS_PI_INT] = controller._integral_pct
    elif isinstance(controller, StaircaseController):
        s[K.CS_SC_COMMANDS] = controller._commands
    return s


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
    ``dt_s`` (where that is a sample period). The estimator's arrays are its own (live); the
    rest are copies."""
    ep, es = chain.estimator.arrays_for(dt_s)
    controller = chain.controller
    gp, gs, glevels = gate_arrays(chain.gate)
    return (ep, es, controller_params(controller), controller_state(controller),
            levels(controller._table), gp, gs, glevels)
