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

The estimator is :mod:`..rls`'s, on the regressor ``[y(k-1), y(k-2), u(k-1), u(k-2)]``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from turning_force.core.compiled import compiled
from turning_force.core.control import rls
from turning_force.core.control.law import (
    C_LAW,
    C_REF,
    CS_HELD,
    CS_LAW,
    OUT_ERR,
    OUT_PCT,
    OUT_S,
    ControllerBase,
    Law,
    clip,
    feed_rate,
    pct,
)
from turning_force.core.settings import setting

__all__ = ['LAW', 'Settings']


@dataclass(frozen=True)
class Settings(ControllerBase):
    """Hwang & Chen's law's settings."""

    asmc_pole: float = setting(0.0, 'Eigenvalue q assigned on the sliding surface (Hwang & Chen '
                               'Eq. 22)', low=-1.0, high=1.0, low_open=True, high_open=True,
                               unit='-', cite='Hwang & Chen 1990, Eq. 22')
    asmc_s_t: float = setting(10.0, 'Forgetting-factor sensitivity s_t = v^2 s_a (Eq. 38)',
                              'N^2', low=0.0, low_open=True, high=1e12,
                              cite='Hwang & Chen 1990, Eq. 38')
    asmc_f_min: float = setting(0.1, 'Smallest forgetting factor f_min (Eq. 39)', low=0.0,
                                low_open=True, high=1.0,
                                unit='-', cite='Hwang & Chen 1990, Eq. 39')
    asmc_p0: float = setting(1000.0, 'Initial covariance P(0) = p0 I', low=0.0, low_open=True,
                             high=1e9, unit='-', cite='Hwang & Chen 1990, Eqs. 33-39')
    asmc_theta0: tuple[float, ...] = setting([0.5, 0.0, 10.0, 5.0], 'Initial [-a1, -a2, b1, b2] '
                                             '(Hwang & Chen Example 1, u in mm/s)',
                                             low=-1e6, high=1e6,
                                             unit='-', cite='Hwang & Chen 1990, Eq. 7, Example 1')
    asmc_b_min: float = setting(1e-3, 'Remark 1: |b| below this is treated as zero', low=0.0,
                                low_open=True, high=1e3,
                                unit='-', cite='Hwang & Chen 1990, Remark 1')
    asmc_freeze_limit: float = setting(1e3, 'Remark 2: hold u when |A(1)/B(1)| reaches this',
                                       'mm/s per N', low=0.0, low_open=True, high=1e9,
                                       cite='Hwang & Chen 1990, Remark 2')

    def check(self) -> None:
        super().check()
        if len(self.asmc_theta0) != 4:
            self.fail('asmc_theta0', 'needs four values [-a1, -a2, b1, b2]')


P_POLE, P_B_MIN, P_FREEZE = range(C_LAW, C_LAW + 3)
P_RLS = C_LAW + 3
# y(k-1), y(k-2), u(k-1), u(k-2) [mm/s], started, the sliding variable; the estimator's.
S_Y, S_U, S_STARTED, S_SLIDING = CS_LAW, CS_LAW + 2, CS_LAW + 4, CS_LAW + 5
S_RLS = CS_LAW + 6


def fill(settings: ControllerBase) -> tuple[Sequence[float], int]:
    assert isinstance(settings, Settings)
    estimator = rls.params(settings.asmc_theta0, settings.asmc_p0,
                           forgetting_sensitivity=settings.asmc_s_t,
                           min_forgetting=settings.asmc_f_min)
    return [settings.asmc_pole, settings.asmc_b_min, settings.asmc_freeze_limit,
            *estimator], 6 + rls.STATE


