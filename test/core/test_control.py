"""Controllers against the analysis of their papers."""

import math

import numpy as np
import pytest

from turning_force.core.control import ControllerSettings, make_controller, rls
from turning_force.core.control.laws import adaptive_pp, adaptive_smc
from turning_force.core.errors import ConfigError


def theta(controller):
    """An adaptive law's model estimate (the compiled state's RLS slots)."""
    law = adaptive_pp if controller.name == 'adaptive_pp' else adaptive_smc
    at = law.S_RLS + rls.S_THETA
    return controller.arrays[1][at:at + 4].copy()


def smc_settings(**changes):
    base = {'controller': 'smc', 'override_table': 'ideal', 'smc_surface': 'park1998',
            'quantiser': 'nearest',
            'smc_ksd_min_n_mm': 2000.0, 'smc_ksd_max_n_mm': 7000.0, 'smc_epsilon_n': 25.0}
    return ControllerSettings(**{**base, **changes})


def test_smc_on_the_surface_gives_the_equivalent_control():
    # At F = F_ref, F' = 0 (s = 0) Eq. 20 reduces to v_c = -a1 F / b_hat = F N / (K_s d)_hat:
    # the feed that gives F_ref if K_s d were the geometric mean of its bounds (Eq. 8).
    c = smc_settings()
    out = make_controller(c).update(500.0, 0.0)
    ksd_hat = math.sqrt(2000.0 * 7000.0)
    assert out.override_pct == pytest.approx(100.0 * 500.0 / (ksd_hat * 0.2), rel=1e-12)
    assert out.sliding_variable == 0.0 and out.error_n == 0.0


@pytest.mark.parametrize('b_fraction', [0.0, 0.25, 0.5, 0.75, 1.0])
def test_smc_satisfies_the_sliding_condition_for_every_b_in_its_bounds(b_fraction):
    # Eq. 14: outside the boundary layer s s' <= -eta |s| for any b in [b_min, b_max], where
    # s' = f + b v_c + lambda F' on the Eq. 5 plant. This is what Eqs. 15-16's gain is for.
    c = smc_settings(override_table='fanuc_8bit', smc_eta=5.0)
    controller = make_controller(c)
    tau_s, tau_c, n = 0.17, 0.05, 600.0
    a1, a2 = -1 / (tau_s * tau_c), -(tau_s + tau_c) / (tau_s * tau_c)
    b_min, b_max = 2000 / (tau_s * tau_c * n), 7000 / (tau_s * tau_c * n)
    b = b_min + b_fraction * (b_max - b_min)
    rng = np.random.default_rng(1)
    checked = 0
    for force, rate in zip(rng.uniform(100, 900, 400), rng.uniform(-3000, 3000, 400),
                           strict=True):
        out = controller.update(force, rate)
        s = out.sliding_variable
        if abs(s) <= c.smc_epsilon_n * c.smc_lambda_per_s or out.override_pct in (0.0, 254.0):
            continue  # inside the layer, or the override saturated
        v_c = out.override_pct / 100 * 0.2 * 600
        s_dot = a1 * force + a2 * rate + b * v_c + c.smc_lambda_per_s * rate
        assert s * s_dot <= -c.smc_eta * abs(s) * (1 - 1e-9)
        checked += 1
    assert checked > 100


def test_smc_pushes_the_feed_the_right_way():
    controller = make_controller(smc_settings())
    low, high = controller.update(450.0, 0.0), controller.update(550.0, 0.0)
    on = controller.update(500.0, 0.0)
    assert low.override_pct > on.override_pct > high.override_pct


def test_smc_output_stays_in_the_table_range():
    controller = make_controller(smc_settings(override_table='fanuc_0t_4bit'))
    for force in (0.0, 5000.0, -100.0):
        assert 0.0 <= controller.update(force, 0.0).override_pct <= 150.0


def eq5_closed_loop(controller, ksd_n_mm, seconds=6.0):
    """The Eq. 1-2 plant (tau_s = 0.17 s, tau_c = 0.05 s, 600 rpm) under ``controller``, with
    the exact F and F' fed back every 10 ms; 1 ms Euler steps in between."""
    v_a, force, pct = 120.0, 0.0, 100.0
    for k in range(int(seconds * 1000)):
        f_ss = ksd_n_mm * v_a / 600.0
        rate = (f_ss - force) / 0.05
        if k % 10 == 0:
            pct = controller.update(force, rate).override_pct
        v_a += 1e-3 * (pct / 100 * 120.0 - v_a) / 0.17
        force += 1e-3 * rate
    return force


