"""Finite-control-set model predictive control over the override levels.

The PMC takes a handful of override levels (16 on a FANUC 0-T), behind a dead time and the feed
servo. As power electronics controls a converter with a handful of switch states (Rodriguez et
al., "Predictive current control of a voltage source inverter", IEEE Trans. Ind. Electron.
54(1), 2007, doi:10.1109/TIE.2006.888802: a cost evaluated for every switch state), this law
predicts the force for each level it may send and sends the best, rather than rounding a
continuous request.

The model is the machine's (``model_*``, from ``turning-force identify``), at the control period
``T``: the levels already sent go through the PMC's dead time (``D = round(model_dead_time_s /
T)`` periods), then the servo (first or second order) and the process lag (``tau_c``), giving
the feed ``z`` [% of the programmed feed] the process feels. The force is ``F = k z^g``
(Kienzle's ``F = K_s d f^g``, ``g`` = ``model_cutting_exponent``), ``k`` (which holds ``K_s
d``) learned on line as ``F / z^g`` while cutting. Every period, for each level ``u`` it may
send now, the law predicts the feed over the horizon after the dead time (``H = mpc_horizon_s /
T`` periods; within the dead time all is decided already) with ``u`` for one period and then a
held feed ``v``, and charges::

    J(u) = min_v  sum_{j=D+1}^{D+H} w^2 (z_j(u, v) - z_ref)^2 + rho (u - u_prev)^2

where ``z_ref = (F_ref / k)^(1/g)`` is the feed that gives the reference, ``w = g k
z_ref^(g-1)`` turns feed into force (``J`` is in N^2), and ``rho`` [N^2 per %^2] is the
switching penalty. The tail ``v`` is the continuous relaxation of the levels the law will send
after ``u`` (move blocking with the later moves relaxed): held on one level, the tail would ask
each period for the level nearest the reference and miss the average the levels between
them give. ``z`` is linear in ``u`` and ``v``, so ``v`` has a closed form (least squares,
clipped to the table); the law sends the ``u`` of least ``J``.

A cut whose depth changes along the part (a taper, a contour) changes ``k`` steadily, and a
``k`` held at its last learned value over the dead time and the horizon leaves the force a
steady error behind it: ``k``'s rate times the time from the learning to the first periods
after the dead time, which the first move is chosen for (the held tail takes the rest of the
horizon): on a 1 -> 2.5 mm taper over 12 s behind 94 ms of dead time, 5-7 N. The law therefore
learns ``k``'s trend ``r`` per period, smoothed over ``mpc_trend_time_constant_s``, and predicts
``k_j = k + r (l + D + 1 + j)`` for the ``j``-th period of the horizon, ``l = (1 - a) / a`` the
lag of the learning's smoothing ``a`` on a ramp: ``z_ref`` and ``w`` are taken per period. A
depth step (or the cut's start) is not a trend: an innovation ``F / z^g - k`` past 3 standard
deviations of the innovations' own (their variance tracked over the trend's time constant, an
innovation counted at most as four times it) is a jump, and ``r`` learns only once the innovations
have stayed inside that gate for three of the learning's time constants, ``k`` settled on the
new level: its convergence to a new depth is not taken for a trend. With the trend's time
constant 0 the law holds ``k`` over the horizon (``r = 0``). The trend carried is ``r`` less
its own noise (one standard deviation, towards 0): on a cut at one depth ``r`` is noise, and the
lead of 10 to 30 periods would carry it into every level.

Being a model of the feed, not an integrator, the law holds no windup: with the tool out of the
cut it asks for the level that would give the reference at the ``k`` last learned. Entering the
cut, the depth comes in through the same process lag as the feed: while the gate holds its
entry feed (and at the end of a hold through an exit the gate did not see) the model's lagged
feed is put where the force's asymptote ``F + tau_c dF/dt`` says it is (:func:`_entering`), so
that ``k`` is the cut's and the model carries the rest of the force's rise.

A machine that drifted from the model (a slower servo, a longer PMC dead time) is predicted
wrong, and the law then rings or limit-cycles. Where the drift monitor (:mod:`..drift`) names
such a lag drift, a member of its bank, the law takes that member's dead time and servo into
its model (:func:`adopt`) until the tool changes, as the sliding mode law's Smith predictor
does (:mod:`..predictor`): the servo's ``phi`` and ``gamma`` are worked out here for every servo
scale of the bank (:func:`..predictor.model_bank`: no matrix exponential runs compiled), and the
dead time's queue holds the bank's longest delay; a new dead time keeps the levels pending in
their order (the oldest repeated for a longer delay, the oldest dropped for a shorter one:
:func:`~turning_force.core.compiled.requeue`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from turning_force.core.compiled import compiled, pymax, requeue
from turning_force.core.control import predictor
from turning_force.core.control.drift import (
    DEAD_OFFSETS,
    DEAD_TIME,
    DS_AT,
    DS_HIST,
    DS_STARTED,
    HISTORY,
    NONE,
    SERVO,
)
from turning_force.core.control.law import (
    C_LAW,
    C_PERIOD,
    C_REF,
    C_TAU_C,
    CS_DRIFT,
    CS_ENTERING,
    CS_HELD,
    CS_LAW,
    OUT_ERR,
    OUT_PCT,
    OUT_S,
    ControllerBase,
    Law,
    heading,
)
from turning_force.core.control.predictor import MODEL_SIZE, SCALES
from turning_force.core.pmc.overrides import get_table
from turning_force.core.settings import setting

__all__ = ['LAW', 'Settings']

# A continuous table (ideal) gives the law this many candidate levels over its range.
CONTINUOUS_LEVELS = 31


@dataclass(frozen=True)
class Settings(ControllerBase):
    """The predictive law's horizon and switching penalty."""

    mpc_horizon_s: float = setting(0.3, 'Prediction horizon after the dead time (H T)', 's',
                                   low=0.0, low_open=True, high=5.0, dynamic=True)
    mpc_switch_penalty: float = setting(0.5, 'Switching penalty rho on each change of level',
                                        'N^2/%^2', low=0.0, high=1e9, dynamic=True)
    mpc_gain_time_constant_s: float = setting(0.05, 'Smoothing of the process gain k = F / z^g '
                                              'learned while cutting', 's', low=1e-3,
                                              high=10.0)
    mpc_trend_time_constant_s: float = setting(
        1.0, "Smoothing of the process gain's trend (a taper, a contour), which the law carries "
        'over the dead time and the horizon; 0: the gain is held as last learned', 's', low=0.0,
        high=60.0)

    def check(self) -> None:
        super().check()
        if self.mpc_horizon_s < self.control_period_s:
            self.fail('mpc_horizon_s', f'shorter than control_period_s '
                                       f'({self.control_period_s} s)')


