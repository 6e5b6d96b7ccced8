"""The control laws, compiled: each law's function, the Smith predictor's models, the
recursive least squares, and what every law shares (the guard on its state, the
error-feedback quantiser, the reachability flag), in ``controller_update``.

Each law's module in this package states the law and reads its settings into these
functions' parameters (``C_*``); :class:`turning_force.core.control.base.Controller` holds the
parameters and the state (``CS_*``) and runs them one period at a time, the compiled loops
(:mod:`turning_force.core.kernel.loops`) many periods at once.
"""

from __future__ import annotations

import math

import numpy as np

from turning_force.core.compiled import Arr, compiled, delayed, entry, pymax, pymin, quantise

# --- controller parameters ------------------------------------------------------------------
C_KIND, C_REF, C_PERIOD, C_MIN, C_MAX, C_GAP, C_EF, C_UNREACH, C_FEED_RATE = range(9)
C_CONT = 9
# smc
C_LAM, C_ETA, C_EPS, C_KSD_MIN, C_KSD_MAX, C_SURFACE, C_FAR, C_NEAR, C_ESCALE = range(10, 19)
C_RPM, C_TAU_C, C_DTAU, C_PRED, C_ENGAGED = range(19, 24)
C_MNX, C_MPHI, C_MGAM = 24, 25, 34            # machine model: phi 3x3, gamma 3
C_DNX, C_DPHI, C_DGAM = 37, 38, 47            # design model
C_QLEN, C_STEPS, C_WEIGHT, C_GAIN0, C_MTAU_C = range(50, 55)
# adaptive
C_MODEL_TAU, C_LOOP_GAIN, C_EST_TAU = range(55, 58)
# RLS (adaptive_smc, adaptive_pp)
C_THETA0, C_P0, C_ST, C_FMIN, C_DEADZONE, C_RESET_TRACE, C_ACCEPT = 58, 62, 63, 64, 65, 66, 67
C_POLE, C_BMIN, C_FREEZE = range(68, 71)      # adaptive_smc
C_PP_W, C_PP_Z = 71, 72                       # adaptive_pp
C_KP, C_KI = 73, 74                           # pi
C_SC_PER, C_SC_N = 75, 76                     # staircase: periods a level, levels
C_BALANCE = 77                                # smc: the automatic layer's balance factor
C_SC_LEVELS = 78                              # staircase: the levels, from here on
C_SIZE = 78
SMC, ADAPTIVE, ASMC, POLE_PLACEMENT, PI, STAIRCASE = range(6)
PARK, INTEGRAL, NONLINEAR = range(3)
# controller state
CS_HELD, CS_CARRY, CS_PINNED, CS_RESETS = range(4)
# smc: integral, predictor gain, machine x (3), design x (3), queue index
CS_INT, CS_PGAIN, CS_MX, CS_DX, CS_QIDX = 4, 5, 6, 9, 12
# pi / adaptive
CS_PI_INT = 4
CS_AD_CMD, CS_AD_MODEL, CS_AD_GAIN = 4, 5, 6
# RLS laws: theta (4), P (16), forgetting factor, restarts; y (2), u (2), extras
CS_THETA, CS_P, CS_F, CS_RLS_RESTARTS, CS_Y, CS_U = 4, 8, 24, 25, 26, 28
CS_STARTED, CS_SLIDING, CS_DU = 30, 31, 30
CS_SC_COMMANDS = 4                            # staircase: commands asked for so far
CS_SIDE = 32                                  # reachability: 1 held at the top, -1 bottom
CS_QUEUE = 33                                 # then the smc predictor's queue
OUT_PCT, OUT_ERR, OUT_S, OUT_REACH = range(4)


# --- the controllers (core/control) ---------------------------------------------------------

@compiled
def _clip(cp: np.ndarray, pct: float) -> float:
    return pymin(pymax(pct, cp[C_MIN]), cp[C_MAX])


@compiled
def _pct(cp: np.ndarray, feed_rate: float) -> float:
    return 100.0 * feed_rate / cp[C_FEED_RATE]


@compiled
def _feed_rate(cp: np.ndarray, pct: float) -> float:
    return pct / 100.0 * cp[C_FEED_RATE]