def test_integral_smc_removes_the_steady_error_of_a_wrong_b_hat():
    # K_s d = 6600 N/mm against b_hat's 3742: Eq. 10's surface settles where
    # K sat(s / Phi) = |a1| F (1 - b_hat / b) (Eq. 20 at rest), an error of about
    # epsilon (1 - b_hat / b) / (beta - 1) = 25 * 0.433 / 0.871 = 12.4 N; the integral surface
    # settles on the reference.
    def settle(surface):
        controller = make_controller(smc_settings(smc_surface=surface))
        return eq5_closed_loop(controller, 6600.0) - 500.0
    assert abs(settle('integral')) < 0.01
    assert settle('park1998') == pytest.approx(25 * (1 - math.sqrt(14e6) / 6600)
                                               / (math.sqrt(3.5) - 1), rel=0.02)


def test_adaptive_loop_gain_does_not_depend_on_the_process_gain():
    # Masory & Koren: dividing the integral gain by the estimated process gain makes the
    # normalised error response the same for any K_s d (here 3x apart), to rounding.
    def response(gain_n_per_pct):
        c = ControllerSettings(controller='adaptive', override_table='ideal',
                               initial_override_pct=400.0 / gain_n_per_pct)
        controller = make_controller(c)
        pct, errors = c.initial_override_pct, []
        for _ in range(300):
            force = gain_n_per_pct * pct
            errors.append((force - 500.0) / 500.0)
            pct = controller.update(force, 0.0).override_pct
        return np.array(errors)
    low, high = response(4.4), response(13.2)
    np.testing.assert_allclose(low, high, atol=1e-9)
    assert abs(low[-1]) < 1e-3


def arma_plant(theta, y1, y2, u1, u2):
    return theta[0] * y1 + theta[1] * y2 + theta[2] * u1 + theta[3] * u2


def run_asmc(true_theta, **changes):
    # u in mm/s: pct / 100 * f_prog * N / 60; ideal table up to 150 %, N = 900, f_prog = 0.5.
    c = ControllerSettings(controller='adaptive_smc', override_table='ideal',
                           spindle_speed_rpm=900.0, programmed_feed_mm_rev=0.5,
                           reference_force_n=1000.0, **changes)
    controller = make_controller(c)
    to_u = 0.5 * 900.0 / 60.0 / 100.0
    y, u = [0.0, 0.0], [0.0, 0.0]
    outputs = []
    for _ in range(60):
        force = arma_plant(true_theta, y[0], y[1], u[0], u[1])
        pct = controller.update(force, 0.0).override_pct
        y, u = [force, y[0]], [pct * to_u, u[0]]
        outputs.append(force)
    return np.array(outputs), controller


TRUE_THETA = np.array([0.6, -0.1, 40.0, 25.0])   # -a1, -a2, b1, b2; DC gain 130 N per mm/s


def test_asmc_with_the_true_model_is_deadbeat():
    # q = 0 and the exact model: s(k+1) = 0 after one step and the reduced dynamics are
    # deadbeat, so y reaches y_r within three samples and stays (Eqs. 22, 27-32). P(0) = 1e-9 I
    # all but freezes the estimate; what it still moves costs less than 1 ppm.
    outputs, _ = run_asmc(TRUE_THETA, asmc_theta0=tuple(TRUE_THETA), asmc_p0=1e-9)
    np.testing.assert_allclose(outputs[4:], 1000.0, rtol=1e-6)


def test_asmc_learns_the_plant_from_hwang_and_chens_initial_guess():
    outputs, controller = run_asmc(TRUE_THETA)
    assert abs(outputs[-10:] - 1000.0).max() < 1.0
    # DC gain B(1)/A(1) identified (the individual parameters need not be).
    t = theta(controller)
    assert (t[2] + t[3]) / (1 - t[0] - t[1]) == pytest.approx(130.0, rel=0.01)


def test_pi_anti_windup_leaves_saturation_at_once():
    c = ControllerSettings(controller='pi', override_table='fanuc_0t_4bit')
    controller = make_controller(c)
    for _ in range(1000):  # force far below the reference: the request saturates at 150 %
        out = controller.update(100.0, 0.0)
    assert out.override_pct == 150.0
    # Once the force is above the reference, the request drops below the maximum immediately.
    assert controller.update(600.0, 0.0).override_pct < 150.0


@pytest.mark.parametrize('name', ['smc', 'adaptive', 'adaptive_smc', 'adaptive_pp', 'pi'])
def test_controllers_are_chosen_by_name(name):
    controller = make_controller(ControllerSettings(controller=name))
    assert controller.name == name
    assert math.isfinite(controller.update(400.0, 10.0).override_pct)


def test_retune_takes_the_new_reference_at_the_next_update():
    controller = make_controller(smc_settings())
    before = controller.update(500.0, 0.0)
    controller.retune(controller.settings.replace(reference_force_n=400.0))
    after = controller.update(500.0, 0.0)
    assert before.error_n == 0.0 and after.error_n == 100.0
    assert after.override_pct < before.override_pct