# The servo models the law may predict with (predictor.SCALES): the commissioned one, then the
# drift monitor's bank's servo members, each phi (3 x 3) and gamma (3) at the period.
# Parameters (from C_LAW): exponent g, rho, the gain's weight, its first value, the engaged
# fraction, dead time D and horizon H [periods], the lowest and highest level, the model's
# order, the trend's weight (0: none), the calm periods it waits for after a jump, the servo
# models' scales and their phi and gamma (SCALES), how many levels, the levels.
(P_EXPONENT, P_PENALTY, P_WEIGHT, P_GAIN0, P_ENGAGED, P_DEAD, P_HORIZON, P_LOW, P_HIGH,
 P_NX, P_TREND, P_CALM) = range(C_LAW, C_LAW + 12)
P_SCALES = C_LAW + 12
P_PHI = P_SCALES + len(SCALES)   # model i: phi from P_PHI + MODEL_SIZE i, then gamma
P_COUNT = P_PHI + MODEL_SIZE * len(SCALES)
P_LEVELS = P_COUNT + 1
# State (from CS_LAW): k, the model's x (3), the queue's next place, k's trend per period and
# the variance of its innovations, the periods since the last jump, the servo model in use (its
# index in SCALES) and the periods added to D (0, 0: the commissioned model, :func:`adopt`);
# the queue (room for D plus the bank's longest delay).
S_GAIN, S_X, S_QIDX, S_TREND, S_SPREAD, S_CALM, S_MODEL, S_SHIFT, S_QUEUE = (
    CS_LAW, CS_LAW + 1, CS_LAW + 4, CS_LAW + 5, CS_LAW + 6, CS_LAW + 7, CS_LAW + 8,
    CS_LAW + 9, CS_LAW + 10)
# Innovations past this many standard deviations are a jump (a depth step), not a trend.
TREND_GATE = 3.0
TREND_SIGNIFICANCE = 1.0   # the trend's own noise, in standard deviations, left out of it
SPREAD0 = 0.01   # the innovations' first standard deviation, of k
# The least share of its asymptote the force is taken at while the entry feed holds
# (:func:`_entering`).
ENTRY_SHARE_MIN = 0.9


