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

The models and the predictor run compiled, inside the sliding mode law
(``controller_update`` of :mod:`.laws`); this module gives their
matrices.
"""

from __future__ import annotations

import functools

import numpy as np
import numpy.typing as npt

from turning_force.core.lti import expm

__all__ = ['MODEL_STEP_S', 'design_time_constant_s', 'model_matrices']

FloatArray = npt.NDArray[np.float64]

# The models run at this step (the DAQ's 1 kHz): a dead time is resolved to a millisecond.
MODEL_STEP_S = 1e-3


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
                   damping: float,
                   cutting_time_constant_s: float) -> tuple[FloatArray, FloatArray]:
    """(phi, gamma) of the machine model at ``MODEL_STEP_S``: the servo (first order, Park
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
    return _discretise(a, b, MODEL_STEP_S)