@compiled
def reset(cp: np.ndarray, cs: np.ndarray) -> None:
    rls.restart(cp, cs, P_RLS, S_RLS)
    cs[S_RLS + rls.S_RESTARTS] = 0.0
    u0 = feed_rate(cp, clip(cp, cs[CS_HELD])) / 60.0
    cs[S_Y], cs[S_Y + 1] = 0.0, 0.0
    cs[S_U], cs[S_U + 1] = u0, u0
    cs[S_STARTED] = 0.0
    cs[S_SLIDING] = 0.0


@compiled
def finite(cp: np.ndarray, cs: np.ndarray) -> bool:
    return (math.isfinite(cs[S_Y]) and math.isfinite(cs[S_Y + 1])
            and math.isfinite(cs[S_U]) and math.isfinite(cs[S_U + 1]))


@compiled
def _control(cp: np.ndarray, cs: np.ndarray, y: float, y_ref: float) -> float:
    """Eqs. 11-32 with Remarks 1-2: the feed-rate command u [mm/s] from the estimated model;
    u(k-1) held where the model cannot carry the transformation (Remark 2, freezing)."""
    theta = S_RLS + rls.S_THETA
    a1, a2 = -cs[theta], -cs[theta + 1]
    b1, b2 = cs[theta + 2], cs[theta + 3]
    cs[S_SLIDING] = 0.0
    a_of_1, b_of_1 = 1.0 + a1 + a2, b1 + b2
    hold = cs[S_U]
    if abs(b_of_1) < cp[P_B_MIN] or abs(a_of_1 / b_of_1) >= cp[P_FREEZE]:
        return hold
    if abs(b2) >= cp[P_B_MIN]:
        m10, m11 = 0.0, 1.0
    elif abs(b1) >= cp[P_B_MIN]:
        m10, m11 = 1.0, 0.0
    else:
        return hold
    m00, m01 = b2, -b1
    a00, a01, a10, a11 = -a1, 1.0, -a2, 0.0
    det = m00 * m11 - m01 * m10
    i00, i01, i10, i11 = m11 / det, -m01 / det, -m10 / det, m00 / det
    ma00, ma01 = m00 * a00 + m01 * a10, m00 * a01 + m01 * a11
    bar00, bar01 = ma00 * i00 + ma01 * i10, ma00 * i01 + ma01 * i11
    if abs(bar01) < 1e-12:
        return hold
    h1 = (bar00 - cp[P_POLE]) / bar01
    d0, d1 = h1 * m00 + 1.0 * m10, h1 * m01 + 1.0 * m11
    u0 = a_of_1 * y_ref / b_of_1
    x0, x1 = y - y_ref, -a2 * (cs[S_Y] - y_ref) + b2 * (cs[S_U] - u0)
    cs[S_SLIDING] = d0 * x0 + d1 * x1
    da0, da1 = d0 * a00 + d1 * a10, d0 * a01 + d1 * a11
    return u0 - (da0 * x0 + da1 * x1) / (d0 * b1 + d1 * b2)


@compiled
def step(cp: np.ndarray, cs: np.ndarray, force: float, rate: float, out: np.ndarray) -> None:
    """RLS with variable forgetting (Eqs. 33-39), then the control (Eqs. 11-32)."""
    y, y_ref = force, cp[C_REF]
    if cs[S_STARTED] != 0.0:
        rls.update(cp, cs, P_RLS, S_RLS, cs[S_Y], cs[S_Y + 1], cs[S_U], cs[S_U + 1], y)
    cs[S_STARTED] = 1.0
    u = _control(cp, cs, y, y_ref)
    u = feed_rate(cp, clip(cp, pct(cp, 60.0 * u))) / 60.0
    cs[S_Y + 1], cs[S_Y] = cs[S_Y], y
    cs[S_U + 1], cs[S_U] = cs[S_U], u
    out[OUT_PCT], out[OUT_ERR], out[OUT_S] = pct(cp, 60.0 * u), y - y_ref, cs[S_SLIDING]


LAW = Law('adaptive_smc', Settings, fill,
          'discrete adaptive sliding mode control (Hwang & Chen 1990, Eqs. 11-39)')
