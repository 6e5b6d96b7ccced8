"""The plant against the closed-form responses of its equations (Park Eqs. 1-2, 25-26;
Hwang & Chen Eqs. 1-3)."""

import math

import numpy as np
import pytest

from turning_force.core.plant.drive import clarke_park
from turning_force.core.plant.lathe import LathePlant
from turning_force.core.plant.settings import DepthProfile, PlantSettings

QUIET = {'current_noise_a': 0.0}


def run(settings, overrides_pct, samples_per_block=10):
    plant = LathePlant(settings, samples_per_block, initial_override_pct=overrides_pct[0])
    blocks = [plant.step(p) for p in overrides_pct]
    cat = lambda f: np.concatenate([f(b) for b in blocks])  # noqa: E731
    return blocks, cat


def test_steady_force_is_ks_d_f():
    # Park Eq. 1 at DC: F = K_s d v_a / N; with d = 2 mm, 100 % of 0.2 mm/rev: 2200 * 2 * 0.2.
    s = PlantSettings(depth_times_s=(0.0,), depth_mm=(2.0,), **QUIET)
    blocks, _ = run(s, [100.0] * 200)
    assert blocks[-1].force_n[-1] == pytest.approx(2200 * 2 * 0.2, rel=1e-6)


def test_power_law_force():
    # Hwang & Chen Eq. 3: y = d k_f f^g.
    s = PlantSettings(specific_cutting_force_n_mm2=1533.3, cutting_exponent=0.95,
                      cutting_time_constant_s=0.0, depth_times_s=(0.0,), depth_mm=(3.0,),
                      **QUIET)
    blocks, _ = run(s, [50.0] * 100)
    assert blocks[-1].force_n[-1] == pytest.approx(3.0 * 1533.3 * 0.1**0.95, rel=1e-6)


def test_servo_reaches_63_percent_at_its_time_constant():
    # Park Eq. 2, tau_s = 0.17 s: after an override step 100 -> 50 %, v_a has gone 63.2 % of the
    # way at t = tau_s. Exact ZOH discretisation, so to within rounding at 1 kHz.
    s = PlantSettings(**QUIET)
    _, cat = run(s, [100.0] + [50.0] * 60)
    feed = cat(lambda b: b.currents.feed_rate_mm_min)
    v0, v1 = 120.0, 60.0
    k = 10 + 170  # first block at 100 %, then 170 samples
    assert (v0 - feed[k]) / (v0 - v1) == pytest.approx(1 - math.exp(-1), abs=2e-3)


def test_cutting_lag_after_a_depth_step():
    # Depth 1 -> 2 mm at t = 0.5 s with the feed steady: F rises with tau_c = 0.05 s.
    s = PlantSettings(depth_times_s=(0.0, 0.5), depth_mm=(1.0, 2.0), **QUIET)
    _, cat = run(s, [100.0] * 100)
    force = cat(lambda b: b.force_n)
    f1, f2 = 2200 * 0.2, 2200 * 2 * 0.2
    assert force[499] == pytest.approx(f1, rel=1e-4)
    assert (force[500 + 50] - f1) / (f2 - f1) == pytest.approx(1 - math.exp(-1), abs=0.03)


def test_pmc_dead_time_delays_the_feed():
    s = PlantSettings(pmc_dead_time_s=0.08, **QUIET)
    _, cat = run(s, [100.0] * 5 + [50.0] * 20)
    feed = cat(lambda b: b.currents.feed_rate_mm_min)
    change = np.flatnonzero(np.abs(feed - 120.0) > 1e-9)[0]
    assert change == 50 + 80 + 1  # commanded at sample 50, seen 80 samples later, one-sample ZOH


def test_second_order_servo_overshoot():
    # Hwang & Chen Eq. 1 with xi = 0.7: peak overshoot exp(-pi xi / sqrt(1 - xi^2)) = 4.6 %.
    s = PlantSettings(servo_model='second_order', **QUIET)
    _, cat = run(s, [100.0] + [50.0] * 30)
    feed = cat(lambda b: b.currents.feed_rate_mm_min)
    overshoot = (60.0 - feed.min()) / 60.0
    assert overshoot == pytest.approx(math.exp(-math.pi * 0.7 / math.sqrt(1 - 0.49)), abs=1e-3)


