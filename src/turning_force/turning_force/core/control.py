"""Cutting-force controllers behind one interface, chosen by name.

Each controller takes, once per control period, the estimated force and force rate and the
reference, and returns the feedrate override it asks for: continuous, in percent of the programmed
feed, inside the override table's range. The PMC's quantisation happens after it (see
:mod:`turning_force.core.overrides`); the controllers do not see it, as on a real CNC.

- ``smc``: continuous sliding mode control (Park 1998, Eqs. 5-21).
- ``adaptive``: the conventional adaptive controller Park compares against: an integral
  controller whose gain follows an on-line estimate of the process gain (Masory & Koren 1980).
- ``adaptive_smc``: discrete adaptive sliding mode control with a variable forgetting factor
  (Hwang & Chen 1990, Eqs. 11-39, Remarks 1-2).
- ``adaptive_pp``: Kim's adaptive controller: recursive least squares on an ARMA model (Kim
  Eq. 12) with dead zone and covariance resetting, and a pole-placement controller with
  integral action (a servo-compensator, Kim Eqs. 16-18) redesigned every period.
- ``pi``: fixed-gain PI with anti-windup, what commercial adaptive-feed options run.
"""

from __future__ import annotations

import abc
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from turning_force.core.overrides import get_table
from turning_force.core.settings import Settings, setting

