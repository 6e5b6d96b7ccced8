"""What the machine will do with the overrides already sent: a model of PMC, servo and process.

The controller knows exactly which override levels it sent, and (after ``turning-force
identify``) the PMC dead time and the feed servo. This module runs two models on those levels,
in override percent, at the DAQ's sample rate:

- the machine model: PMC dead time, then the servo (first order, Park Eq. 2, or second order,
  Hwang & Chen Eq. 1), then the cutting process's lag (Park Eq. 1): ``z`` is the feed the
  process feels, in % of the programmed feed, at the time of the last force estimate;
- the design model the sliding mode law is designed for: no dead time and a first-order servo
  (Park's Eq. 2 with the same or an equivalent time constant).

The cutting force is ``F = k z`` with ``k`` (N per %) the process gain ``K_s d f / 100``,
estimated on line as ``F / z`` of the machine model. A Smith predictor (Smith 1957) with model
matching then hands the law ``F_p = F + k (z_design - z_machine)``: the force the design plant
would show, so that the law acts as if the dead time were not there and the servo were the one
it was designed for. With no dead time and a first-order servo the two models are one and
``F_p = F`` exactly. ``k`` is smoothed with ``smc_gain_time_constant_s`` and learned only while
cutting (the force above ``ENGAGED_FRACTION`` of the reference) and the model feeds.

A machine that drifted from the model (a slower servo, a longer PMC dead time) is predicted
wrong. Where the drift monitor (:mod:`.drift`) names such a lag drift, a member of its bank,
the machine model takes that member's dead time and servo from then on (:func:`adopt`) until
the tool changes, as the predictive law does (:mod:`.laws.mpc`), and the design model, with the
law (:func:`design_tau_s`), the servo the law would have been designed for on the drifted
machine (:func:`design_time_constant_s` of it): the law runs as if commissioned with the
member. Only the machine model taken in, the law stays designed for a servo faster than the
machine's, and model matching then hands it a plant that answers a depth step the slower
servo's way through the predictor's correction: bench_drift.py seed 16 #2 (a 0.34 s servo
slowed x1.8) held 21.1 N steady so, 3.7 N with the design taken too (2.4 N commissioned on
the drifted servo from the start). The servo's ``phi`` and ``gamma`` are worked out
beforehand for every servo scale of the bank (:data:`SCALES`, :func:`model_bank`: no matrix
exponential runs compiled), and the dead time's queue has room for the bank's longest delay;
a new dead time keeps the levels pending in their order
(:func:`~turning_force.core.compiled.requeue`).

The models and the predictor run compiled (:func:`predict`, :func:`reset`, :func:`send`,
:func:`adopt`), in a law's arrays from the offsets it passes (``pb``, ``sb``): ``PARAMS``
parameters (:func:`params`) and ``STATE`` slots plus the dead time's queue.
"""

from __future__ import annotations

import functools
import math

import numpy as np
import numpy.typing as npt

from turning_force.core.compiled import compiled, delayed, pymax, pymin, requeue
from turning_force.core.control.drift import (
    DEAD_OFFSETS,
    DEAD_TIME,
    NONE,
    SERVO,
    SERVO_POWERS,
    SERVO_RATIO,
)
from turning_force.core.lti import expm

__all__ = ['ENGAGED_FRACTION', 'MODEL_SIZE', 'MODEL_STEP_S', 'PARAMS', 'SCALES', 'STATE',
           'adopt', 'design_tau_s', 'design_time_constant_s', 'member', 'model_bank',
           'model_matrices', 'model_order', 'params', 'predict', 'reset', 'send']

FloatArray = npt.NDArray[np.float64]

# The models run at this step (the DAQ's 1 kHz): a dead time is resolved to a millisecond.
MODEL_STEP_S = 1e-3
# The process gain is learned only while cutting: above this share of the reference force.
ENGAGED_FRACTION = 0.05

# The servo models a machine model may run on: the commissioned one, then the drift monitor's
# bank's servo members (time scales SERVO_RATIO^k), each phi (3 x 3) and gamma (3).
SCALES = (1.0, *(SERVO_RATIO ** k for k in SERVO_POWERS))
MODEL_SIZE = 12

