"""Fixed-gain PI on the override with anti-windup by clamping the integral.

``pct = I - kp (F - F_ref)``, ``I += -ki (F - F_ref) T``; where the output would pass a
limit, the integral is set so that it sits on the limit, and it leaves the limit as soon as
the error changes sign.

What commercial adaptive-feed options run. The law runs compiled (``_pi`` in
:mod:`.laws`); this module reads its settings into it.
"""

from __future__ import annotations

from types import ModuleType
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt

from turning_force.core.control.law import Law

if TYPE_CHECKING:
    from turning_force.core.control.settings import ControllerSettings

__all__ = ['LAW']

FloatArray = npt.NDArray[np.float64]


def fill(jit: ModuleType, c: ControllerSettings, p: FloatArray) -> tuple[FloatArray, int]:
    p[jit.C_KP], p[jit.C_KI] = c.pi_kp_pct_per_n, c.pi_ki_pct_per_n_s
    return p, 0


LAW = Law('pi', lambda jit: int(jit.PI), fill, 'fixed-gain PI with anti-windup')
