"""Continuous sliding mode force control (Park 1998, Eqs. 5-21).

Plant (Eq. 5): ``F'' = a1 F + a2 F' + b v_c`` with ``a1 = -1 / (tau_s tau_c)``,
``a2 = -(tau_s + tau_c) / (tau_s tau_c)``, ``b = K_s d / (tau_s tau_c N)``, and
``b_min <= b <= b_max`` from the K_s d bounds (Eq. 7). With ``e = F - F_ref`` (Eq. 9),
``s = e' + lambda e`` (Eq. 10), ``b_hat = sqrt(b_min b_max)`` (Eq. 8),
``Phi = epsilon lambda`` (Eq. 21)::

    v_c = (-f - lambda F' - K sat(s / Phi)) / b_hat                       (Eq. 20)
    K   = |b_hat / b_min - 1| |f + lambda F'| + (b_hat / b_min) eta        (Eqs. 15-16)

with ``f = a1 F + a2 F'``. Eqs. 15-16 as printed carry ``b / b_hat`` where the sliding
condition (Eq. 14), divided through by ``b / b_hat``, gives ``b_hat / b``; only that form is
largest at ``b = b_min``, the choice the paper makes "such that condition (15) is always
guaranteed" (it is Slotine & Li's gain, Eq. 7.30). We implement that form.

Surfaces (``smc_surface``): Park's Eq. 10; with integral action (Slotine & Li Sec. 7.1.3:
``s = e' + 2 lambda e + lambda^2 int e``), which removes the steady error a wrong
``b_hat`` leaves; or that surface with a nonlinear damping (El Khalick et al. 2012).

Dead time and servo (``smc_predictor``): the law acts on the force a Smith predictor gives
(:mod:`.predictor`): the machine's PMC dead time and servo (from ``turning-force identify``)
are taken out, and the law sees the plant of Eq. 5 it is designed for, whose ``tau_s`` is
the servo's (or a second-order servo's equivalent ``2 zeta / w_n``). With no dead time and
a first-order servo the predictor changes nothing.

The law runs compiled (``_smc`` and the predictor's models in ``controller_update``,
:mod:`.laws`); this module reads its settings into it.
"""

from __future__ import annotations

import math
from types import ModuleType
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt

from turning_force.core.control.law import Law
from turning_force.core.control.predictor import (
    MODEL_STEP_S,
    design_time_constant_s,
    model_matrices,
)

if TYPE_CHECKING:
    from turning_force.core.control.settings import ControllerSettings

__all__ = ['BALANCE_FACTOR', 'ENGAGED_FRACTION', 'LAW']

FloatArray = npt.NDArray[np.float64]

# The automatic boundary layer (smc_epsilon_n = 0): from the balance condition (Slotine & Li
# Sec. 7.2) K / Phi = lambda / BALANCE_FACTOR at F = F_ref, F' = 0, where the gain is
# K = |b_hat / b_min - 1| |a1| F_ref. Slotine & Li's balance takes K / Phi = lambda; through the
# 4-bit override with error feedback a layer three times as wide measured best in every row of
# the robustness matrix (test/bench/bench_matrix.py: steady error and ripple both fall from 1 to
# 3; Park's fig8 file, tuned by hand, has 1.56).
BALANCE_FACTOR = 3.0
# The process gain is learned only while cutting: above this share of the reference force.
ENGAGED_FRACTION = 0.05
_SURFACES = {'park1998': 'PARK', 'integral': 'INTEGRAL', 'nonlinear': 'NONLINEAR'}


def fill(jit: ModuleType, c: ControllerSettings, p: FloatArray) -> tuple[FloatArray, int]:
    """The law's parameters, the Smith predictor's models among them (:mod:`.predictor`)."""
    p[jit.C_LAM], p[jit.C_ETA], p[jit.C_EPS] = c.smc_lambda_per_s, c.smc_eta, c.smc_epsilon_n
    p[jit.C_KSD_MIN], p[jit.C_KSD_MAX] = c.smc_ksd_min_n_mm, c.smc_ksd_max_n_mm
    p[jit.C_SURFACE] = getattr(jit, _SURFACES[c.smc_surface])
    p[jit.C_FAR], p[jit.C_NEAR] = c.smc_damping_far, c.smc_damping_near
    p[jit.C_ESCALE], p[jit.C_RPM] = c.smc_damping_error_n, c.spindle_speed_rpm
    p[jit.C_TAU_C] = c.model_cutting_time_constant_s
    p[jit.C_ENGAGED] = ENGAGED_FRACTION
    p[jit.C_BALANCE] = BALANCE_FACTOR
    if not c.smc_predictor:
        p[jit.C_DTAU] = c.model_servo_time_constant_s
        return p, 0
    tau_c = c.model_cutting_time_constant_s
    design_tau = design_time_constant_s(c.model_servo_model, c.model_servo_time_constant_s,
                                        c.model_servo_natural_freq_rad_s, c.model_servo_damping,
                                        tau_c)
    p[jit.C_DTAU], p[jit.C_PRED] = design_tau, 1.0
    machine = model_matrices(c.model_servo_model, c.model_servo_time_constant_s,
                             c.model_servo_natural_freq_rad_s, c.model_servo_damping, tau_c)
    design = model_matrices('first_order', design_tau, 1.0, 1.0, tau_c)
    for (phi, gamma), nx, phi_at, gamma_at in ((machine, jit.C_MNX, jit.C_MPHI, jit.C_MGAM),
                                               (design, jit.C_DNX, jit.C_DPHI, jit.C_DGAM)):
        size = gamma.size
        p[nx] = size
        for i in range(size):
            p[phi_at + 3 * i:phi_at + 3 * i + size] = phi[i]
        p[gamma_at:gamma_at + size] = gamma
    queue = round(c.model_dead_time_s / MODEL_STEP_S)
    p[jit.C_QLEN] = queue
    p[jit.C_STEPS] = max(1, round(c.control_period_s / MODEL_STEP_S))
    p[jit.C_WEIGHT] = 1.0 - math.exp(-c.control_period_s / c.smc_gain_time_constant_s)
    ksd_hat = math.sqrt(c.smc_ksd_min_n_mm * c.smc_ksd_max_n_mm)
    p[jit.C_GAIN0] = ksd_hat * c.programmed_feed_mm_rev / 100.0
    p[jit.C_MTAU_C] = tau_c
    return p, queue


LAW = Law('smc', lambda jit: int(jit.SMC), fill,
          'continuous sliding mode control (Park 1998, Eqs. 5-21)')