def fill(settings: ControllerBase) -> tuple[Sequence[float], int]:
    assert isinstance(settings, Settings)
    c = settings
    period = c.control_period_s
    models = predictor.model_bank(c.model_servo_model, c.model_servo_time_constant_s,
                                  c.model_servo_natural_freq_rad_s, c.model_servo_damping,
                                  c.model_cutting_time_constant_s, period)
    nx = predictor.model_order(c.model_servo_model)
    table = get_table(c.override_table)
    levels = (np.linspace(table.min_pct, table.max_pct, CONTINUOUS_LEVELS) if table.continuous
              else np.array(table.levels_pct, dtype=np.float64))
    dead = round(c.model_dead_time_s / period)
    # k at 100 %: the reference, until the first cut says otherwise.
    gain0 = c.reference_force_n / 100.0 ** c.model_cutting_exponent
    own = [c.model_cutting_exponent, c.mpc_switch_penalty,
           1.0 - math.exp(-period / c.mpc_gain_time_constant_s), gain0,
           predictor.ENGAGED_FRACTION, dead, max(1, round(c.mpc_horizon_s / period)),
           table.min_pct, table.max_pct, nx,
           (1.0 - math.exp(-period / c.mpc_trend_time_constant_s)
            if c.mpc_trend_time_constant_s > 0.0 else 0.0),
           math.ceil(3.0 * c.mpc_gain_time_constant_s / period),
           *SCALES, *models, levels.size, *levels]
    return own, S_QUEUE - CS_LAW + dead + max(DEAD_OFFSETS)


@compiled
def reset(cp: np.ndarray, cs: np.ndarray) -> None:
    """The model at rest at the held level, the queue full of it; the process gain learned so
    far is kept (a new cut of the same tool and material), unless it is not a gain; its trend
    belongs to the cut that ended and starts again from none."""
    held = cs[CS_HELD]
    nx = int(cp[P_NX])
    if not (math.isfinite(cs[S_GAIN]) and cs[S_GAIN] > 0.0):
        cs[S_GAIN] = cp[P_GAIN0]
    cs[S_TREND], cs[S_SPREAD], cs[S_CALM] = 0.0, math.inf, 0.0
    for i in range(3):
        cs[S_X + i] = 0.0
    cs[S_X] = held
    cs[S_X + nx - 1] = held
    cs[S_QIDX] = 0.0
    for i in range(_dead(cp, cs)):
        cs[S_QUEUE + i] = held


@compiled
def _dead(cp: np.ndarray, cs: np.ndarray) -> int:
    """The dead time the model is on [periods]: the commissioned one, or the one adopted."""
    return int(cp[P_DEAD] + cs[S_SHIFT])


@compiled
def _model(cs: np.ndarray) -> int:
    """Where the servo model in use starts in the parameters (its phi, then its gamma)."""
    return P_PHI + MODEL_SIZE * int(cs[S_MODEL])


@compiled
def _advance(cp: np.ndarray, model: int, x: np.ndarray, nx: int, level: float) -> None:
    """One control period of the model starting at ``model``: x = phi x + gamma u."""
    x0, x1, x2 = x[0], x[1], x[2]
    for i in range(nx):
        row = model + 3 * i
        x[i] = cp[row] * x0 + cp[row + 1] * x1 + cp[row + 2] * x2 + cp[model + 9 + i] * level


@compiled
def adopt(cp: np.ndarray, cs: np.ndarray, cause: int, size: float) -> bool:
    """The drift monitor named a lag drift, ``size`` the member of its bank (:mod:`..drift`):
    the model predicts with that member's servo and dead time from now on (the module's
    text, :func:`..predictor.member`); the levels pending keep their order
    (:func:`~turning_force.core.compiled.requeue`), and the model's state is the new model's
    over the overrides applied (:func:`_resync`). ``NONE``: the commissioned model (a tool
    change: the law is reset after). Whether the law took it."""
    if cause == NONE:
        cs[S_MODEL], cs[S_SHIFT] = 0.0, 0.0
        return True
    if cause != DEAD_TIME and cause != SERVO:
        return False
    shift, model = predictor.member(cp, P_SCALES, cause, size, cp[C_PERIOD])
    shift = pymax(shift, -cp[P_DEAD])
    requeue(cs, S_QUEUE, S_QIDX, _dead(cp, cs), int(cp[P_DEAD] + shift), cs[CS_HELD])
    cs[S_MODEL], cs[S_SHIFT] = model, shift
    _resync(cp, cs)
    return True