def test_pole_placement_design_puts_the_poles_where_asked():
    # With the model known, A (1 - q^-1) R + B S must equal A_m: the closed loop's poles are
    # those of a 6 rad/s, 0.9 damping loop sampled at 10 ms (two more at the origin).
    c = ControllerSettings(controller='adaptive_pp', override_table='ideal')
    controller = make_controller(c)
    a1, a2, b0, b1 = theta(controller)
    solution = np.empty(4)
    assert adaptive_pp.pp_design(controller.arrays[0], a1, a2, b0, b1, solution)
    r1, *s = solution
    closed = np.polymul(np.polymul([1, a1, a2], [1, -1]), [1, r1])
    closed = np.polyadd(closed, np.polymul([0, b0, b1], s))
    wd = 6.0 * math.sqrt(1 - 0.81)
    m1 = -2 * math.exp(-0.9 * 6.0 * 0.01) * math.cos(wd * 0.01)
    m2 = math.exp(-2 * 0.9 * 6.0 * 0.01)
    np.testing.assert_allclose(closed, [1, m1, m2, 0, 0], atol=1e-12)
    # A and B with a common root (B = b (1 - 0.5 q^-1), A = (1 - 0.5 q^-1)(1 - 0.2 q^-1)):
    # the system is singular, and the law holds its feed rather than divide by it.
    assert not adaptive_pp.pp_design(controller.arrays[0], -0.7, 0.1, 1.0, -0.5, solution)


def test_pole_placement_adaptive_settles_on_the_reference():
    # A second-order ARMA plant far from the initial guess (gain 13 N/% against 8): the
    # integral action gives zero steady error, and the RLS finds the static gain.
    true = np.array([-1.7, 0.75, 0.4, 0.25])   # a1, a2, b0, b1: gain 0.65 / 0.05 = 13 N/%
    c = ControllerSettings(controller='adaptive_pp', override_table='ideal',
                           reference_force_n=500.0)
    controller = make_controller(c)
    y, u = [0.0, 0.0], [100.0, 100.0]
    for _ in range(1500):
        force = -true[0] * y[0] - true[1] * y[1] + true[2] * u[0] + true[3] * u[1]
        pct = controller.update(force, 0.0).override_pct
        y, u = [force, y[0]], [pct, u[0]]
    assert y[0] == pytest.approx(500.0, abs=0.5)
    a1, a2, b0, b1 = theta(controller)
    assert (b0 + b1) / (1 + a1 + a2) == pytest.approx(13.0, rel=0.05)


# --- state that never recovers (issue: faults and bad input) ---------------------------------

@pytest.mark.parametrize('name', ['adaptive_smc', 'adaptive_pp', 'smc', 'adaptive', 'pi', 'mpc'])
@pytest.mark.parametrize('absurd_n', [1e300, -1e300, math.inf, math.nan])
def test_a_law_recovers_from_an_absurd_force(name, absurd_n):
    # Before: adaptive_smc and adaptive_pp requested NaN forever after a force of +-1e300 N
    # (the RLS squares the prediction error). Every request stays finite and in range, and the
    # law returns to regulating: after the bad sample it behaves like a law that was reset.
    c = ControllerSettings(controller=name, override_table='ideal')
    controller = make_controller(c)
    for _ in range(20):
        controller.update(450.0, 0.0)
    out = controller.update(absurd_n, 0.0)
    assert math.isfinite(out.override_pct) and 0.0 <= out.override_pct <= 150.0
    requests = [controller.update(450.0 + k, 0.0).override_pct for k in range(40)]
    assert all(math.isfinite(r) and 0.0 <= r <= 150.0 for r in requests)
    if name in ('adaptive_smc', 'adaptive_pp'):
        assert np.all(np.isfinite(theta(controller)))
    if not math.isfinite(absurd_n):
        assert controller.resets == 1


def rls_arrays(theta0, p0, **options):
    """The compiled estimator's parameters (as the adaptive laws fill them) and state, at
    offset 0 in arrays of their own."""
    p = np.array(rls.params(theta0, p0, **options))
    s = np.zeros(rls.STATE)
    rls.restart(p, s, 0, 0)
    return p, s


def fit(p, s, *phi_y):
    rls.update(p, s, 0, 0, *phi_y)


