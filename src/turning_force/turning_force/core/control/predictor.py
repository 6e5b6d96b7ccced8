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

The models and the predictor run compiled (:func:`predict`, :func:`reset`, :func:`send`), in
a law's arrays from the offsets it passes (``pb``, ``sb``): ``PARAMS`` parameters
(:func:`params`) and ``STATE`` slots plus the dead time's queue.
"""

from __future__ import annotations

import functools
import math

import numpy as np
import numpy.typing as npt

from turning_force.core.compiled import compiled, delayed
from turning_force.core.lti import expm

__all__ = ['ENGAGED_FRACTION', 'MODEL_STEP_S', 'PARAMS', 'STATE', 'design_time_constant_s',
           'model_matrices', 'params', 'predict', 'reset', 'send']

FloatArray = npt.NDArray[np.float64]

# The models run at this step (the DAQ's 1 kHz): a dead time is resolved to a millisecond.
MODEL_STEP_S = 1e-3
# The process gain is learned only while cutting: above this share of the reference force.
ENGAGED_FRACTION = 0.05

# Parameters, from the law's offset pb: each model's order, phi (3 x 3) and gamma (3); the
# queue's length, model steps a control period, the gain's smoothing weight, its first value,
# tau_c, the engaged fraction.
M_NX, M_PHI, M_GAMMA, D_NX, D_PHI, D_GAMMA = 0, 1, 10, 13, 14, 23
Q_LEN, Q_STEPS, Q_WEIGHT, Q_GAIN0, Q_TAU_C, Q_ENGAGED = range(26, 32)
PARAMS = 32
# State, from the law's offset sb: the process gain k, the machine's x (3), the design's x
# (3), the queue's next place; the queue (Q_LEN slots) follows.
S_GAIN, S_MX, S_DX, S_QIDX = 0, 1, 4, 7
STATE = 8


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


def params(servo_model: str, time_constant_s: float, natural_freq_rad_s: float, damping: float,
           cutting_time_constant_s: float, design_tau_s: float, dead_time_s: float,
           control_period_s: float, gain_time_constant_s: float,
           gain0: float) -> tuple[list[float], int]:
    """The predictor's parameters (``PARAMS``) and the length of its dead time's queue."""
    p = np.zeros(PARAMS)
    machine = model_matrices(servo_model, time_constant_s, natural_freq_rad_s, damping,
                             cutting_time_constant_s)
    design = model_matrices('first_order', design_tau_s, 1.0, 1.0, cutting_time_constant_s)
    for (phi, gamma), nx, phi_at, gamma_at in ((machine, M_NX, M_PHI, M_GAMMA),
                                               (design, D_NX, D_PHI, D_GAMMA)):
        size = gamma.size
        p[nx] = size
        for i in range(size):
            p[phi_at + 3 * i:phi_at + 3 * i + size] = phi[i]
        p[gamma_at:gamma_at + size] = gamma
    queue = round(dead_time_s / MODEL_STEP_S)
    p[Q_LEN] = queue
    p[Q_STEPS] = max(1, round(control_period_s / MODEL_STEP_S))
    p[Q_WEIGHT] = 1.0 - math.exp(-control_period_s / gain_time_constant_s)
    p[Q_GAIN0], p[Q_TAU_C], p[Q_ENGAGED] = gain0, cutting_time_constant_s, ENGAGED_FRACTION
    return p.tolist(), queue


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
def reset(cp: np.ndarray, cs: np.ndarray, pb: int, sb: int, held: float) -> None:
    """Both models at rest at the held override, the queue full of it, the gain its first
    value."""
    cs[sb + S_GAIN] = cp[pb + Q_GAIN0]
    _model_reset(cs, sb + S_MX, int(cp[pb + M_NX]), held)
    _model_reset(cs, sb + S_DX, int(cp[pb + D_NX]), held)
    cs[sb + S_QIDX] = 0.0
    for i in range(int(cp[pb + Q_LEN])):
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
    """The level sent, into both models for one control period: the machine's through the
    PMC's dead time."""
    mnx, dnx, qlen = int(cp[pb + M_NX]), int(cp[pb + D_NX]), int(cp[pb + Q_LEN])
    for _ in range(int(cp[pb + Q_STEPS])):
        servo_in = delayed(cs, sb + STATE, sb + S_QIDX, qlen, level)
        _model_advance(cp, cs, sb + S_MX, mnx, pb + M_PHI, pb + M_GAMMA, servo_in)
    for _ in range(int(cp[pb + Q_STEPS])):
        _model_advance(cp, cs, sb + S_DX, dnx, pb + D_PHI, pb + D_GAMMA, level)