@compiled
def _model_reset(cs: np.ndarray, x: int, nx: int, held: float) -> None:
    for i in range(3):
        cs[x + i] = 0.0
    cs[x] = held
    cs[x + nx - 1] = held


@compiled
def _model_advance(cp: np.ndarray, cs: np.ndarray, x: int, nx: int, phi: int, gamma: int,
                   servo_in: float) -> None:
    """The predictor's model (:func:`..control.predictor.model_matrices`), one step:
    x = phi x + gamma u (each row summed in order)."""
    x0, x1, x2 = cs[x], cs[x + 1], cs[x + 2]
    for i in range(nx):
        row = phi + 3 * i
        total = cp[row] * x0
        total = total + cp[row + 1] * x1
        if nx == 3:
            total = total + cp[row + 2] * x2
        cs[x + i] = total + cp[gamma + i] * servo_in


@compiled
def _rls_restart(cp: np.ndarray, cs: np.ndarray) -> None:
    for i in range(4):
        cs[CS_THETA + i] = cp[C_THETA0 + i]
        for j in range(4):
            cs[CS_P + 4 * i + j] = cp[C_P0] if i == j else 0.0
    cs[CS_F] = 1.0


@compiled
def _rls_update(cp: np.ndarray, cs: np.ndarray, x0: float, x1: float, x2: float, x3: float,
                y: float) -> None:
    """Recursive least squares, four parameters (:mod:`..control.rls` states it: Hwang & Chen
    Eqs. 33-39, Kim Eq. 15)."""
    x = np.array((x0, x1, x2, x3))
    if not (math.isfinite(y) and math.isfinite(x0) and math.isfinite(x1)
            and math.isfinite(x2) and math.isfinite(x3)):
        cs[CS_RLS_RESTARTS] += 1.0
        _rls_restart(cp, cs)
        return
    total = x[0] * cs[CS_THETA]
    for i in range(1, 4):
        total = total + x[i] * cs[CS_THETA + i]
    error = y - total
    if abs(error) <= cp[C_DEADZONE]:
        return
    p_phi = np.empty(4)
    for i in range(4):
        total = cs[CS_P + 4 * i] * x[0]
        for j in range(1, 4):
            total = total + cs[CS_P + 4 * i + j] * x[j]
        p_phi[i] = total
    total = x[0] * p_phi[0]
    for i in range(1, 4):
        total = total + x[i] * p_phi[i]
    denominator = 1.0 + total
    gain = np.empty(4)
    theta = np.empty(4)
    finite = True
    for i in range(4):
        gain[i] = p_phi[i] / denominator
        theta[i] = cs[CS_THETA + i] + gain[i] * error
        finite = finite and math.isfinite(theta[i])
    if finite and cp[C_ACCEPT] != 0.0 \
            and not (theta[2] + theta[3] > 0.0 and 1.0 + theta[0] + theta[1] > 0.0):
        return
    f = 1.0
    if cp[C_ST] > 0:
        total = x[0] * gain[0]
        for i in range(1, 4):
            total = total + x[i] * gain[i]
        f = pymax(1.0 - (1.0 - total) * (error * error) / cp[C_ST], cp[C_FMIN])
    p = np.empty(16)
    for i in range(4):
        for j in range(4):
            total = (gain[i] * x[0]) * cs[CS_P + j]
            for k in range(1, 4):
                total = total + (gain[i] * x[k]) * cs[CS_P + 4 * k + j]
            p[4 * i + j] = (cs[CS_P + 4 * i + j] - total) / f
            finite = finite and math.isfinite(p[4 * i + j])
    if not finite:
        cs[CS_RLS_RESTARTS] += 1.0
        _rls_restart(cp, cs)
        return
    for i in range(4):
        cs[CS_THETA + i] = theta[i]
    trace = 0.0
    for i in range(16):
        cs[CS_P + i] = p[i]
    for i in range(4):
        trace = trace + p[5 * i]
    cs[CS_F] = f
    if cp[C_RESET_TRACE] > 0 and trace < cp[C_RESET_TRACE]:
        for i in range(4):
            for j in range(4):
                cs[CS_P + 4 * i + j] = cp[C_P0] if i == j else 0.0