# Parameters, from the law's offset pb: each model's order; the queue's commissioned length,
# model steps a control period, the gain's smoothing weight, its first value, tau_c, the
# engaged fraction, the queue's room (its longest length); per servo scale of SCALES: the
# scale, the design's time constant, the machine model's phi and gamma (:func:`model_bank`),
# the design model's.
M_NX, D_NX = 0, 1
Q_LEN, Q_STEPS, Q_WEIGHT, Q_GAIN0, Q_TAU_C, Q_ENGAGED, Q_ROOM = range(2, 9)
M_SCALES = 9
D_TAUS = M_SCALES + len(SCALES)
M_BANK = D_TAUS + len(SCALES)   # servo model i: phi from M_BANK + MODEL_SIZE i, then gamma
D_BANK = M_BANK + MODEL_SIZE * len(SCALES)   # its design model likewise
PARAMS = D_BANK + MODEL_SIZE * len(SCALES)
# State, from the law's offset sb: the process gain k, the machine's x (3), the design's x
# (3), the queue's next place, the machine model's servo (its index in SCALES) and the model
# steps added to its dead time (0, 0: the commissioned model, :func:`adopt`); the queue
# (Q_ROOM slots) follows.
S_GAIN, S_MX, S_DX, S_QIDX, S_MODEL, S_SHIFT = 0, 1, 4, 7, 8, 9
STATE = 10


def design_time_constant_s(servo_model: str, time_constant_s: float, natural_freq_rad_s: float,
                           damping: float, cutting_time_constant_s: float) -> float:
    """The first-order servo the sliding mode law is designed for: the servo's own time
    constant, or for a second-order servo the first-order one with the same mean delay,
    ``2 zeta / w_n``; but no faster than the cutting process's lag ``tau_c``.

    Park's ``a1 = -1 / (tau_s tau_c)`` grows without bound as ``tau_s`` falls, and with it the
    switching gain and the boundary layer the balance condition asks for: designed on Hwang &
    Chen's 60 rad/s servo (23 ms) the law holds a 2900 N layer and answers a depth step the
    wrong way for 0.1 s (test/bench/bench_matrix.py: 30 N mean against 11 N with the floor).
    The predictor makes the faster machine look like the slower design servo.
    """
    if servo_model == 'first_order':
        equivalent = time_constant_s
    else:
        equivalent = 2.0 * damping / natural_freq_rad_s
    return max(equivalent, cutting_time_constant_s)


def _discretise(a: FloatArray, b: FloatArray, step_s: float) -> tuple[FloatArray, FloatArray]:
    """Exact zero-order-hold discretisation of ``x' = A x + B u`` (cached by value)."""
    phi, gamma = _discretised(tuple(map(tuple, a.tolist())), tuple(b.tolist()), step_s)
    return np.array(phi), np.array(gamma)


@functools.lru_cache(maxsize=64)
def _discretised(a_rows: tuple[tuple[float, ...], ...], b_values: tuple[float, ...],
                 step_s: float) -> tuple[list[list[float]], list[float]]:
    a, b = np.array(a_rows), np.array(b_values)
    n = a.shape[0]
    block = np.zeros((n + 1, n + 1))
    block[:n, :n], block[:n, n] = a * step_s, b * step_s
    e = expm(block)
    return e[:n, :n].tolist(), e[:n, n].tolist()


def model_order(servo_model: str) -> int:
    """The machine model's state size (:func:`model_matrices`): the servo's order, then the
    process lag's one."""
    return 2 if servo_model == 'first_order' else 3


def model_matrices(servo_model: str, time_constant_s: float, natural_freq_rad_s: float,
                   damping: float, cutting_time_constant_s: float,
                   step_s: float = MODEL_STEP_S) -> tuple[FloatArray, FloatArray]:
    """(phi, gamma) of the machine model at ``step_s``: the servo (first order, Park
    Eq. 2, or second order, Hwang & Chen Eq. 1) and the process lag (Park Eq. 1), in override
    percent. The state's first entry is the servo's feed and its last the process-lagged feed
    ``z``; the compiled predictor steps ``x = phi x + gamma u``, each row summed in order."""
    tau_c = cutting_time_constant_s
    if servo_model == 'first_order':
        a = np.array([[-1.0 / time_constant_s, 0.0], [1.0 / tau_c, -1.0 / tau_c]])
        b = np.array([1.0 / time_constant_s, 0.0])
    else:
        w, zeta = natural_freq_rad_s, damping
        a = np.array([[0.0, 1.0, 0.0], [-w * w, -2.0 * zeta * w, 0.0],
                      [1.0 / tau_c, 0.0, -1.0 / tau_c]])
        b = np.array([0.0, w * w, 0.0])
    return _discretise(a, b, step_s)


