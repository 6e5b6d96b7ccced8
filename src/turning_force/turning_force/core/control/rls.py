"""Recursive least squares, one implementation for the adaptive laws.

``theta`` is fitted to ``y(k) = phi(k)^T theta + e(k)`` one sample at a time (Goodwin & Sin;
Hwang & Chen 1990, Eqs. 33-37; Kim Eq. 15)::

    K(k)     = P(k-1) phi(k) / (1 + phi(k)^T P(k-1) phi(k))
    theta(k) = theta(k-1) + K(k) (y(k) - phi(k)^T theta(k-1))
    P(k)     = (P(k-1) - K(k) phi(k)^T P(k-1)) / f(k)

with the options the two papers use:

- a variable forgetting factor (Hwang & Chen Eqs. 38-39):
  ``f(k) = max(1 - (1 - phi^T K) e^2 / s_t, f_min)``; without it ``f = 1``;
- a dead zone (Kim): prediction errors within it leave the model alone;
- covariance resetting (Kim): when ``trace(P)`` has run down below a threshold, ``P = p0 I``;
- a projection: a candidate ``theta`` the caller's rule refuses is not taken.

Non-finite data or a non-finite result restart the estimator from its initial values: one
absurd sample must not leave the model broken for good.

``P - K phi^T P`` is taken as Eq. 37 prints it. Algebraically it is ``K (P phi)^T``, but ``P``
loses its symmetry in rounding, and with forgetting down at ``f_min`` (``P`` divided by 0.1 a
sample) the two forms part: with the other, Hwang & Chen's Example 1 settles 800 N off.

Four parameters, compiled: a law keeps the estimator's parameters (:func:`params`,
``PARAMS`` of them) and state (``STATE`` slots: ``theta``, ``P``, ``f``, the restarts) in its
own arrays from the offsets it passes (``pb`` and ``sb``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from turning_force.core.compiled import compiled, pymax

__all__ = ['PARAMS', 'STATE', 'S_F', 'S_RESTARTS', 'S_THETA', 'params', 'restart', 'update']

# Parameters, from the law's offset pb: theta(0) (4), p0, s_t, f_min, dead zone, reset trace,
# the projection on a positive static gain.
R_THETA0, R_P0, R_ST, R_FMIN, R_DEADZONE, R_RESET_TRACE, R_ACCEPT = 0, 4, 5, 6, 7, 8, 9
PARAMS = 10
# State, from the law's offset sb: theta (4), P (16, row by row), f, restarts.
S_THETA, S_P, S_F, S_RESTARTS = 0, 4, 20, 21
STATE = 22


def params(theta0: Sequence[float], p0: float, *, forgetting_sensitivity: float = 0.0,
           min_forgetting: float = 1.0, dead_zone: float = 0.0, reset_trace: float = 0.0,
           positive_static_gain: bool = False) -> list[float]:
    """The estimator's parameters: initial estimate and covariance ``p0 I``; Hwang & Chen's
    ``s_t`` (``forgetting_sensitivity``, 0: no forgetting) and ``f_min``; Kim's dead zone and
    covariance resetting; and the projection on a positive static gain (``B(1) > 0`` and
    ``A(1) > 0`` for ``theta = [a1, a2, b0, b1]``: more feed, more force)."""
    if len(theta0) != 4:
        raise ValueError(f'theta0 {list(theta0)!r}: the compiled estimator takes four')
    return [*theta0, p0, forgetting_sensitivity, min_forgetting, dead_zone, reset_trace,
            float(positive_static_gain)]


@compiled
def restart(cp: np.ndarray, cs: np.ndarray, pb: int, sb: int) -> None:
    """theta(0), P = p0 I, f = 1."""
    for i in range(4):
        cs[sb + S_THETA + i] = cp[pb + R_THETA0 + i]
        for j in range(4):
            cs[sb + S_P + 4 * i + j] = cp[pb + R_P0] if i == j else 0.0
    cs[sb + S_F] = 1.0


@compiled
def update(cp: np.ndarray, cs: np.ndarray, pb: int, sb: int, x0: float, x1: float,
           x2: float, x3: float, y: float) -> None:
    """One sample: regressor ``(x0, x1, x2, x3)``, output ``y`` (the module's text)."""
    theta_at, p_at = sb + S_THETA, sb + S_P
    x = np.array((x0, x1, x2, x3))
    if not (math.isfinite(y) and math.isfinite(x0) and math.isfinite(x1)
            and math.isfinite(x2) and math.isfinite(x3)):
        cs[sb + S_RESTARTS] += 1.0
        restart(cp, cs, pb, sb)
        return
    total = x[0] * cs[theta_at]
    for i in range(1, 4):
        total = total + x[i] * cs[theta_at + i]
    error = y - total
    if abs(error) <= cp[pb + R_DEADZONE]:
        return
    p_phi = np.empty(4)
    for i in range(4):
        total = cs[p_at + 4 * i] * x[0]
        for j in range(1, 4):
            total = total + cs[p_at + 4 * i + j] * x[j]
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
        theta[i] = cs[theta_at + i] + gain[i] * error
        finite = finite and math.isfinite(theta[i])
    if finite and cp[pb + R_ACCEPT] != 0.0 \
            and not (theta[2] + theta[3] > 0.0 and 1.0 + theta[0] + theta[1] > 0.0):
        return
    f = 1.0
    if cp[pb + R_ST] > 0:
        total = x[0] * gain[0]
        for i in range(1, 4):
            total = total + x[i] * gain[i]
        f = pymax(1.0 - (1.0 - total) * (error * error) / cp[pb + R_ST], cp[pb + R_FMIN])
    p = np.empty(16)
    for i in range(4):
        for j in range(4):
            total = (gain[i] * x[0]) * cs[p_at + j]
            for k in range(1, 4):
                total = total + (gain[i] * x[k]) * cs[p_at + 4 * k + j]
            p[4 * i + j] = (cs[p_at + 4 * i + j] - total) / f
            finite = finite and math.isfinite(p[4 * i + j])
    if not finite:
        cs[sb + S_RESTARTS] += 1.0
        restart(cp, cs, pb, sb)
        return
    for i in range(4):
        cs[theta_at + i] = theta[i]
    trace = 0.0
    for i in range(16):
        cs[p_at + i] = p[i]
    for i in range(4):
        trace = trace + p[5 * i]
    cs[sb + S_F] = f
    if cp[pb + R_RESET_TRACE] > 0 and trace < cp[pb + R_RESET_TRACE]:
        for i in range(4):
            for j in range(4):
                cs[p_at + 4 * i + j] = cp[pb + R_P0] if i == j else 0.0
