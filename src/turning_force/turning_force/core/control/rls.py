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

The estimator runs compiled (``_rls_update`` in :mod:`.laws`, four
parameters); :func:`fill` reads a law's choices into it.
"""

from __future__ import annotations

from collections.abc import Sequence
from types import ModuleType

import numpy as np
import numpy.typing as npt

__all__ = ['fill']

FloatArray = npt.NDArray[np.float64]


def fill(jit: ModuleType, p: FloatArray, theta0: Sequence[float], p0: float, *,
         forgetting_sensitivity: float = 0.0, min_forgetting: float = 1.0,
         dead_zone: float = 0.0, reset_trace: float = 0.0,
         positive_static_gain: bool = False) -> None:
    """The estimator's parameters: initial estimate and covariance ``p0 I``; Hwang & Chen's
    ``s_t`` (``forgetting_sensitivity``, 0: no forgetting) and ``f_min``; Kim's dead zone and
    covariance resetting; and the projection on a positive static gain (``B(1) > 0`` and
    ``A(1) > 0`` for ``theta = [a1, a2, b0, b1]``: more feed, more force)."""
    if len(theta0) != 4:
        raise ValueError(f'theta0 {list(theta0)!r}: the compiled estimator takes four')
    p[jit.C_THETA0:jit.C_THETA0 + 4] = theta0
    p[jit.C_P0], p[jit.C_ST], p[jit.C_FMIN] = p0, forgetting_sensitivity, min_forgetting
    p[jit.C_DEADZONE], p[jit.C_RESET_TRACE] = dead_zone, reset_trace
    p[jit.C_ACCEPT] = positive_static_gain
