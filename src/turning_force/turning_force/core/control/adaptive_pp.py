"""Kim's adaptive cutting-force controller, as a self-tuning pole-placement regulator.

Model (Kim Eq. 12): ``A(q) F = B(q) u`` with ``A = 1 + a1 q^-1 + a2 q^-2``,
``B = b0 q^-1 + b1 q^-2``, ``u`` the override [%]. Every period:

1. RLS (Kim Eq. 15, Goodwin & Sin) updates ``[a1, a2, b0, b1]``, skipped inside a dead zone
   of prediction error, with ``P`` reset to ``p0 I`` when its trace has run down, and
   projected on a positive static gain ``B(1) / A(1)``.
2. A servo-compensator (integral action, Kim Eq. 16) and pole placement: ``R``, ``S`` from
   ``A (1 - q^-1) R + B S = A_m``, where ``A_m`` has the poles of a second-order loop of
   natural frequency ``pp_natural_freq_rad_s`` and damping ``pp_damping`` (two more at the
   origin). The law ``R (1 - q^-1) u = S(1) F_ref - S F`` holds ``F = F_ref`` at rest
   whatever the model's error.

Kim places the poles by eigenstructure assignment on a state-space form (Eqs. 17-24); the
polynomial form here gives the same closed-loop poles for this second-order model.

Kim used it with an eight-bit override. Through the four-bit one the RLS fits the quantised
response to the continuous request, the model goes wrong and the loop limit-cycles between
0 and 150 % (``turning-force reproduce``): Park's case against adaptive control, measured.

The initial model: the servo's and the process's poles (``exp(-T / tau)``) and a static gain
of ``pp_gain0_n_per_pct``. The law runs compiled (``_pole_placement`` in
:mod:`.laws`, the estimator of :mod:`.rls`, the Diophantine equation
solved by elimination); this module reads its settings into it.
"""

from __future__ import annotations

import math
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
    dt = c.control_period_s
    p1 = math.exp(-dt / c.model_servo_time_constant_s)
    p2 = math.exp(-dt / c.model_cutting_time_constant_s)
    a1, a2 = -(p1 + p2), p1 * p2
    b = c.pp_gain0_n_per_pct * (1 + a1 + a2) / 2
    # Regressor [-F(k-1), -F(k-2), u(k-1), u(k-2)] for theta = [a1, a2, b0, b1].
    rls.fill(jit, p, [a1, a2, b, b], c.pp_p0, dead_zone=c.pp_dead_zone_n,
             reset_trace=c.pp_reset_trace, positive_static_gain=True)
    p[jit.C_PP_W], p[jit.C_PP_Z] = c.pp_natural_freq_rad_s, c.pp_damping
    return p, 0


LAW = Law('adaptive_pp', lambda jit: int(jit.POLE_PLACEMENT), fill,
          "Kim's adaptive controller: RLS and pole placement (Kim Eqs. 12-24)")
