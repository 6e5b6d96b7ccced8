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
(:mod:`..predictor`): the machine's PMC dead time and servo (from ``turning-force identify``)
are taken out, and the law sees the plant of Eq. 5 it is designed for, whose ``tau_s`` is
the servo's (or a second-order servo's equivalent ``2 zeta / w_n``). With no dead time and
a first-order servo the predictor changes nothing. Where the drift monitor names a PMC dead time
or servo drift (``drift_adopt_model``), the predictor's machine model takes it, and the law the
design it would have been commissioned with on that servo (:func:`adopt`,
:func:`..predictor.adopt`), until the tool changes.

Its gain uses the spindle speed through ``b``: the live one (``machine/spindle_speed``) where it
is given, else ``spindle_speed_rpm`` (:func:`..law.spindle_speed`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from turning_force.core.compiled import compiled, pymax, pymin
from turning_force.core.control import predictor
from turning_force.core.control.law import (
    C_LAW,
    C_MAX,
    C_MIN,
    C_PERIOD,
    C_REF,
    C_RPM,
    CS_HELD,
    CS_LAW,
    OUT_ERR,
    OUT_PCT,
    OUT_S,
    ControllerBase,
    Law,
    clip,
    pct,
)
from turning_force.core.settings import setting

__all__ = ['BALANCE_FACTOR', 'LAW', 'Settings']

# The automatic boundary layer (smc_epsilon_n = 0): from the balance condition (Slotine & Li
# Sec. 7.2) K / Phi = lambda / BALANCE_FACTOR at F = F_ref, F' = 0, where the gain is
# K = |b_hat / b_min - 1| |a1| F_ref. Slotine & Li's balance takes K / Phi = lambda; through the
# 4-bit override with error feedback a layer three times as wide measured best in every row of
# the robustness matrix (test/bench/bench_matrix.py: steady error and ripple both fall from 1 to
# 3; Park's fig8 file, tuned by hand, has 1.56).
BALANCE_FACTOR = 3.0
SURFACES = ('park1998', 'integral', 'nonlinear')
PARK, INTEGRAL, NONLINEAR = range(3)


@dataclass(frozen=True)
class Settings(ControllerBase):
    """The sliding mode law's settings."""

    smc_lambda_per_s: float = setting(20.0, 'Sliding-surface bandwidth lambda (Park Eq. 10), '
                                      'bounded by Eqs. 22-24', '1/s', low=0.0, low_open=True,
                                      dynamic=True, high=1e4, cite='Park 1998, Eqs. 10, 22-24')
    smc_eta: float = setting(0.1, 'Reaching-condition margin eta (Park Eq. 14)', 'N/s^2',
                             low=0.0, high=1e6, dynamic=True, cite='Park 1998, Eq. 14')
    smc_epsilon_n: float = setting(25.0, 'Boundary-layer width epsilon, the allowed tracking '
                                   'error (Park Eq. 21); 0: from the balance condition K / Phi '
                                   '= lambda / 3; below max_feed_force_n', 'N', low=0.0,
                                   high=1e5, dynamic=True, cite='Park 1998, Eq. 21')
    smc_ksd_min_n_mm: float = setting(1000.0, 'Smallest K_s d the process may have (Park Eq. 7)',
                                      'N/mm', low=0.0, low_open=True, high=1e6,
                                      cite='Park 1998, Eqs. 7-8')
    smc_ksd_max_n_mm: float = setting(8000.0, 'Largest K_s d the process may have (Park Eq. 7)',
                                      'N/mm', low=0.0, low_open=True, high=1e6,
                                      cite='Park 1998, Eqs. 7-8')
    smc_surface: str = setting('park1998', "Sliding surface: Park Eq. 10 (s = e' + lambda e), "
                               'with integral action (Slotine & Li Sec. 7.1.3), or that with a '
                               'damping rising as the error shrinks (El Khalick et al. 2012)',
                               choices=SURFACES,
                               cite='Park 1998, Eq. 10; Slotine & Li 1991, Sec. 7.1.3; '
                               'El Khalick et al. 2012')
    smc_damping_far: float = setting(0.6, 'Nonlinear surface: damping far from the reference',
                                     low=0.1, high=5.0, dynamic=True,
                                     unit='-', cite='El Khalick et al. 2012')
    smc_damping_near: float = setting(1.5, 'Nonlinear surface: damping at the reference',
                                      low=0.1, high=5.0, dynamic=True,
                                      unit='-', cite='El Khalick et al. 2012')
    smc_damping_error_n: float = setting(50.0, 'Nonlinear surface: the error at which the '
                                         'damping is mostly the far one', 'N', low=0.0,
                                         low_open=True, high=1e5, dynamic=True)
    smc_predictor: bool = setting(True, 'Act on the force a Smith predictor gives from the '
                                  "machine model (model_dead_time_s, model_servo_*): the PMC's "
                                  'dead time and the servo taken out')
    smc_gain_time_constant_s: float = setting(0.05, 'Smoothing of the process gain F / z the '
                                              'predictor learns while cutting', 's', low=1e-3,
                                              high=10.0)
    smc_resonance_hz: float = setting(0.0, 'Lowest unmodelled structural resonance nu_R for the '
                                      'Eq. 22 bound; 0: none known', 'Hz', low=0.0,
                                      high=1e5, cite='Park 1998, Eq. 22')
    smc_unmodeled_delay_s: float = setting(0.0, 'Largest unmodelled time delay T_A for the '
                                           'Eq. 23 bound; 0: none', 's', low=0.0,
                                           high=10.0, cite='Park 1998, Eq. 23')

    def check(self) -> None:
        super().check()
        if self.smc_ksd_max_n_mm <= self.smc_ksd_min_n_mm:
            self.fail('smc_ksd_max_n_mm', f'must exceed smc_ksd_min_n_mm '
                                          f'({self.smc_ksd_min_n_mm})')
        if self.smc_epsilon_n >= self.max_feed_force_n:
            self.fail('smc_epsilon_n', f'not below max_feed_force_n '
                                       f'({self.max_feed_force_n:g} N)')
        bound, why = self.lambda_bound_per_s()
        if self.smc_lambda_per_s > bound:
            self.fail('smc_lambda_per_s', f'above the {why} bound {bound:.4g} 1/s')

    def lambda_bound_per_s(self) -> tuple[float, str]:
        """The smallest of Park's Eqs. 22-24 bounds on lambda, and which one it is."""
        bounds = [(0.2 / self.control_period_s,
                   f'Eq. 24 (sampling rate / 5, control_period_s = {self.control_period_s})')]
        if self.smc_unmodeled_delay_s > 0:
            bounds.append((1.0 / (3.0 * self.smc_unmodeled_delay_s),
                           f'Eq. 23 (1 / (3 T_A), T_A = {self.smc_unmodeled_delay_s} s)'))
        if self.smc_resonance_hz > 0:
            bounds.append((2.0 * math.pi / 3.0 * self.smc_resonance_hz,
                           f'Eq. 22 (2 pi nu_R / 3, nu_R = {self.smc_resonance_hz} Hz)'))
        return min(bounds)


# Parameters (from C_LAW) and state (from CS_LAW); the predictor's follow where it is on.
(P_LAMBDA, P_ETA, P_EPSILON, P_KSD_MIN, P_KSD_MAX, P_SURFACE, P_FAR, P_NEAR, P_ESCALE,
 P_TAU_C, P_DTAU, P_BALANCE, P_PREDICTOR) = range(C_LAW, C_LAW + 13)
P_MODEL = C_LAW + 13
S_INTEGRAL, S_MODEL = CS_LAW, CS_LAW + 1


def fill(settings: ControllerBase) -> tuple[Sequence[float], int]:
    """The law's parameters, the Smith predictor's among them (:mod:`..predictor`)."""
    assert isinstance(settings, Settings)
    c = settings
    tau_c = c.model_cutting_time_constant_s
    own = [c.smc_lambda_per_s, c.smc_eta, c.smc_epsilon_n, c.smc_ksd_min_n_mm,
           c.smc_ksd_max_n_mm, SURFACES.index(c.smc_surface), c.smc_damping_far,
           c.smc_damping_near, c.smc_damping_error_n, tau_c]
    if not c.smc_predictor:
        return [*own, c.model_servo_time_constant_s, BALANCE_FACTOR, 0.0], 1
    design_tau = predictor.design_time_constant_s(
        c.model_servo_model, c.model_servo_time_constant_s, c.model_servo_natural_freq_rad_s,
        c.model_servo_damping, tau_c)
    ksd_hat = math.sqrt(c.smc_ksd_min_n_mm * c.smc_ksd_max_n_mm)
    model, queue = predictor.params(
        c.model_servo_model, c.model_servo_time_constant_s, c.model_servo_natural_freq_rad_s,
        c.model_servo_damping, tau_c, design_tau, c.model_dead_time_s, c.control_period_s,
        c.smc_gain_time_constant_s, ksd_hat * c.programmed_feed_mm_rev / 100.0)
    return [*own, design_tau, BALANCE_FACTOR, 1.0, *model], 1 + predictor.STATE + queue


@compiled
def reset(cp: np.ndarray, cs: np.ndarray) -> None:
    cs[S_INTEGRAL] = 0.0
    if cp[P_PREDICTOR] != 0.0:
        predictor.reset(cp, cs, P_MODEL, S_MODEL, cs[CS_HELD])


@compiled
def sent(cp: np.ndarray, cs: np.ndarray, level: float) -> None:
    """The predictor's models take the level sent."""
    if cp[P_PREDICTOR] != 0.0:
        predictor.send(cp, cs, P_MODEL, S_MODEL, level)


@compiled
def adopt(cp: np.ndarray, cs: np.ndarray, cause: int, size: float) -> bool:
    """The drift monitor named a lag drift, ``size`` the member of its bank: the Smith
    predictor's machine model takes it, and the law the design for its servo
    (:func:`..predictor.adopt`); without the predictor the law has no model to take it
    into."""
    if cp[P_PREDICTOR] == 0.0:
        return False
    return predictor.adopt(cp, cs, P_MODEL, S_MODEL, cause, size, cs[CS_HELD])


@compiled
def step(cp: np.ndarray, cs: np.ndarray, force: float, rate: float, out: np.ndarray) -> None:
    """Eqs. 5-21 (the module's text) on the force the Smith predictor gives."""
    ref = cp[C_REF]
    measured_error = force - ref
    tau_s, tau_c = cp[P_DTAU], cp[P_TAU_C]
    if cp[P_PREDICTOR] != 0.0:
        force, rate = predictor.predict(cp, cs, P_MODEL, S_MODEL, ref, force, rate)
        tau_s = predictor.design_tau_s(cp, cs, P_MODEL, S_MODEL)
    a1 = -1.0 / (tau_s * tau_c)
    a2 = -(tau_s + tau_c) / (tau_s * tau_c)
    to_b = 1.0 / (tau_s * tau_c * cp[C_RPM])
    b_min, b_max = cp[P_KSD_MIN] * to_b, cp[P_KSD_MAX] * to_b
    b_hat = math.sqrt(b_min * b_max)
    lam = cp[P_LAMBDA]
    error = force - ref
    f = a1 * force + a2 * rate
    integral = cs[S_INTEGRAL] + error * cp[C_PERIOD]
    surface = int(cp[P_SURFACE])
    if surface == PARK:
        s = rate + lam * error
        known = f + lam * rate
    else:
        # With integral action: s = e' + 2 zeta lambda e + lambda^2 int(e); zeta = 1, or for
        # the nonlinear surface a damping that rises as the error shrinks (El Khalick et al.
        # 2012, after composite nonlinear feedback): zeta(e) = zeta_far + (zeta_near -
        # zeta_far) exp(-(e / e_0)^2), low far from the reference (a fast approach), high near
        # it (little overshoot); dzeta_e = d(zeta(e) e) / de, which the equivalent control
        # needs. Products, not ** 2: libm's pow is not always x * x.
        zeta, dzeta_e = 1.0, 1.0
        if surface == NONLINEAR:
            near, far, scale = cp[P_NEAR], cp[P_FAR], cp[P_ESCALE]
            ratio = error / scale
            bump = math.exp(-(ratio * ratio))
            zeta = far + (near - far) * bump
            dzeta_e = zeta + (near - far) * bump * (-2.0 * (error * error) / (scale * scale))
        s = rate + 2.0 * zeta * lam * error + lam * lam * integral
        known = f + 2.0 * dzeta_e * lam * rate + lam * lam * error
    gain = abs(b_hat / b_min - 1.0) * abs(known) + b_hat / b_min * cp[P_ETA]
    if cp[P_EPSILON] > 0:
        epsilon = cp[P_EPSILON]
    else:
        # The balance condition (Slotine & Li Sec. 7.2): K / Phi = lambda / BALANCE_FACTOR at
        # F = F_ref, F' = 0, where K = |b_hat / b_min - 1| |a1| F_ref.
        b_ratio = math.sqrt(cp[P_KSD_MAX] / cp[P_KSD_MIN])
        a1_abs = 1.0 / (tau_s * tau_c)
        balance = abs(b_ratio - 1.0) * a1_abs * ref
        epsilon = cp[P_BALANCE] * balance / (lam * lam)
    phi = epsilon * lam
    request = pct(cp, (-known - gain * pymin(pymax(s / phi, -1.0), 1.0)) / b_hat)
    if surface != PARK and cp[C_MIN] <= request <= cp[C_MAX]:
        cs[S_INTEGRAL] = integral
    out[OUT_PCT], out[OUT_ERR], out[OUT_S] = clip(cp, request), measured_error, s


LAW = Law('smc', Settings, fill, 'continuous sliding mode control (Park 1998, Eqs. 5-21)')