@compiled
def controller_reset(cp: np.ndarray, cs: np.ndarray) -> None:
    """Each law's fresh state (a new cut, or state that went non-finite), from the held
    request."""
    kind = int(cp[C_KIND])
    held = cs[CS_HELD]
    if kind == SMC:
        cs[CS_INT] = 0.0
        if cp[C_PRED] != 0.0:
            cs[CS_PGAIN] = cp[C_GAIN0]
            _model_reset(cs, CS_MX, int(cp[C_MNX]), held)
            _model_reset(cs, CS_DX, int(cp[C_DNX]), held)
            cs[CS_QIDX] = 0.0
            for i in range(int(cp[C_QLEN])):
                cs[CS_QUEUE + i] = held
    elif kind == ADAPTIVE:
        cs[CS_AD_CMD] = held
        cs[CS_AD_MODEL] = held
        cs[CS_AD_GAIN] = math.nan
    elif kind == ASMC:
        _rls_restart(cp, cs)
        cs[CS_RLS_RESTARTS] = 0.0
        u0 = _feed_rate(cp, _clip(cp, held)) / 60.0
        cs[CS_Y], cs[CS_Y + 1] = 0.0, 0.0
        cs[CS_U], cs[CS_U + 1] = u0, u0
        cs[CS_STARTED] = 0.0
        cs[CS_SLIDING] = 0.0
    elif kind == POLE_PLACEMENT:
        _rls_restart(cp, cs)
        cs[CS_RLS_RESTARTS] = 0.0
        u0 = _clip(cp, held)
        cs[CS_Y], cs[CS_Y + 1] = math.nan, math.nan
        cs[CS_U], cs[CS_U + 1] = u0, u0
        cs[CS_DU] = 0.0
    elif kind == PI:
        cs[CS_PI_INT] = held
    # the staircase forgets nothing: its place in the script is no state a bad sample spoils


@compiled
def _smc(cp: np.ndarray, cs: np.ndarray, force: float, rate: float, out: np.ndarray) -> None:
    """Continuous sliding mode control (Park 1998, Eqs. 5-21; :mod:`..control.smc` states the
    law) acting on the force its Smith predictor gives (:mod:`..control.predictor`)."""
    ref = cp[C_REF]
    measured_error = force - ref
    if cp[C_PRED] != 0.0:
        mnx, dnx = int(cp[C_MNX]), int(cp[C_DNX])
        z = cs[CS_MX + mnx - 1]
        if z > 1.0 and force > cp[C_ENGAGED] * ref:
            cs[CS_PGAIN] += cp[C_WEIGHT] * (force / z - cs[CS_PGAIN])
        k = cs[CS_PGAIN]
        tau_c = cp[C_MTAU_C]
        design_z = cs[CS_DX + dnx - 1]
        design_rate = (cs[CS_DX] - design_z) / tau_c
        machine_rate = (cs[CS_MX] - z) / tau_c
        force, rate = force + k * (design_z - z), rate + k * (design_rate - machine_rate)
    tau_s, tau_c = cp[C_DTAU], cp[C_TAU_C]
    a1 = -1.0 / (tau_s * tau_c)
    a2 = -(tau_s + tau_c) / (tau_s * tau_c)
    to_b = 1.0 / (tau_s * tau_c * cp[C_RPM])
    b_min, b_max = cp[C_KSD_MIN] * to_b, cp[C_KSD_MAX] * to_b
    b_hat = math.sqrt(b_min * b_max)
    lam = cp[C_LAM]
    error = force - ref
    f = a1 * force + a2 * rate
    integral = cs[CS_INT] + error * cp[C_PERIOD]
    surface = int(cp[C_SURFACE])
    if surface == PARK:
        s = rate + lam * error
        known = f + lam * rate
    else:
        # With integral action: s = e' + 2 zeta lambda e + lambda^2 int(e); zeta = 1, or for
        # the nonlinear surface a damping that rises as the error shrinks (El Khalick et al.
        # 2012, after composite nonlinear feedback): zeta(e) = zeta_far + (zeta_near -
        # zeta_far) exp(-(e / e_0)^2), low far from the reference (a fast approach), high near
        # it (little overshoot); dzeta_e = d(zeta(e) e) / de, which the equivalent control
        # needs. Products, not ** 2: libm's pow is not always x * x.
        zeta, dzeta_e = 1.0, 1.0
        if surface == NONLINEAR:
            near, far, scale = cp[C_NEAR], cp[C_FAR], cp[C_ESCALE]
            ratio = error / scale
            bump = math.exp(-(ratio * ratio))
            zeta = far + (near - far) * bump
            dzeta_e = zeta + (near - far) * bump * (-2.0 * (error * error) / (scale * scale))
        s = rate + 2.0 * zeta * lam * error + lam * lam * integral
        known = f + 2.0 * dzeta_e * lam * rate + lam * lam * error
    gain = abs(b_hat / b_min - 1.0) * abs(known) + b_hat / b_min * cp[C_ETA]
    if cp[C_EPS] > 0:
        epsilon = cp[C_EPS]
    else:
        # The balance condition (Slotine & Li Sec. 7.2): K / Phi = lambda / C_BALANCE at
        # F = F_ref, F' = 0, where K = |b_hat / b_min - 1| |a1| F_ref.
        b_ratio = math.sqrt(cp[C_KSD_MAX] / cp[C_KSD_MIN])
        a1_abs = 1.0 / (tau_s * tau_c)
        balance = abs(b_ratio - 1.0) * a1_abs * ref
        epsilon = cp[C_BALANCE] * balance / (lam * lam)
    phi = epsilon * lam
    pct = _pct(cp, (-known - gain * pymin(pymax(s / phi, -1.0), 1.0)) / b_hat)
    if surface != PARK and cp[C_MIN] <= pct <= cp[C_MAX]:
        cs[CS_INT] = integral
    out[OUT_PCT], out[OUT_ERR], out[OUT_S] = _clip(cp, pct), measured_error, s