__all__ = [
    'CONTROLLERS',
    'AdaptiveController',
    'AdaptiveSlidingModeController',
    'ControlOutput',
    'Controller',
    'ControllerSettings',
    'PIController',
    'PolePlacementAdaptiveController',
    'SlidingModeController',
    'make_controller',
]

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class ControllerSettings(Settings):
    """The force controller (``force_controller`` parameters)."""

    SECTION = 'force_controller'

    controller: str = setting('smc', 'Control law', choices=('smc', 'adaptive', 'adaptive_smc',
                                                             'adaptive_pp', 'pi'))
    reference_force_n: float = setting(500.0, 'Reference cutting force F_ref', 'N', low=0.0,
                                       low_open=True, high=1e5, dynamic=True)
    control_period_s: float = setting(0.01, 'Control period (Park: 10 ms)', 's', low=1e-4,
                                      high=1.0)
    spindle_speed_rpm: float = setting(600.0, 'Spindle speed N', 'rpm', low=0.0, low_open=True,
                                       high=20000.0)
    programmed_feed_mm_rev: float = setting(0.2, 'Programmed feed (the 100 % override)',
                                            'mm/rev', low=0.0, low_open=True, high=5.0)
    override_table: str = setting('fanuc_0t_4bit', 'Override table; its range bounds the '
                                  'command', choices=('fanuc_0t_4bit', 'fanuc_8bit', 'ideal'))
    initial_override_pct: float = setting(100.0, 'Override before the first update', '%',
                                          low=0.0, high=255.0)
    model_servo_time_constant_s: float = setting(0.17, 'Servo time constant tau_s the '
                                                 'controllers assume (Park Eq. 2)', 's', low=0.0,
                                                 low_open=True, high=10.0)
    model_cutting_time_constant_s: float = setting(0.05, 'Process time constant tau_c the SMC '
                                                   'assumes (Park Eq. 1)', 's', low=0.0,
                                                   low_open=True, high=10.0)
    smc_lambda_per_s: float = setting(20.0, 'Sliding-surface bandwidth lambda (Park Eq. 10), '
                                      'bounded by Eqs. 22-24', '1/s', low=0.0, low_open=True,
                                      dynamic=True)
    smc_eta: float = setting(0.1, 'Reaching-condition margin eta (Park Eq. 14)', 'N/s^2',
                             low=0.0, dynamic=True)
    smc_epsilon_n: float = setting(25.0, 'Boundary-layer width epsilon, the allowed tracking '
                                   'error (Park Eq. 21)', 'N', low=0.0, low_open=True,
                                   dynamic=True)
    smc_ksd_min_n_mm: float = setting(1000.0, 'Smallest K_s d the process may have (Park Eq. 7)',
                                      'N/mm', low=0.0, low_open=True)
    smc_ksd_max_n_mm: float = setting(8000.0, 'Largest K_s d the process may have (Park Eq. 7)',
                                      'N/mm', low=0.0, low_open=True)
    smc_surface: str = setting('park1998', "Sliding surface: Park Eq. 10 (s = e' + lambda e) or "
                               'with integral action (Slotine & Li Sec. 7.1.3)',
                               choices=('park1998', 'integral'))
    smc_resonance_hz: float = setting(0.0, 'Lowest unmodelled structural resonance nu_R for the '
                                      'Eq. 22 bound; 0: none known', 'Hz', low=0.0)
    smc_unmodeled_delay_s: float = setting(0.0, 'Largest unmodelled time delay T_A for the '
                                           'Eq. 23 bound; 0: none', 's', low=0.0)
    adaptive_loop_gain_per_s: float = setting(3.0, 'Closed-loop integral gain the adaptive '
                                              'controller holds (Masory & Koren)', '1/s',
                                              low=0.0, low_open=True, dynamic=True)
    adaptive_estimate_time_constant_s: float = setting(0.05, 'Smoothing of the on-line process '
                                                       'gain estimate', 's', low=0.0)
    asmc_pole: float = setting(0.0, 'Eigenvalue q assigned on the sliding surface (Hwang & Chen '
                               'Eq. 22)', low=-1.0, high=1.0, low_open=True, high_open=True)
    asmc_s_t: float = setting(10.0, 'Forgetting-factor sensitivity s_t = v^2 s_a (Eq. 38)',
                              'N^2', low=0.0, low_open=True)
    asmc_f_min: float = setting(0.1, 'Smallest forgetting factor f_min (Eq. 39)', low=0.0,
                                low_open=True, high=1.0)
    asmc_p0: float = setting(1000.0, 'Initial covariance P(0) = p0 I', low=0.0, low_open=True)
    asmc_theta0: tuple[float, ...] = setting([0.5, 0.0, 10.0, 5.0], 'Initial [-a1, -a2, b1, b2] '
                                             '(Hwang & Chen Example 1, u in mm/s)')
    asmc_b_min: float = setting(1e-3, 'Remark 1: |b| below this is treated as zero', low=0.0,
                                low_open=True)
    asmc_freeze_limit: float = setting(1e3, 'Remark 2: hold u when |A(1)/B(1)| reaches this',
                                       'mm/s per N', low=0.0, low_open=True)
    pp_natural_freq_rad_s: float = setting(6.0, 'Closed-loop natural frequency the pole '
                                           'placement assigns', 'rad/s', low=0.0, low_open=True,
                                           dynamic=True)
    pp_damping: float = setting(0.9, 'Closed-loop damping the pole placement assigns', low=0.0,
                                low_open=True, high=5.0, dynamic=True)
    pp_gain0_n_per_pct: float = setting(8.0, 'Process gain the identification starts from',
                                        'N/%', low=0.0, low_open=True)
    pp_dead_zone_n: float = setting(2.0, 'Prediction errors below this do not update the model '
                                    '(dead zone)', 'N', low=0.0)
    pp_p0: float = setting(100.0, 'Covariance the RLS starts from and is reset to', low=0.0,
                           low_open=True)
    pp_reset_trace: float = setting(1e-2, 'Covariance resetting: when trace(P) falls below '
                                    'this, P is reset to p0 I', low=0.0)
    pi_kp_pct_per_n: float = setting(0.02, 'PI proportional gain', '%/N', low=0.0, dynamic=True)
    pi_ki_pct_per_n_s: float = setting(0.2, 'PI integral gain', '%/(N s)', low=0.0, dynamic=True)

    def check(self) -> None:
        if self.smc_ksd_max_n_mm <= self.smc_ksd_min_n_mm:
            self.fail('smc_ksd_max_n_mm', f'must exceed smc_ksd_min_n_mm '
                                          f'({self.smc_ksd_min_n_mm})')
        if len(self.asmc_theta0) != 4:
            self.fail('asmc_theta0', 'needs four values [-a1, -a2, b1, b2]')
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

    @property
    def programmed_feed_rate_mm_min(self) -> float:
        return self.programmed_feed_mm_rev * self.spindle_speed_rpm


@dataclass(frozen=True)
class ControlOutput:
    """One control decision (the core side of ``FeedCommand``).

    ``error_n`` is ``F - F_ref`` (Park Eq. 9); ``sliding_variable`` is the controller's ``s``
    (0 for controllers that have none).
    """

    override_pct: float
    error_n: float
    sliding_variable: float


