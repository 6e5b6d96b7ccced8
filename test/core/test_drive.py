"""Feed-drive relations: d-q transform, friction (Park Eq. 25), current-force map (Eq. 26)."""

import math

import numpy as np
import pytest

from turning_force.core.errors import ConfigError
from turning_force.core.plant.drive import (
    CurrentForceMap,
    FrictionModel,
    clarke_park,
    inverse_park_clarke,
    rotor_angle_rad,
)


def test_dq_transform_inverts_exactly():
    rng = np.random.default_rng(0)
    angle = rng.uniform(0, 2 * math.pi, 500)
    d, q = rng.normal(size=500), rng.normal(size=500)
    u, v = inverse_park_clarke(d, q, angle)
    d2, q2 = clarke_park(u, v, angle)
    np.testing.assert_allclose(d2, d, atol=1e-12)
    np.testing.assert_allclose(q2, q, atol=1e-12)


def test_constant_torque_current_gives_balanced_sinusoids():
    # Field-oriented: i_d = 0, i_q = 2 A; the phases are sinusoids of amplitude 2 A, 120 deg apart.
    angle = np.linspace(0, 2 * math.pi, 361)
    u, v = inverse_park_clarke(np.zeros_like(angle), np.full_like(angle, 2.0), angle)
    np.testing.assert_allclose(u, -2.0 * np.sin(angle), atol=1e-12)
    np.testing.assert_allclose(v, -2.0 * np.sin(angle - 2 * math.pi / 3), atol=1e-12)


def test_rotor_angle_turns_pole_pairs_times_per_screw_revolution():
    # 12 mm pitch: 3 mm is a quarter turn of the screw, a full electrical turn for 4 pole pairs.
    angle = rotor_angle_rad(np.array([0.0, 1.5, 3.0]), 12.0, 4)
    np.testing.assert_allclose(angle, [0.0, math.pi, 0.0], atol=1e-12)


def test_friction_curve_passes_its_end_points_with_vertex_at_slowest_feed():
    model = FrictionModel.from_end_points(6.0, 300.0, 0.6, 0.35)
    at = model.current_a(np.array([6.0, 300.0, 6.0 + 1e-6, 1000.0]))
    np.testing.assert_allclose(at[:2], [0.6, 0.35])
    assert at[2] == pytest.approx(0.6, abs=1e-12)   # zero slope at v_min (Eq. 25's vertex)
    assert at[3] == pytest.approx(0.35)             # held beyond the calibrated range


def test_friction_opposes_motion_and_vanishes_at_standstill():
    model = FrictionModel.from_end_points(6.0, 300.0, 0.6, 0.35)
    at = model.current_a(np.array([-100.0, 100.0, 0.0, 3.0]))
    assert at[0] == -at[1] and at[1] > 0
    assert at[2] == 0.0
    assert at[3] == pytest.approx(0.3)   # half of v_min: half of the friction


def test_friction_calibration_recovers_eq25_from_several_feeds():
    truth = FrictionModel.from_end_points(10.0, 200.0, 0.8, 0.4)
    feeds = np.array([10.0, 50.0, 100.0, 150.0, 200.0])
    fitted = FrictionModel.calibrate(feeds, truth.current_a(feeds))
    assert fitted.a_a_per_mm_min2 == pytest.approx(truth.a_a_per_mm_min2, rel=1e-9)
    assert fitted.b_a == pytest.approx(truth.b_a, rel=1e-9)


@pytest.mark.parametrize(('feeds', 'currents', 'match'), [
    ([100.0], [0.5], 'two or more distinct'),
    ([100.0, 100.0], [0.5, 0.5], 'two or more distinct'),
    ([100.0, 200.0], [0.5], 'do not pair up'),
    ([100.0, 200.0], [0.5, math.nan], 'finite'),
])
def test_friction_calibration_rejects_what_cannot_fit(feeds, currents, match):
    with pytest.raises(ConfigError, match=match):
        FrictionModel.calibrate(feeds, currents)


def test_park_eq26_current_force_map():
    eq26 = CurrentForceMap()
    assert eq26.current_a(np.array(500.0)) == pytest.approx(-0.12432 + 0.00629 * 500)
    # Eq. 26's slope is 1 / 0.00629 = 159 N per ampere (the paper's text rounds it to "about
    # 145 N"); we hold the equation, not the prose.
    np.testing.assert_allclose(eq26.force_n(eq26.current_a(np.array([0.0, 100.0]))), [0, 100])


def test_current_force_map_needs_a_positive_slope():
    with pytest.raises(ConfigError, match=r'current_per_force_a_n = 0\.0'):
        CurrentForceMap(0.0, 0.0)