@compiled
def _adaptive(cp: np.ndarray, cs: np.ndarray, force: float, out: np.ndarray) -> None:
    """The conventional adaptive controller (Masory & Koren 1980; :mod:`..control.adaptive`)."""
    dt = cp[C_PERIOD]
    cs[CS_AD_MODEL] += (cs[CS_AD_CMD] - cs[CS_AD_MODEL]) * (
        1.0 - math.exp(-dt / cp[C_MODEL_TAU]))
    ref = cp[C_REF]
    error = force - ref
    if cs[CS_AD_MODEL] > 1.0 and force > 0.05 * ref:
        measured = force / cs[CS_AD_MODEL]
        if math.isnan(cs[CS_AD_GAIN]):
            cs[CS_AD_GAIN] = measured
        else:
            tau = cp[C_EST_TAU]
            weight = 1.0 - math.exp(-dt / tau) if tau > 0 else 1.0
            cs[CS_AD_GAIN] += weight * (measured - cs[CS_AD_GAIN])
    if not math.isnan(cs[CS_AD_GAIN]):
        step = cp[C_LOOP_GAIN] * dt * error / cs[CS_AD_GAIN]
        cs[CS_AD_CMD] = _clip(cp, cs[CS_AD_CMD] - step)
    out[OUT_PCT], out[OUT_ERR], out[OUT_S] = cs[CS_AD_CMD], error, 0.0


@compiled
def _asmc_control(cp: np.ndarray, cs: np.ndarray, y: float, y_ref: float) -> float:
    """Hwang & Chen 1990, Eqs. 11-32 with Remarks 1-2 (:mod:`..control.adaptive_smc`): the
    feed-rate command u [mm/s] from the estimated model; u(k-1) held where the model cannot
    carry the transformation (Remark 2, freezing)."""
    a1, a2 = -cs[CS_THETA], -cs[CS_THETA + 1]
    b1, b2 = cs[CS_THETA + 2], cs[CS_THETA + 3]
    cs[CS_SLIDING] = 0.0
    a_of_1, b_of_1 = 1.0 + a1 + a2, b1 + b2
    hold = cs[CS_U]
    if abs(b_of_1) < cp[C_BMIN] or abs(a_of_1 / b_of_1) >= cp[C_FREEZE]:
        return hold
    if abs(b2) >= cp[C_BMIN]:
        m10, m11 = 0.0, 1.0
    elif abs(b1) >= cp[C_BMIN]:
        m10, m11 = 1.0, 0.0
    else:
        return hold
    m00, m01 = b2, -b1
    a00, a01, a10, a11 = -a1, 1.0, -a2, 0.0
    det = m00 * m11 - m01 * m10
    i00, i01, i10, i11 = m11 / det, -m01 / det, -m10 / det, m00 / det
    ma00, ma01 = m00 * a00 + m01 * a10, m00 * a01 + m01 * a11
    bar00, bar01 = ma00 * i00 + ma01 * i10, ma00 * i01 + ma01 * i11
    if abs(bar01) < 1e-12:
        return hold
    h1 = (bar00 - cp[C_POLE]) / bar01
    d0, d1 = h1 * m00 + 1.0 * m10, h1 * m01 + 1.0 * m11
    u0 = a_of_1 * y_ref / b_of_1
    x0, x1 = y - y_ref, -a2 * (cs[CS_Y] - y_ref) + b2 * (cs[CS_U] - u0)
    cs[CS_SLIDING] = d0 * x0 + d1 * x1
    da0, da1 = d0 * a00 + d1 * a10, d0 * a01 + d1 * a11
    return u0 - (da0 * x0 + da1 * x1) / (d0 * b1 + d1 * b2)