class Controller(abc.ABC):
    """Interface of the force controllers.

    ``settings`` may be replaced while cutting (:meth:`retune`); the next :meth:`update` uses the
    new values. Fixed settings (``dynamic=False``) are not to change after construction.
    """

    name: str = ''

    def __init__(self, settings: ControllerSettings) -> None:
        self.settings = settings
        table = get_table(settings.override_table)
        self.min_pct, self.max_pct = table.min_pct, table.max_pct
        self.reset()

    def retune(self, settings: ControllerSettings) -> None:
        """Take new dynamic settings (reference, gains) from the next update on."""
        self.settings = settings

    @abc.abstractmethod
    def reset(self) -> None:
        """Forget all history (new cut)."""

    @abc.abstractmethod
    def update(self, force_n: float, force_rate_n_s: float) -> ControlOutput:
        """One control period: measured force and force rate in, override request out."""

    def _clip(self, pct: float) -> float:
        return min(max(pct, self.min_pct), self.max_pct)

    def _pct(self, feed_rate_mm_min: float) -> float:
        return 100.0 * feed_rate_mm_min / self.settings.programmed_feed_rate_mm_min

    def _feed_rate_mm_min(self, pct: float) -> float:
        return pct / 100.0 * self.settings.programmed_feed_rate_mm_min


def sat(x: float) -> float:
    """Park 1998, Eq. 19."""
    return min(max(x, -1.0), 1.0)