def _packed(phi: FloatArray, gamma: FloatArray) -> FloatArray:
    """A model's phi (rows of 3) and gamma (from 9), MODEL_SIZE values."""
    packed = np.zeros(MODEL_SIZE)
    nx = gamma.size
    for i in range(nx):
        packed[3 * i:3 * i + nx] = phi[i]
    packed[9:9 + nx] = gamma
    return packed


def model_bank(servo_model: str, time_constant_s: float, natural_freq_rad_s: float,
               damping: float, cutting_time_constant_s: float, step_s: float) -> FloatArray:
    """The machine model at ``step_s`` (:func:`model_matrices`) for every servo scale of
    :data:`SCALES` (a slower servo: ``tau_s`` x scale, or ``w_n`` / scale), each packed in
    MODEL_SIZE values: phi in rows of 3, gamma from 9."""
    return np.concatenate([_packed(*model_matrices(
        servo_model, time_constant_s * scale, natural_freq_rad_s / scale, damping,
        cutting_time_constant_s, step_s=step_s)) for scale in SCALES])


def _design_bank(servo_model: str, time_constant_s: float, natural_freq_rad_s: float,
                 damping: float, cutting_time_constant_s: float,
                 design_tau_s: float) -> tuple[list[float], FloatArray]:
    """The design's time constant and its model for every servo scale of :data:`SCALES`:
    ``design_tau_s`` for the commissioned servo, and for each member of the bank the one
    :func:`design_time_constant_s` gives for its servo."""
    taus = [design_tau_s, *(design_time_constant_s(
        servo_model, time_constant_s * scale, natural_freq_rad_s / scale, damping,
        cutting_time_constant_s) for scale in SCALES[1:])]
    return taus, np.concatenate([_packed(*model_matrices(
        'first_order', tau, 1.0, 1.0, cutting_time_constant_s)) for tau in taus])


def params(servo_model: str, time_constant_s: float, natural_freq_rad_s: float, damping: float,
           cutting_time_constant_s: float, design_tau_s: float, dead_time_s: float,
           control_period_s: float, gain_time_constant_s: float,
           gain0: float) -> tuple[list[float], int]:
    """The predictor's parameters (``PARAMS``) and the length of its dead time's queue, room
    for the drift monitor's longest delay included."""
    p = np.zeros(PARAMS)
    p[M_NX] = model_order(servo_model)
    p[D_NX] = 2
    queue = round(dead_time_s / MODEL_STEP_S)
    room = queue + round(max(DEAD_OFFSETS) * control_period_s / MODEL_STEP_S)
    p[Q_LEN], p[Q_ROOM] = queue, room
    p[Q_STEPS] = max(1, round(control_period_s / MODEL_STEP_S))
    p[Q_WEIGHT] = 1.0 - math.exp(-control_period_s / gain_time_constant_s)
    p[Q_GAIN0], p[Q_TAU_C], p[Q_ENGAGED] = gain0, cutting_time_constant_s, ENGAGED_FRACTION
    p[M_SCALES:D_TAUS] = SCALES
    p[M_BANK:D_BANK] = model_bank(servo_model, time_constant_s, natural_freq_rad_s, damping,
                                  cutting_time_constant_s, MODEL_STEP_S)
    p[D_TAUS:M_BANK], p[D_BANK:] = _design_bank(servo_model, time_constant_s,
                                                natural_freq_rad_s, damping,
                                                cutting_time_constant_s, design_tau_s)
    return p.tolist(), room


@compiled
def member(cp: np.ndarray, scales_at: int, cause: int, size: float,
           step_s: float) -> tuple[float, int]:
    """The member of the drift monitor's bank it named (:mod:`.drift`: ``cause``, ``size``):
    the steps of ``step_s`` it adds to the dead time, and its servo model's index in
    :data:`SCALES` (the nearest scale by its log; the scales at ``scales_at`` in ``cp``).
    (0, 0): the commissioned model (``NONE``, or a cause that is no lag)."""
    if cause == DEAD_TIME:
        return float(round(size / step_s)), 0
    model = 0
    if cause == SERVO:
        gap = math.inf
        for i in range(1, len(SCALES)):
            off = abs(math.log(cp[scales_at + i] / size))
            if off < gap:
                model, gap = i, off
    return 0.0, model


@compiled
def _length(cp: np.ndarray, cs: np.ndarray, pb: int, sb: int) -> int:
    """The dead time the machine model is on [model steps]: commissioned, or adopted."""
    return int(cp[pb + Q_LEN] + cs[sb + S_SHIFT])