@compiled
def _resync(cp: np.ndarray, cs: np.ndarray) -> None:
    """The model's state ``x`` as the model in use gives it from the overrides the PMC
    applied over the drift monitor's memory of them (its ring of HISTORY control periods,
    :mod:`..drift`), from rest at the oldest, up to those still in the dead time's queue. The
    state the commissioned model left is that model's answer to the same levels: on a servo
    slower than commissioned the feed it holds runs ahead of the axis's (population seed 42
    #116, servo x1.36 named 0.12 s after the entry's step to 150 %: 77 % of the programmed
    feed in the model, 57 % on the axis), and a law on the new model from that state brakes
    too late for the feed the step set going. Where the monitor is off (no ring), the state
    is kept."""
    if cs[CS_DRIFT + DS_STARTED] == 0.0:
        return
    ring, at = CS_DRIFT + DS_HIST, int(cs[CS_DRIFT + DS_AT])
    nx = int(cp[P_NX])
    x = np.zeros(3)
    oldest = 100.0 * cs[ring + (at + 1) % HISTORY]
    x[0], x[nx - 1] = oldest, oldest
    for j in range(1, HISTORY - _dead(cp, cs)):
        _advance(cp, _model(cs), x, nx, 100.0 * cs[ring + (at + 1 + j) % HISTORY])
    for i in range(3):
        cs[S_X + i] = x[i]


@compiled
def sent(cp: np.ndarray, cs: np.ndarray, level: float) -> None:
    """The level sent goes into the dead time's queue; the one leaving it drives the model one
    period on, to the next estimate's time."""
    dead = _dead(cp, cs)
    applied = level
    if dead > 0:
        at = int(cs[S_QIDX])
        applied = cs[S_QUEUE + at]
        cs[S_QUEUE + at] = level
        cs[S_QIDX] = (at + 1) % dead
    x = np.empty(3)
    for i in range(3):
        x[i] = cs[S_X + i]
    _advance(cp, _model(cs), x, int(cp[P_NX]), applied)
    for i in range(3):
        cs[S_X + i] = x[i]


@compiled
def _response(cp: np.ndarray, model: int, x: np.ndarray, nx: int, first: float, then: float,
              z: np.ndarray) -> None:
    """The process-lagged feed at the end of each of the ``z.size`` periods from state ``x``
    (changed) on the model at ``model``: input ``first`` for one period, then ``then``."""
    for j in range(z.size):
        _advance(cp, model, x, nx, first if j == 0 else then)
        z[j] = x[nx - 1]


@compiled
def _learn(cp: np.ndarray, cs: np.ndarray, measured: float) -> None:
    """One period of learning ``k`` from ``measured = F / z^g``, and its trend from the
    periods that are no jump (the module's text)."""
    innovation = measured - cs[S_GAIN]
    before = cs[S_GAIN]
    cs[S_GAIN] += cp[P_WEIGHT] * innovation
    weight = cp[P_TREND]
    if weight <= 0.0:
        return
    spread = cs[S_SPREAD]
    if not (math.isfinite(spread) and spread > 0.0):
        # the cut's first period: 1 % of k, which the innovations then widen to their own
        cs[S_SPREAD] = (SPREAD0 * measured) ** 2
        return
    gate = TREND_GATE * TREND_GATE * spread
    if innovation * innovation > gate:
        cs[S_CALM] = 0.0
    else:
        cs[S_CALM] += 1.0
        if cs[S_CALM] > cp[P_CALM]:
            cs[S_TREND] += weight * (cs[S_GAIN] - before - cs[S_TREND])
    cs[S_SPREAD] = spread + weight * (min(innovation * innovation, 4.0 * spread) - spread)


@compiled
def _significant_trend(cp: np.ndarray, cs: np.ndarray) -> float:
    """The trend less its own standard deviation (towards 0; 0 if no more than that):
    the learned increments ``a e`` of innovations ``e`` averaged with weight ``b`` vary by
    ``a sqrt(b / (2 - b)) std(e)``, and the horizon's lead would carry that noise into every
    period's level."""
    weight, trend = cp[P_TREND], cs[S_TREND]
    if weight <= 0.0 or not math.isfinite(cs[S_SPREAD]):
        return 0.0
    noise = cp[P_WEIGHT] * math.sqrt(cs[S_SPREAD] * weight / (2.0 - weight))
    return math.copysign(max(abs(trend) - TREND_SIGNIFICANCE * noise, 0.0), trend)


