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
of ``pp_gain0_n_per_pct``. The estimator is
:mod:`..rls`'s; the Diophantine equation is solved by elimination (:func:`pp_design`).
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
    C_PERIOD,
    C_REF,
    CS_HELD,
    CS_LAW,
    OUT_ERR,
    OUT_PCT,
    OUT_S,
    ControllerBase,
    Law,
    clip,
)
from turning_force.core.settings import setting

__all__ = ['LAW', 'Settings', 'pp_design']


@dataclass(frozen=True)
class Settings(ControllerBase):
    """Kim's law's settings."""

    pp_natural_freq_rad_s: float = setting(6.0, 'Closed-loop natural frequency the pole '
                                           'placement assigns; below the Nyquist rate '
                                           'pi / control_period_s', 'rad/s', low=0.0,
                                           low_open=True, high=1e4, dynamic=True,
                                           cite='Kim, Eqs. 16-24')
    pp_damping: float = setting(0.9, 'Closed-loop damping the pole placement assigns', low=0.0,
                                low_open=True, high=5.0, dynamic=True, unit='-',
                                cite='Kim, Eqs. 16-24')
    pp_gain0_n_per_pct: float = setting(8.0, 'Process gain the identification starts from',
                                        'N/%', low=0.0, low_open=True, high=1e4)
    pp_dead_zone_n: float = setting(2.0, 'Prediction errors below this do not update the model '
                                    '(dead zone)', 'N', low=0.0, high=1e4,
                                    cite='Kim, Eq. 12 (RLS dead zone)')
    pp_p0: float = setting(100.0, 'Covariance the RLS starts from and is reset to', low=0.0,
                           low_open=True, high=1e9, unit='-',
                           cite='Kim, Eq. 12 (RLS with covariance resetting)')
    pp_reset_trace: float = setting(1e-2, 'Covariance resetting: when trace(P) falls below '
                                    'this, P is reset to p0 I', low=0.0, high=1e9, unit='-',
                                    cite='Kim, Eq. 12 (RLS with covariance resetting)')

    def check(self) -> None:
        super().check()
        if self.pp_natural_freq_rad_s >= self.nyquist_rad_s:
            self.fail('pp_natural_freq_rad_s', f'not below the Nyquist rate pi / '
                                               f'control_period_s ({self.nyquist_rad_s:.4g} '
                                               'rad/s)')


P_NATURAL_FREQ, P_DAMPING, P_RLS = C_LAW, C_LAW + 1, C_LAW + 2
# y(k-1), y(k-2), u(k-1), u(k-2), the last change of u; the estimator's.
S_Y, S_U, S_DU, S_RLS = CS_LAW, CS_LAW + 2, CS_LAW + 4, CS_LAW + 5


def fill(settings: ControllerBase) -> tuple[Sequence[float], int]:
    assert isinstance(settings, Settings)
    dt = settings.control_period_s
    p1 = math.exp(-dt / settings.model_servo_time_constant_s)
    p2 = math.exp(-dt / settings.model_cutting_time_constant_s)
    a1, a2 = -(p1 + p2), p1 * p2
    b = settings.pp_gain0_n_per_pct * (1 + a1 + a2) / 2
    # Regressor [-F(k-1), -F(k-2), u(k-1), u(k-2)] for theta = [a1, a2, b0, b1].
    estimator = rls.params([a1, a2, b, b], settings.pp_p0, dead_zone=settings.pp_dead_zone_n,
                           reset_trace=settings.pp_reset_trace, positive_static_gain=True)
    return [settings.pp_natural_freq_rad_s, settings.pp_damping, *estimator], 5 + rls.STATE


@compiled
def reset(cp: np.ndarray, cs: np.ndarray) -> None:
    rls.restart(cp, cs, P_RLS, S_RLS)
    cs[S_RLS + rls.S_RESTARTS] = 0.0
    u0 = clip(cp, cs[CS_HELD])
    cs[S_Y], cs[S_Y + 1] = math.nan, math.nan
    cs[S_U], cs[S_U + 1] = u0, u0
    cs[S_DU] = 0.0


@compiled
def finite(cp: np.ndarray, cs: np.ndarray) -> bool:
    return math.isfinite(cs[S_U]) and math.isfinite(cs[S_U + 1]) and math.isfinite(cs[S_DU])