@compiled
def _asmc(cp: np.ndarray, cs: np.ndarray, force: float, out: np.ndarray) -> None:
    """Discrete adaptive sliding mode control (Hwang & Chen 1990; :mod:`..control.adaptive_smc`):
    RLS with variable forgetting (Eqs. 33-39), then the control (Eqs. 11-32)."""
    y, y_ref = force, cp[C_REF]
    if cs[CS_STARTED] != 0.0:
        _rls_update(cp, cs, cs[CS_Y], cs[CS_Y + 1], cs[CS_U], cs[CS_U + 1], y)
    cs[CS_STARTED] = 1.0
    u = _asmc_control(cp, cs, y, y_ref)
    u = _feed_rate(cp, _clip(cp, _pct(cp, 60.0 * u))) / 60.0
    cs[CS_Y + 1], cs[CS_Y] = cs[CS_Y], y
    cs[CS_U + 1], cs[CS_U] = cs[CS_U], u
    out[OUT_PCT], out[OUT_ERR], out[OUT_S] = _pct(cp, 60.0 * u), y - y_ref, cs[CS_SLIDING]


@compiled
def _solve4(m: np.ndarray, rhs: np.ndarray, x: np.ndarray) -> bool:
    """turning_force.core.lti.solve for 4 x 4: False where singular."""
    a = np.empty((4, 5))
    for i in range(4):
        for j in range(4):
            a[i, j] = m[i, j]
        a[i, 4] = rhs[i]
    for col in range(4):
        pivot = col
        for row in range(col + 1, 4):
            if abs(a[row, col]) > abs(a[pivot, col]):
                pivot = row
        if a[pivot, col] == 0.0:
            return False
        if pivot != col:
            for k in range(5):
                a[col, k], a[pivot, k] = a[pivot, k], a[col, k]
        for row in range(col + 1, 4):
            factor = a[row, col] / a[col, col]
            for k in range(col, 5):
                a[row, k] = a[row, k] - factor * a[col, k]
    for row in range(3, -1, -1):
        total = a[row, 4]
        for k in range(row + 1, 4):
            total = total - a[row, k] * x[k]
        x[row] = total / a[row, row]
    return True


@compiled
def pp_design(cp: np.ndarray, a1: float, a2: float, b0: float, b1: float,
              solution: np.ndarray) -> bool:
    """Kim's servo-compensator by pole placement: ``[r1, s0, s1, s2]`` into ``solution`` from
    ``A (1 - q^-1) (1 + r1 q^-1) + B (s0 + s1 q^-1 + s2 q^-2) = A_m``, the coefficients of
    ``q^-1 .. q^-4`` matched; ``A_m`` has the poles of a second-order loop of natural frequency
    ``C_PP_W`` and damping ``C_PP_Z`` sampled at the control period (two more at the
    origin). False where the system is singular (A and B share a root)."""
    w, z, dt = cp[C_PP_W], cp[C_PP_Z], cp[C_PERIOD]
    if z < 1.0:
        wd = w * math.sqrt(1.0 - z * z)
        m1 = -2.0 * math.exp(-z * w * dt) * math.cos(wd * dt)
    else:
        wd = w * math.sqrt(z * z - 1.0)
        m1 = -2.0 * math.exp(-z * w * dt) * math.cosh(wd * dt)
    m2 = math.exp(-2.0 * z * w * dt)
    matrix = np.array(((1.0, b0, 0.0, 0.0), (a1 - 1.0, b1, b0, 0.0),
                       (a2 - a1, 0.0, b1, b0), (-a2, 0.0, 0.0, b1)))
    rhs = np.array((m1 - (a1 - 1.0), m2 - (a2 - a1), a2, 0.0))
    return _solve4(matrix, rhs, solution)


