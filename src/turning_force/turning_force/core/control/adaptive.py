"""The conventional adaptive force controller (Masory & Koren 1980, as Park compares to).

An integral controller on the feed whose gain is divided by an on-line estimate of the
process gain ``K_p = F / f_a`` [N per mm/rev], so that the loop gain stays at
``adaptive_loop_gain_per_s`` whatever the depth of cut::

    f_c(k) = f_c(k-1) - G T (F(k) - F_ref) / K_p_hat(k)

``f_a`` is the controller's own first-order servo model of its commands; it does not know
which override level the PMC applied, as a conventional controller does not.

The law runs compiled (``_adaptive`` in :mod:`.laws`); this module
reads its settings into it.
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
    p[jit.C_MODEL_TAU] = c.model_servo_time_constant_s
    p[jit.C_LOOP_GAIN] = c.adaptive_loop_gain_per_s
    p[jit.C_EST_TAU] = c.adaptive_estimate_time_constant_s
    return p, 0


LAW = Law('adaptive', lambda jit: int(jit.ADAPTIVE), fill,
          'the conventional adaptive controller Park compares against (Masory & Koren 1980)')