class SlidingModeController(Controller):
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
    """

    name = 'smc'

    def reset(self) -> None:
        self._error_integral_n_s = 0.0

    def update(self, force_n: float, force_rate_n_s: float) -> ControlOutput:
        c = self.settings
        tau_s, tau_c = c.model_servo_time_constant_s, c.model_cutting_time_constant_s
        a1 = -1.0 / (tau_s * tau_c)
        a2 = -(tau_s + tau_c) / (tau_s * tau_c)
        to_b = 1.0 / (tau_s * tau_c * c.spindle_speed_rpm)
        b_min, b_max = c.smc_ksd_min_n_mm * to_b, c.smc_ksd_max_n_mm * to_b
        b_hat = math.sqrt(b_min * b_max)
        lam = c.smc_lambda_per_s
        error = force_n - c.reference_force_n
        f = a1 * force_n + a2 * force_rate_n_s
        if c.smc_surface == 'integral':
            integral = self._error_integral_n_s + error * c.control_period_s
            s = force_rate_n_s + 2.0 * lam * error + lam**2 * integral
            known = f + 2.0 * lam * force_rate_n_s + lam**2 * error
        else:
            s = force_rate_n_s + lam * error
            known = f + lam * force_rate_n_s
        gain = abs(b_hat / b_min - 1.0) * abs(known) + b_hat / b_min * c.smc_eta
        phi = c.smc_epsilon_n * lam
        pct = self._pct((-known - gain * sat(s / phi)) / b_hat)
        if c.smc_surface == 'integral' and self.min_pct <= pct <= self.max_pct:
            self._error_integral_n_s = integral  # no integration while saturated
        return ControlOutput(self._clip(pct), error, s)


class AdaptiveController(Controller):
    """The conventional adaptive force controller (Masory & Koren 1980, as Park compares to).

    An integral controller on the feed whose gain is divided by an on-line estimate of the
    process gain ``K_p = F / f_a`` [N per mm/rev], so that the loop gain stays at
    ``adaptive_loop_gain_per_s`` whatever the depth of cut::

        f_c(k) = f_c(k-1) - G T (F(k) - F_ref) / K_p_hat(k)

    ``f_a`` is the controller's own first-order servo model of its commands; it does not know
    which override level the PMC applied, as a conventional controller does not.
    """

    name = 'adaptive'

    def reset(self) -> None:
        self._pct_cmd = self._clip(self.settings.initial_override_pct)
        self._feed_model_pct = self._pct_cmd
        self._gain_n_per_pct = math.nan

    def update(self, force_n: float, force_rate_n_s: float) -> ControlOutput:
        c = self.settings
        dt = c.control_period_s
        self._feed_model_pct += (self._pct_cmd - self._feed_model_pct) * (
            1.0 - math.exp(-dt / c.model_servo_time_constant_s))
        error = force_n - c.reference_force_n
        # Estimate only where both force and feed are well above zero: a ratio of noise is no
        # gain. The estimate is then held.
        if self._feed_model_pct > 1.0 and force_n > 0.05 * c.reference_force_n:
            measured = force_n / self._feed_model_pct
            if math.isnan(self._gain_n_per_pct):
                self._gain_n_per_pct = measured
            else:
                tau = c.adaptive_estimate_time_constant_s
                weight = 1.0 - math.exp(-dt / tau) if tau > 0 else 1.0
                self._gain_n_per_pct += weight * (measured - self._gain_n_per_pct)
        if not math.isnan(self._gain_n_per_pct):
            step = c.adaptive_loop_gain_per_s * dt * error / self._gain_n_per_pct
            self._pct_cmd = self._clip(self._pct_cmd - step)
        return ControlOutput(self._pct_cmd, error, 0.0)


class AdaptiveSlidingModeController(Controller):
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
    """

    name = 'adaptive_smc'

    def reset(self) -> None:
        c = self.settings
        self.theta = np.array(c.asmc_theta0, dtype=float)
        self._p = c.asmc_p0 * np.eye(4)
        u0 = self._feed_rate_mm_min(self._clip(c.initial_override_pct)) / 60.0
        self._y = [0.0, 0.0]  # y(k-1), y(k-2)
        self._u = [u0, u0]  # u(k-1), u(k-2)
        self.forgetting_factor = 1.0
        self._started = False

    def update(self, force_n: float, force_rate_n_s: float) -> ControlOutput:
        c = self.settings
        y, y_ref = force_n, c.reference_force_n
        if self._started:
            self._estimate(y)
        self._started = True
        u = self._control(y, y_ref)
        u = self._feed_rate_mm_min(self._clip(self._pct(60.0 * u))) / 60.0
        self._y = [y, self._y[0]]
        self._u = [u, self._u[0]]
        return ControlOutput(self._pct(60.0 * u), y - y_ref, self._sliding)

    def _estimate(self, y: float) -> None:
        """Eqs. 33-39."""
        c = self.settings
        phi = np.array([*self._y, *self._u])
        p = self._p
        p_phi = p @ phi
        gain = p_phi / (1.0 + phi @ p_phi)
        error = y - phi @ self.theta
        self.theta = self.theta + gain * error
        ff = 1.0 - (1.0 - phi @ gain) * error**2 / c.asmc_s_t
        self.forgetting_factor = max(ff, c.asmc_f_min)
        self._p = (p - np.outer(gain, phi) @ p) / self.forgetting_factor

    def _control(self, y: float, y_ref: float) -> float:
        """Eqs. 11-32 with Remarks 1-2."""
        c = self.settings
        a1, a2 = -self.theta[0], -self.theta[1]
        b1, b2 = self.theta[2], self.theta[3]
        self._sliding = 0.0
        a_of_1, b_of_1 = 1.0 + a1 + a2, b1 + b2
        hold = self._u[0]
        if abs(b_of_1) < c.asmc_b_min or abs(a_of_1 / b_of_1) >= c.asmc_freeze_limit:
            return hold  # Remark 2
        if abs(b2) >= c.asmc_b_min:
            m = np.array([[b2, -b1], [0.0, 1.0]])  # Eq. 12
        elif abs(b1) >= c.asmc_b_min:
            m = np.array([[b2, -b1], [1.0, 0.0]])  # Remark 1
        else:
            return hold
        a_mat = np.array([[-a1, 1.0], [-a2, 0.0]])
        b_vec = np.array([b1, b2])
        a_bar = m @ a_mat @ np.linalg.inv(m)  # Eq. 14
        if abs(a_bar[0, 1]) < 1e-12:
            return hold  # (a_bar11, a_bar12) not controllable: A and B share a root
        h1 = (a_bar[0, 0] - c.asmc_pole) / a_bar[0, 1]  # Eq. 22
        d = np.array([h1, 1.0]) @ m  # Eq. 23
        u0 = a_of_1 * y_ref / b_of_1  # Eq. 31
        x = np.array([y - y_ref, -a2 * (self._y[0] - y_ref) + b2 * (self._u[0] - u0)])
        self._sliding = float(d @ x)
        return float(u0 - (d @ a_mat @ x) / (d @ b_vec))  # Eqs. 27-29