def test_rls_restarts_on_non_finite_data_and_fits_again():
    # y = 2 x1 - 3 x2 + 0.5 x3 + x4, noise-free: RLS with a large P0 fits it in a few samples.
    p, s = rls_arrays([0.0] * 4, 1e6)
    true = np.array([2.0, -3.0, 0.5, 1.0])
    rng = np.random.default_rng(3)
    for _ in range(12):
        phi = rng.normal(size=4)
        fit(p, s, *phi, float(phi @ true))
    np.testing.assert_allclose(s[rls.S_THETA:rls.S_THETA + 4], true, rtol=1e-6)
    fit(p, s, 1.0, math.nan, 0.0, 0.0, 1.0)
    assert s[rls.S_RESTARTS] == 1 and np.all(s[rls.S_THETA:rls.S_THETA + 4] == 0.0)
    for _ in range(12):
        phi = rng.normal(size=4)
        fit(p, s, *phi, float(phi @ true))
    np.testing.assert_allclose(s[rls.S_THETA:rls.S_THETA + 4], true, rtol=1e-6)


def test_rls_dead_zone_and_projection_leave_the_model_alone():
    p, s = rls_arrays([1.0, 0.0, 0.0, 0.0], 100.0, dead_zone=0.5)
    fit(p, s, 1.0, 0.0, 0.0, 0.0, 1.4)     # error 0.4: inside the dead zone
    assert s[rls.S_THETA] == 1.0
    fit(p, s, 1.0, 0.0, 0.0, 0.0, 2.0)
    assert s[rls.S_THETA] > 1.0
    # The projection: theta = [a1, a2, b0, b1] must keep B(1) > 0 and A(1) > 0.
    p, s = rls_arrays([-0.5, 0.0, 1.0, 1.0], 100.0, positive_static_gain=True)
    fit(p, s, 0.0, 0.0, 1.0, 1.0, -50.0)   # would turn B(1) negative
    np.testing.assert_array_equal(s[rls.S_THETA:rls.S_THETA + 4], [-0.5, 0.0, 1.0, 1.0])
    fit(p, s, 0.0, 0.0, 1.0, 1.0, 3.0)     # B(1) stays positive: taken
    assert s[rls.S_THETA + 2] + s[rls.S_THETA + 3] > 2.0


def test_the_settings_choices_are_the_registry():
    from turning_force.core.control import CONTROLLERS

    assert ControllerSettings.fields()['controller'][1].choices == tuple(CONTROLLERS)
    for name, law in CONTROLLERS.items():
        assert law.name == name


@pytest.mark.parametrize(('changes', 'message'), [
    # Before: gains of 1e308 were accepted.
    ({'pi_kp_pct_per_n': 1e308}, r'pi_kp_pct_per_n = 1e\+308: outside \[0, 10\]'),
    ({'pi_ki_pct_per_n_s': 1e308}, r'outside \[0, 100\]'),
    ({'smc_eta': 1e308}, r'smc_eta = 1e\+308: outside'),
    ({'smc_epsilon_n': 6000.0}, r'smc_epsilon_n = 6000.0: not below max_feed_force_n'),
    ({'reference_force_n': 5000.0}, r'reference_force_n = 5000.0: not below max_feed_force_n'),
    ({'adaptive_loop_gain_per_s': 150.0}, r'above 1 / control_period_s \(100 1/s\)'),
    ({'pp_natural_freq_rad_s': 400.0}, r'not below the Nyquist rate'),
    ({'initial_override_pct': 200.0}, r'initial_override_pct = 200.0: outside the fanuc_0t_4bit'),
    ({'asmc_theta0': (1e308, 0.0, 1.0, 1.0)}, r'asmc_theta0 = .*: outside'),
])
def test_gains_and_forces_are_bounded(changes, message):
    with pytest.raises(ConfigError, match=message):
        ControllerSettings(**changes)


@pytest.fixture
def installed(monkeypatch):
    """Pretend other distributions install the laws given: (name, module, distribution)."""
    from turning_force.core.control import registry

    def install(*laws):
        monkeypatch.setattr(registry, 'installed_laws', lambda: laws)
        registry.law_modules.cache_clear()
        registry._law.cache_clear()
        return registry

    yield install
    monkeypatch.undo()
    registry.law_modules.cache_clear()
    registry._law.cache_clear()


def test_an_installed_law_may_not_take_a_name_of_ours(installed):
    registry = installed(('smc', 'their_package.smc', 'their-dist'))
    with pytest.raises(ConfigError, match=r"smc = their_package.smc \(from their-dist\): the law "
                                          r"'smc' is already turning_force.core.control.laws.smc"):
        registry.names()


@pytest.mark.parametrize(('module', 'message'), [
    ('json', r"control law 'broken' \(json\): no LAW = "),
    ('turning_force.core.control.laws.pi', r"its LAW is named 'pi'"),
    ('no_such_module_anywhere', r'its module no_such_module_anywhere does not import'),
])
def test_an_installed_law_that_is_not_one_is_refused_by_name(installed, module, message):
    registry = installed(('broken', module, 'their-dist'))
    assert registry.names()[-1] == 'broken'
    with pytest.raises(ConfigError, match=message):
        registry.CONTROLLERS['broken']
