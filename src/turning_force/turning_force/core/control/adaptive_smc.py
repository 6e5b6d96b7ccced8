"""Discrete adaptive sliding mode control (Hwang & Chen 1990).

Plant model (Eqs. 6-7): ``A(d) y = B(d) u``, ``A = 1 + a1 d + a2 d^2``,
``B = b1 d + b2 d^2``, ``u`` the feed-rate command [mm/s] (Hwang & Chen's servo input).
Every period:

1. RLS with variable forgetting factor (Eqs. 33-39) updates ``[-a1, -a2, b1, b2]``.
2. A transformation ``M`` with ``M b = [0, q_b]`` (Eq. 12), ``A_bar = M A M^-1`` (Eq. 14),
   ``h1 = (a_bar11 - q) / a_bar12`` for the assigned eigenvalue ``q`` (Eq. 22), and the
   surface ``d = [h1, 1] M`` (Eq. 23).
3. ``u = u0 - d^T A x_e / d^T b`` with ``x_e = [y_e(k), -a2 y_e(k-1) + b2 u_e(k-1)]``
   (Eqs. 27-32), ``u0 = A(1) y_r / B(1)`` (Eq. 31).

Remark 1: if ``|b2|`` is too small to carry the transformation, the second row of ``M``
becomes ``[1, 0]`` so that ``q_b = b1``. Remark 2: if ``|A(1) / B(1)|`` reaches
``asmc_freeze_limit``, or both b's vanish, ``u`` is held (freezing).

The law runs compiled (``_asmc`` and ``_asmc_control`` in
:mod:`.laws`, the estimator of :mod:`.rls`); this module reads its
settings into it.
"""

from __future__ import annotations

from types import ModuleType
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt

from turning_force.core.control import rls
from turning_force.core.control.law import Law

if TYPE_CHECKING:
    from turning_force.core.control.settings import ControllerSettings

__all__ = ['LAW']

FloatArray = npt.NDArray[np.float64]


def fill(jit: ModuleType, c: ControllerSettings, p: FloatArray) -> tuple[FloatArray, int]:
    rls.fill(jit, p, c.asmc_theta0, c.asmc_p0, forgetting_sensitivity=c.asmc_s_t,
             min_forgetting=c.asmc_f_min)
    p[jit.C_POLE], p[jit.C_BMIN] = c.asmc_pole, c.asmc_b_min
    p[jit.C_FREEZE] = c.asmc_freeze_limit
    return p, 0


LAW = Law('adaptive_smc', lambda jit: int(jit.ASMC), fill,
          'discrete adaptive sliding mode control (Hwang & Chen 1990, Eqs. 11-39)')
