"""The commissioning staircase: a law that plays a script through the same chain as the others."""

from __future__ import annotations

import math

import numpy as np
import pytest

from turning_force.core.control import CONTROLLERS, ControllerSettings, make_controller
from turning_force.core.errors import ConfigError
from turning_force.core.experiment import load_experiment
from turning_force.core.kernel.simulate import simulate


def staircase(**changes):
    return make_controller(ControllerSettings(controller='staircase', **changes))


def test_registered_as_a_law():
    from turning_force.core.control.laws import staircase as module

    assert CONTROLLERS['staircase'] is module.LAW
    assert staircase().name == 'staircase'


def test_plays_each_level_for_its_step_and_repeats():
    law = staircase(staircase_levels_pct=(50.0, 130.0, 90.0), staircase_step_s=0.03)
    played = [law.update(400.0, 0.0).override_pct for _ in range(11)]
    assert played == [50.0] * 3 + [130.0] * 3 + [90.0] * 3 + [50.0] * 2


def test_ignores_the_force_and_keeps_its_place_through_a_bad_sample():
    law = staircase(staircase_levels_pct=(50.0, 130.0), staircase_step_s=0.02)
    assert law.update(0.0, 0.0).override_pct == 50.0
    held = law.update(math.nan, 0.0)              # the guard holds the last request ...
    assert held.override_pct == 50.0 and law.resets == 1
    # ... and the script goes on where it was (a reset does not restart it): the NaN period was
    # not a command, so the second 50 % period comes now, then 130 %.
    assert [law.update(f, 0.0).override_pct for f in (1e4, -3.0, 7.0)] == [50.0, 130.0, 130.0]
    assert law.update(700.0, 0.0).error_n == pytest.approx(200.0)   # F - F_ref, reported


@pytest.mark.parametrize(('changes', 'message'), [
    ({'staircase_levels_pct': (50.0, 160.0)}, r'\[160.0\] outside the fanuc_0t_4bit range'),
    ({'staircase_levels_pct': ()}, 'needs at least one level'),
    ({'staircase_step_s': 0.015}, 'not a whole number of control periods'),
    ({'staircase_step_s': 0.005}, 'not a whole number of control periods'),
])
def test_settings_refuse_a_script_the_pmc_cannot_play(changes, message):
    with pytest.raises(ConfigError, match=message):
        ControllerSettings(controller='staircase', **changes)
    ControllerSettings(controller='smc', **changes)   # only the staircase reads them


def test_commissioning_runs_the_script_through_the_gate(experiments_dir):
    experiment = load_experiment(experiments_dir / 'commissioning.yaml')
    trace = simulate(experiment).trace
    applied = trace['applied_override_pct']
    levels = experiment.controller.staircase_levels_pct
    # The first command answers block 0; the PMC applies it from block 1 on, 100 blocks a level.
    assert applied[0] == 100.0
    expected = np.array([levels[(k - 1) // 100 % len(levels)] for k in range(1, applied.size)])
    np.testing.assert_array_equal(applied[1:], expected)
    # An air move, then the cut: no force before 10.5 s, force at every level after.
    t, force = trace['t_s'], trace['force_n']
    assert np.all(force[t <= 10.5] == 0.0) and np.all(force[t > 10.8] > 60.0)