@compiled
def _pole_placement(cp: np.ndarray, cs: np.ndarray, force: float, out: np.ndarray) -> None:
    """Kim's adaptive controller (Kim Eqs. 12-24; :mod:`..control.adaptive_pp`): RLS on the
    ARMA model, then the pole-placement servo-compensator (:func:`pp_design`)."""
    y = force
    y1, y2, u1, u2 = cs[CS_Y], cs[CS_Y + 1], cs[CS_U], cs[CS_U + 1]
    if not math.isnan(y2):
        _rls_update(cp, cs, -y1, -y2, u1, u2, y)
    solution = np.empty(4)
    solved = pp_design(cp, cs[CS_THETA], cs[CS_THETA + 1], cs[CS_THETA + 2], cs[CS_THETA + 3],
                       solution)
    ref = cp[C_REF]
    error = y - ref
    if not solved or math.isnan(y2):
        u = u1
    else:
        r1, s0, s1, s2 = solution[0], solution[1], solution[2], solution[3]
        du = (-r1 * cs[CS_DU] + (s0 + s1 + s2) * ref - (s0 * y + s1 * y1 + s2 * y2))
        u = _clip(cp, u1 + du)
    cs[CS_DU] = u - u1
    cs[CS_Y], cs[CS_Y + 1] = y, y1
    cs[CS_U], cs[CS_U + 1] = u, u1
    out[OUT_PCT], out[OUT_ERR], out[OUT_S] = u, error, 0.0


@compiled
def _pi(cp: np.ndarray, cs: np.ndarray, force: float, out: np.ndarray) -> None:
    """Fixed-gain PI with anti-windup by clamping the integral (:mod:`..control.pi`)."""
    error = force - cp[C_REF]
    proportional = -cp[C_KP] * error
    integral = cs[CS_PI_INT] - cp[C_KI] * error * cp[C_PERIOD]
    cs[CS_PI_INT] = pymin(pymax(integral, cp[C_MIN] - proportional), cp[C_MAX] - proportional)
    out[OUT_PCT], out[OUT_ERR], out[OUT_S] = _clip(cp, cs[CS_PI_INT] + proportional), error, 0.0