def test_phase_currents_carry_force_and_friction():
    # Without noise the d-q transform of the simulated phases gives back Eq. 26 + Eq. 25 exactly.
    s = PlantSettings(**QUIET)
    _, cat = run(s, [100.0] * 50)
    u, v = cat(lambda b: b.currents.phase_u_a), cat(lambda b: b.currents.phase_v_a)
    angle = cat(lambda b: b.currents.rotor_angle_rad)
    d, q = clarke_park(u, v, angle)
    feed, force = cat(lambda b: b.currents.feed_rate_mm_min), cat(lambda b: b.force_n)
    expected = s.current_map.current_a(force) + s.friction.current_a(feed)
    np.testing.assert_allclose(q, expected, atol=1e-12)
    np.testing.assert_allclose(d, 0.0, atol=1e-12)
    assert np.ptp(angle) > 1.0  # the rotor turns: the phases are not DC


def test_same_seed_same_noise_other_seed_other_noise():
    a = run(PlantSettings(seed=7), [100.0] * 5)[1](lambda b: b.currents.phase_u_a)
    b = run(PlantSettings(seed=7), [100.0] * 5)[1](lambda b: b.currents.phase_u_a)
    c = run(PlantSettings(seed=8), [100.0] * 5)[1](lambda b: b.currents.phase_u_a)
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)


def test_depth_profile_steps_and_taper():
    steps = DepthProfile((0.0, 4.0, 8.0), (1.0, 2.0, 3.0))
    np.testing.assert_array_equal(steps.at(np.array([0.0, 3.99, 4.0, 9.0])), [1, 1, 2, 3])
    assert steps.change_times_s() == (4.0, 8.0)
    taper = DepthProfile((0.0, 1.0, 9.0), (1.0, 1.0, 2.0), 'linear')
    np.testing.assert_allclose(taper.at(np.array([0.5, 5.0, 10.0])), [1.0, 1.5, 2.0])
    assert taper.change_times_s() == (1.0,)


def test_feed_reading_noise_leaves_the_truth_alone():
    # The DAQ's feed reading (an encoder differentiated) carries noise of the set standard
    # deviation; the feed the cut sees does not. 10,000 samples: the sample deviation's own
    # spread is sigma / sqrt(2 n) = 0.7 %, so 3 % is more than four of it.
    quiet = PlantSettings(depth_times_s=(0.0,), depth_mm=(1.0,), **QUIET)
    noisy = PlantSettings(depth_times_s=(0.0,), depth_mm=(1.0,), feed_noise_mm_min=2.0, **QUIET)
    _, cat_q = run(quiet, [100.0] * 1000)
    _, cat_n = run(noisy, [100.0] * 1000)
    read = lambda b: b.currents.feed_rate_mm_min  # noqa: E731
    np.testing.assert_array_equal(cat_n(lambda b: b.force_n), cat_q(lambda b: b.force_n))
    np.testing.assert_array_equal(cat_n(lambda b: b.currents.phase_u_a),
                                  cat_q(lambda b: b.currents.phase_u_a))
    assert np.std(cat_n(read) - cat_q(read)) == pytest.approx(2.0, rel=0.03)


@pytest.mark.parametrize('noise', [
    {'current_noise_a': 0.05},
    {'current_noise_a': 0.05, 'feed_noise_mm_min': 1.0},
    {'current_noise_a': 0.0, 'feed_noise_mm_min': 1.0},
    {'current_noise_a': 0.05, 'force_noise_fraction': 0.02},
    {'current_noise_a': 0.05, 'force_noise_fraction': 0.02, 'feed_noise_mm_min': 1.0},
])
def test_noise_drawn_in_stretches_equals_noise_drawn_block_by_block(noise):
    # The compiled loop draws a stretch of blocks' noise at once, a node one block at a time:
    # the same seed must give the same numbers either way.
    s = PlantSettings(**noise)
    whole = LathePlant(s, 10).draw_noise(7)
    one = LathePlant(s, 10)
    parts = [one.draw_noise(1) for _ in range(7)]
    for j, drawn in enumerate(whole):
        np.testing.assert_array_equal(drawn, np.concatenate([p[j] for p in parts]))