@compiled
def adopt(cp: np.ndarray, cs: np.ndarray, pb: int, sb: int, cause: int, size: float,
          held: float) -> bool:
    """The machine model takes the member of the drift monitor's bank it named, and the design
    model the servo the law would be designed for with it (the module's text; ``NONE``: the
    commissioned models, at a tool change, before :func:`reset`); the levels pending keep
    their order (none pending: ``held``). Whether it took it (a lag drift, or none)."""
    if cause != NONE and cause != DEAD_TIME and cause != SERVO:
        return False
    shift, model = member(cp, pb + M_SCALES, cause, size, MODEL_STEP_S)
    length = pymin(pymax(cp[pb + Q_LEN] + shift, 0.0), cp[pb + Q_ROOM])
    requeue(cs, sb + STATE, sb + S_QIDX, _length(cp, cs, pb, sb), int(length), held)
    cs[sb + S_MODEL], cs[sb + S_SHIFT] = model, length - cp[pb + Q_LEN]
    return True


@compiled
def _model_reset(cs: np.ndarray, x: int, nx: int, held: float) -> None:
    for i in range(3):
        cs[x + i] = 0.0
    cs[x] = held
    cs[x + nx - 1] = held


@compiled
def _model_advance(cp: np.ndarray, cs: np.ndarray, x: int, nx: int, phi: int, gamma: int,
                   servo_in: float) -> None:
    """One model step: x = phi x + gamma u (each row summed in order)."""
    x0, x1, x2 = cs[x], cs[x + 1], cs[x + 2]
    for i in range(nx):
        row = phi + 3 * i
        total = cp[row] * x0
        total = total + cp[row + 1] * x1
        if nx == 3:
            total = total + cp[row + 2] * x2
        cs[x + i] = total + cp[gamma + i] * servo_in


@compiled
def design_tau_s(cp: np.ndarray, cs: np.ndarray, pb: int, sb: int) -> float:
    """The servo time constant the law is designed for now: the commissioned design's, or the
    one for the servo adopted (:func:`adopt`)."""
    return cp[pb + D_TAUS + int(cs[sb + S_MODEL])]


@compiled
def reset(cp: np.ndarray, cs: np.ndarray, pb: int, sb: int, held: float) -> None:
    """Both models at rest at the held override, the queue full of it, the gain its first
    value."""
    cs[sb + S_GAIN] = cp[pb + Q_GAIN0]
    _model_reset(cs, sb + S_MX, int(cp[pb + M_NX]), held)
    _model_reset(cs, sb + S_DX, int(cp[pb + D_NX]), held)
    cs[sb + S_QIDX] = 0.0
    for i in range(_length(cp, cs, pb, sb)):
        cs[sb + STATE + i] = held


@compiled
def predict(cp: np.ndarray, cs: np.ndarray, pb: int, sb: int, reference: float, force: float,
            rate: float) -> tuple[float, float]:
    """The force and force rate the design plant would show: ``F_p = F + k (z_design -
    z_machine)`` (the module's text), ``k`` learned while cutting."""
    mnx, dnx = int(cp[pb + M_NX]), int(cp[pb + D_NX])
    z = cs[sb + S_MX + mnx - 1]
    if z > 1.0 and force > cp[pb + Q_ENGAGED] * reference:
        cs[sb + S_GAIN] += cp[pb + Q_WEIGHT] * (force / z - cs[sb + S_GAIN])
    k = cs[sb + S_GAIN]
    tau_c = cp[pb + Q_TAU_C]
    design_z = cs[sb + S_DX + dnx - 1]
    design_rate = (cs[sb + S_DX] - design_z) / tau_c
    machine_rate = (cs[sb + S_MX] - z) / tau_c
    return force + k * (design_z - z), rate + k * (design_rate - machine_rate)


@compiled
def send(cp: np.ndarray, cs: np.ndarray, pb: int, sb: int, level: float) -> None:
    """The level sent, into both models for one control period: the machine's (the servo and
    dead time in use, :func:`adopt`) through the PMC's dead time."""
    mnx, dnx, qlen = int(cp[pb + M_NX]), int(cp[pb + D_NX]), _length(cp, cs, pb, sb)
    model = pb + M_BANK + MODEL_SIZE * int(cs[sb + S_MODEL])
    design = pb + D_BANK + MODEL_SIZE * int(cs[sb + S_MODEL])
    for _ in range(int(cp[pb + Q_STEPS])):
        servo_in = delayed(cs, sb + STATE, sb + S_QIDX, qlen, level)
        _model_advance(cp, cs, sb + S_MX, mnx, model, model + 9, servo_in)
    for _ in range(int(cp[pb + Q_STEPS])):
        _model_advance(cp, cs, sb + S_DX, dnx, design, design + 9, level)