@compiled
def _staircase(cp: np.ndarray, cs: np.ndarray, force: float, out: np.ndarray) -> None:
    """The commissioning staircase (:mod:`..control.staircase`)."""
    commands = int(cs[CS_SC_COMMANDS])
    index = (commands // int(cp[C_SC_PER])) % int(cp[C_SC_N])
    cs[CS_SC_COMMANDS] = commands + 1
    out[OUT_PCT] = _clip(cp, cp[C_SC_LEVELS + index])
    out[OUT_ERR], out[OUT_S] = force - cp[C_REF], 0.0


@compiled
def _track_reach(cp: np.ndarray, cs: np.ndarray, request: float, error: float) -> float:
    """1.0 while the reference can be reached, else 0.0 (:class:`..control.Controller`)."""
    tolerance = pymin(cp[C_GAP] / 2.0, 5.0)
    side = 0
    if request >= cp[C_MAX] - tolerance and error < 0.0:
        side = 1
    elif request <= cp[C_MIN] + tolerance and error > 0.0:
        side = -1
    pinned_side = int(cs[CS_SIDE])
    if side != 0 and side == pinned_side:
        cs[CS_PINNED] += cp[C_PERIOD]
    elif side != 0:
        cs[CS_SIDE], cs[CS_PINNED] = side, cp[C_PERIOD]
    else:
        reached = (pinned_side == 1 and (error >= 0.0 or request
                                         < cp[C_MAX] - 2.0 * tolerance)) or (
            pinned_side == -1 and (error <= 0.0 or request > cp[C_MIN] + 2.0 * tolerance))
        if reached:
            cs[CS_SIDE], cs[CS_PINNED] = 0.0, 0.0
    return 1.0 if cs[CS_PINNED] < cp[C_UNREACH] else 0.0


@compiled
def _state_is_finite(cp: np.ndarray, cs: np.ndarray) -> bool:
    kind = int(cp[C_KIND])
    if kind == ASMC:
        return (math.isfinite(cs[CS_Y]) and math.isfinite(cs[CS_Y + 1])
                and math.isfinite(cs[CS_U]) and math.isfinite(cs[CS_U + 1]))
    if kind == POLE_PLACEMENT:
        return (math.isfinite(cs[CS_U]) and math.isfinite(cs[CS_U + 1])
                and math.isfinite(cs[CS_DU]))
    return True


@compiled
def _recover(cp: np.ndarray, cs: np.ndarray, error: float, out: np.ndarray) -> None:
    cs[CS_RESETS] += 1.0
    cs[CS_CARRY] = 0.0
    controller_reset(cp, cs)
    out[OUT_PCT] = cs[CS_HELD]
    out[OUT_ERR] = error if math.isfinite(error) else 0.0
    out[OUT_S] = 0.0
    out[OUT_REACH] = 1.0


@compiled
def controller_update(cp: np.ndarray, cs: np.ndarray, levels: np.ndarray, force: float,
                      rate: float, out: np.ndarray) -> None:
    """One control period (:class:`..control.Controller` states it): the law, the guard on its
    state, the error-feedback quantiser and the reachability flag;
    out = (pct, error, s, reachable)."""
    error = force - cp[C_REF]
    if not (math.isfinite(force) and math.isfinite(rate)):
        _recover(cp, cs, error, out)
        return
    kind = int(cp[C_KIND])
    if kind == SMC:
        _smc(cp, cs, force, rate, out)
    elif kind == ADAPTIVE:
        _adaptive(cp, cs, force, out)
    elif kind == ASMC:
        _asmc(cp, cs, force, out)
    elif kind == POLE_PLACEMENT:
        _pole_placement(cp, cs, force, out)
    elif kind == PI:
        _pi(cp, cs, force, out)
    else:
        _staircase(cp, cs, force, out)
    if not (math.isfinite(out[OUT_PCT]) and math.isfinite(out[OUT_S])
            and _state_is_finite(cp, cs)):
        _recover(cp, cs, error, out)
        return
    request = out[OUT_PCT]
    continuous = cp[C_CONT] != 0.0
    if cp[C_EF] == 0.0 or continuous:
        sent = request
    else:
        wanted = _clip(cp, request + cs[CS_CARRY])
        sent = quantise(levels, continuous, wanted)
        cs[CS_CARRY] = pymin(pymax(request + cs[CS_CARRY] - sent, -cp[C_GAP]), cp[C_GAP])
    if kind == SMC and cp[C_PRED] != 0.0:   # the predictor's models take the level sent
        level = quantise(levels, continuous, sent)
        mnx, dnx, qlen = int(cp[C_MNX]), int(cp[C_DNX]), int(cp[C_QLEN])
        for _ in range(int(cp[C_STEPS])):
            servo_in = delayed(cs, CS_QUEUE, CS_QIDX, qlen, level)
            _model_advance(cp, cs, CS_MX, mnx, C_MPHI, C_MGAM, servo_in)
        for _ in range(int(cp[C_STEPS])):
            _model_advance(cp, cs, CS_DX, dnx, C_DPHI, C_DGAM, level)
    cs[CS_HELD] = sent
    out[OUT_REACH] = _track_reach(cp, cs, request, out[OUT_ERR])
    out[OUT_PCT] = sent


@entry('void(float64[::1], float64[::1])')
def controller_start(cp: Arr, cs: Arr) -> None:
    """A controller's first state, from the held request (``CS_HELD``) and its parameters."""
    controller_reset(cp, cs)


@entry('void(float64[::1], float64[::1], float64[::1], float64, float64, float64[::1])')
def control_step(cp: Arr, cs: Arr, levels: Arr, force: float, rate: float, out: Arr) -> None:
    """:func:`controller_update` from Python (the nodes, replay)."""
    controller_update(cp, cs, levels, force, rate, out)