class PolePlacementAdaptiveController(Controller):
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
    """

    name = 'adaptive_pp'

    def reset(self) -> None:
        c = self.settings
        dt = c.control_period_s
        p1 = math.exp(-dt / c.model_servo_time_constant_s)
        p2 = math.exp(-dt / c.model_cutting_time_constant_s)
        a1, a2 = -(p1 + p2), p1 * p2
        b = c.pp_gain0_n_per_pct * (1 + a1 + a2) / 2
        self.theta = np.array([a1, a2, b, b])
        self._p = c.pp_p0 * np.eye(4)
        u0 = self._clip(c.initial_override_pct)
        self._y = [math.nan, math.nan]   # F(k-1), F(k-2)
        self._u = [u0, u0]               # u(k-1), u(k-2)
        self._du = 0.0                   # u(k-1) - u(k-2)

    def _identify(self, y: float) -> None:
        c = self.settings
        phi = np.array([-self._y[0], -self._y[1], self._u[0], self._u[1]])
        error = y - phi @ self.theta
        if abs(error) <= c.pp_dead_zone_n:
            return
        p_phi = self._p @ phi
        gain = p_phi / (1.0 + phi @ p_phi)
        theta = self.theta + gain * error
        # Projection on what is known of the process: more feed, more force. An estimate with
        # B(1) <= 0 (a transient with the feed held, read as a gain of the wrong sign) would
        # turn the loop around; it is refused.
        if theta[2] + theta[3] <= 0.0 or 1.0 + theta[0] + theta[1] <= 0.0:
            return
        self.theta = theta
        self._p = self._p - np.outer(gain, p_phi)
        if np.trace(self._p) < c.pp_reset_trace:
            self._p = c.pp_p0 * np.eye(4)

    def _design(self) -> tuple[float, FloatArray] | None:
        """(r1, [s0, s1, s2]) solving the Diophantine equation, or None if singular."""
        c = self.settings
        a1, a2, b0, b1 = self.theta
        w, z, dt = c.pp_natural_freq_rad_s, c.pp_damping, c.control_period_s
        if z < 1.0:
            wd = w * math.sqrt(1.0 - z * z)
            m1 = -2.0 * math.exp(-z * w * dt) * math.cos(wd * dt)
        else:
            wd = w * math.sqrt(z * z - 1.0)
            m1 = -2.0 * math.exp(-z * w * dt) * math.cosh(wd * dt)
        m2 = math.exp(-2.0 * z * w * dt)
        # Coefficients of q^-1..q^-4 of A (1 - q^-1) (1 + r1 q^-1) + B (s0 + s1 q^-1 + s2 q^-2).
        matrix = np.array([
            [1.0, b0, 0.0, 0.0],
            [a1 - 1.0, b1, b0, 0.0],
            [a2 - a1, 0.0, b1, b0],
            [-a2, 0.0, 0.0, b1],
        ])
        rhs = np.array([m1 - (a1 - 1.0), m2 - (a2 - a1), a2, 0.0])
        try:
            r1, *s = np.linalg.solve(matrix, rhs)
        except np.linalg.LinAlgError:
            return None
        return float(r1), np.array(s)

    def update(self, force_n: float, force_rate_n_s: float) -> ControlOutput:
        c = self.settings
        y = force_n
        if not math.isnan(self._y[1]):
            self._identify(y)
        design = self._design()
        error = y - c.reference_force_n
        if design is None or math.isnan(self._y[1]):
            u = self._u[0]   # no model yet, or a singular one: hold the feed
        else:
            r1, s = design
            history = [y, self._y[0], self._y[1]]
            du = -r1 * self._du + s.sum() * c.reference_force_n - float(s @ history)
            u = self._clip(self._u[0] + du)
        self._du = u - self._u[0]
        self._y = [y, self._y[0]]
        self._u = [u, self._u[0]]
        return ControlOutput(u, error, 0.0)


class PIController(Controller):
    """Fixed-gain PI on the override with anti-windup by clamping the integral.

    ``pct = I - kp (F - F_ref)``, ``I += -ki (F - F_ref) T``; where the output would pass a
    limit, the integral is set so that it sits on the limit, and it leaves the limit as soon as
    the error changes sign.
    """

    name = 'pi'

    def reset(self) -> None:
        self._integral_pct = self._clip(self.settings.initial_override_pct)

    def update(self, force_n: float, force_rate_n_s: float) -> ControlOutput:
        c = self.settings
        error = force_n - c.reference_force_n
        proportional = -c.pi_kp_pct_per_n * error
        integral = self._integral_pct - c.pi_ki_pct_per_n_s * error * c.control_period_s
        self._integral_pct = min(max(integral, self.min_pct - proportional),
                                 self.max_pct - proportional)
        return ControlOutput(self._clip(self._integral_pct + proportional), error, 0.0)


CONTROLLERS: Mapping[str, Callable[[ControllerSettings], Controller]] = {
    cls.name: cls
    for cls in (SlidingModeController, AdaptiveController, AdaptiveSlidingModeController,
                PolePlacementAdaptiveController, PIController)
}


def make_controller(settings: ControllerSettings) -> Controller:
    """The controller ``settings.controller`` names (validated by the settings)."""
    return CONTROLLERS[settings.controller](settings)