@compiled
def _entering(cp: np.ndarray, cs: np.ndarray, force: float, rate: float) -> None:
    """While the gate holds its entry feed the model rests at that level (:func:`reset`), but
    the force still rises: the depth enters through the cut's own lag, tau_c, as the feed
    does. The force heads for ``F + tau_c dF/dt`` (the first-order lag's asymptote); the
    model's lagged feed is put where ``k z^g`` gives the force now with ``k`` from that
    asymptote, ``z = u (F / (F + tau_c dF/dt))^(1/g)``, so that ``k`` learns the cut's gain
    and not the rise's, and the model carries the rest of the rise into the horizon. Learned
    from the rising force itself, ``k`` came out low, and at the entry feed's end the law
    asked for a pulse of up to 150 % and then 0 % to take it back (population seed 15's
    #4: 140 %, 0 %, 0 %, 20 % from a 30 % entry feed, 28 N over the reference). The same holds
    at the end of a hold through an exit the gate did not see (``CS_ENTERING``): the law rests
    on the level held while the tool enters the work again.

    The force is taken at ENTRY_SHARE_MIN of its asymptote at least: mid-rise the estimate's
    rate runs ahead of the force's (the estimator's own dynamics on a steep rise), and an
    asymptote from it was 40 % high on seed 15's #2 (678 N where 30 % gave about 475 N): the
    law cut the feed to 0-10 % at the hand-over, swung back to 150 %, was alarmed as a cycle,
    and met the next piece 298 N over the reference (12 N before)."""
    if cs[CS_ENTERING] == 0.0 or cp[C_TAU_C] <= 0.0 \
            or not force > cp[P_ENGAGED] * cp[C_REF]:
        return
    asymptote = heading(cp, force, rate)
    if asymptote > force:
        nx = int(cp[P_NX])
        share = pymax(force / asymptote, ENTRY_SHARE_MIN)
        cs[S_X + nx - 1] = cs[CS_HELD] * share ** (1.0 / cp[P_EXPONENT])


@compiled
def step(cp: np.ndarray, cs: np.ndarray, force: float, rate: float, out: np.ndarray) -> None:
    """The level of least cost (the module's text)."""
    ref = cp[C_REF]
    nx = int(cp[P_NX])
    g = cp[P_EXPONENT]
    _entering(cp, cs, force, rate)
    z_now = cs[S_X + nx - 1]
    if z_now > 1.0 and force > cp[P_ENGAGED] * ref:
        _learn(cp, cs, force / z_now ** g)
    k, trend = cs[S_GAIN], _significant_trend(cp, cs)
    horizon = int(cp[P_HORIZON])
    dead, model = _dead(cp, cs), _model(cs)
    # k over the horizon (the module's text), and the feed z_ref that gives the reference
    # there, and w, which turns feed into force
    lead = (1.0 - cp[P_WEIGHT]) / cp[P_WEIGHT] + dead + 1.0
    z_ref, w = np.empty(horizon), np.empty(horizon)
    for j in range(horizon):
        if j > 0 and trend == 0.0:   # k held: one z_ref and w for the whole horizon
            z_ref[j], w[j] = z_ref[0], w[0]
            continue
        k_j = min(max(k + trend * (lead + j), 0.5 * k), 2.0 * k)
        z_ref[j] = (ref / k_j) ** (1.0 / g)
        w[j] = g * k_j * z_ref[j] ** (g - 1.0)
    # z_j = a_j + b_j u + c_j v: the free response after the dead time's levels (a), and the
    # responses to the first move (b) and to the held tail (c).
    x = np.empty(3)
    for i in range(3):
        x[i] = cs[S_X + i]
    at = int(cs[S_QIDX])
    for j in range(dead):
        _advance(cp, model, x, nx, cs[S_QUEUE + (at + j) % dead])
    a, b, c = np.empty(horizon), np.empty(horizon), np.empty(horizon)
    _response(cp, model, x, nx, 0.0, 0.0, a)
    x[:] = 0.0
    _response(cp, model, x, nx, 1.0, 0.0, b)
    x[:] = 0.0
    _response(cp, model, x, nx, 0.0, 1.0, c)
    cc = 0.0
    for j in range(horizon):
        cc += c[j] * c[j]
    rho, held = cp[P_PENALTY], cs[CS_HELD]
    best, best_cost = held, math.inf
    for i in range(int(cp[P_COUNT])):
        u = cp[P_LEVELS + i]
        cost = rho * (u - held) * (u - held)
        if cost >= best_cost:
            continue
        rc = 0.0
        for j in range(horizon):
            rc += c[j] * (z_ref[j] - a[j] - b[j] * u)
        v = min(max(rc / cc, cp[P_LOW]), cp[P_HIGH]) if cc > 0.0 else u
        for j in range(horizon):
            e = w[j] * (a[j] + b[j] * u + c[j] * v - z_ref[j])
            cost += e * e
        if cost < best_cost:
            best, best_cost = u, cost
    out[OUT_PCT], out[OUT_ERR], out[OUT_S] = best, force - ref, 0.0


LAW = Law('mpc', Settings, fill,
          'finite-control-set model predictive control over the override levels')