@compiled
def _solve4(m: np.ndarray, rhs: np.ndarray, x: np.ndarray) -> bool:
    """A 4 x 4 system by elimination with partial pivoting: False where singular."""
    a = np.empty((4, 5))
    for i in range(4):
        for j in range(4):
            a[i, j] = m[i, j]
        a[i, 4] = rhs[i]
    for col in range(4):
        pivot = col
        for row in range(col + 1, 4):
            if abs(a[row, col]) > abs(a[pivot, col]):
                pivot = row
        if a[pivot, col] == 0.0:
            return False
        if pivot != col:
            for k in range(5):
                a[col, k], a[pivot, k] = a[pivot, k], a[col, k]
        for row in range(col + 1, 4):
            factor = a[row, col] / a[col, col]
            for k in range(col, 5):
                a[row, k] = a[row, k] - factor * a[col, k]
    for row in range(3, -1, -1):
        total = a[row, 4]
        for k in range(row + 1, 4):
            total = total - a[row, k] * x[k]
        x[row] = total / a[row, row]
    return True


@compiled
def pp_design(cp: np.ndarray, a1: float, a2: float, b0: float, b1: float,
              solution: np.ndarray) -> bool:
    """Kim's servo-compensator by pole placement: ``[r1, s0, s1, s2]`` into ``solution`` from
    ``A (1 - q^-1) (1 + r1 q^-1) + B (s0 + s1 q^-1 + s2 q^-2) = A_m``, the coefficients of
    ``q^-1 .. q^-4`` matched; ``A_m`` has the poles of a second-order loop of natural frequency
    ``pp_natural_freq_rad_s`` and damping ``pp_damping`` sampled at the control period (two
    more at the origin). False where the system is singular (A and B share a root)."""
    w, z, dt = cp[P_NATURAL_FREQ], cp[P_DAMPING], cp[C_PERIOD]
    if z < 1.0:
        wd = w * math.sqrt(1.0 - z * z)
        m1 = -2.0 * math.exp(-z * w * dt) * math.cos(wd * dt)
    else:
        wd = w * math.sqrt(z * z - 1.0)
        m1 = -2.0 * math.exp(-z * w * dt) * math.cosh(wd * dt)
    m2 = math.exp(-2.0 * z * w * dt)
    matrix = np.array(((1.0, b0, 0.0, 0.0), (a1 - 1.0, b1, b0, 0.0),
                       (a2 - a1, 0.0, b1, b0), (-a2, 0.0, 0.0, b1)))
    rhs = np.array((m1 - (a1 - 1.0), m2 - (a2 - a1), a2, 0.0))
    return _solve4(matrix, rhs, solution)


@compiled
def step(cp: np.ndarray, cs: np.ndarray, force: float, rate: float, out: np.ndarray) -> None:
    """RLS on the ARMA model (Kim Eqs. 12, 15), then the pole-placement servo-compensator
    (Kim Eqs. 16-24, :func:`pp_design`)."""
    y = force
    y1, y2, u1, u2 = cs[S_Y], cs[S_Y + 1], cs[S_U], cs[S_U + 1]
    if not math.isnan(y2):
        rls.update(cp, cs, P_RLS, S_RLS, -y1, -y2, u1, u2, y)
    solution = np.empty(4)
    theta = S_RLS + rls.S_THETA
    solved = pp_design(cp, cs[theta], cs[theta + 1], cs[theta + 2], cs[theta + 3], solution)
    ref = cp[C_REF]
    error = y - ref
    if not solved or math.isnan(y2):
        u = u1
    else:
        r1, s0, s1, s2 = solution[0], solution[1], solution[2], solution[3]
        du = (-r1 * cs[S_DU] + (s0 + s1 + s2) * ref - (s0 * y + s1 * y1 + s2 * y2))
        u = clip(cp, u1 + du)
    cs[S_DU] = u - u1
    cs[S_Y], cs[S_Y + 1] = y, y1
    cs[S_U], cs[S_U + 1] = u, u1
    out[OUT_PCT], out[OUT_ERR], out[OUT_S] = u, error, 0.0


LAW = Law('adaptive_pp', Settings, fill,
          "Kim's adaptive controller: RLS and pole placement (Kim Eqs. 12-24)")
