"""The drift monitor (issue 16 item 2): commissioned on a machine, cutting after it changed, the
loop says what drifted and by how much, within 5 s of cutting; on a machine that did not
change, it says nothing.

The machine is Park's Fig. 8 lathe with Kim's 80 ms PMC dead time, commissioned the user's way
(the commissioning experiment recorded on the core loop, ``identify`` on it); the job a 2 mm
cut of 6 s at the product's quantiser, with the identified model and the monitor's settings
that ``identify`` writes. The drifts are the issue's: dead time +50 %, process gain +40 %,
feed friction +25 %, servo time constant x1.8.
"""

from __future__ import annotations

import re

import pytest

from turning_force.commands import population
from turning_force.core.control.drift import CAUSES
from turning_force.core.experiment import Experiment
from turning_force.core.kernel.simulate import simulate

DEPTH_MM = 2.0
MACHINE = population.Machine(0, 0, {
    'seed': 1, 'pmc_dead_time_s': 0.08, 'cutting_exponent': 1.0,
    'specific_cutting_force_n_mm2': 2200.0, 'current_noise_a': 0.02,
    'force_noise_fraction': 0.0, 'spindle_speed_rpm': 600.0, 'cutting_time_constant_s': 0.05,
    'servo_model': 'first_order', 'servo_time_constant_s': 0.17}, 'steps')
JOB = ['lathe_sim.depth_times_s=[0.0]', f'lathe_sim.depth_mm=[{DEPTH_MM!r}]',
       'experiment.duration_s=6.0', 'force_controller.quantiser=error_feedback']


@pytest.fixture(scope='module')
def commissioned() -> list[str]:
    """The identified model and the monitor's settings for a job cutting DEPTH_MM deep."""
    ident, cut_depth = population.identify_machine(MACHINE)
    identified, monitor = population.identified_sets(MACHINE, ident, cut_depth,
                                                     (DEPTH_MM, DEPTH_MM))
    return identified + monitor


def job(commissioned: list[str], *drift: str) -> Experiment:
    return population.job_experiment(MACHINE).with_sets([*JOB, *commissioned, *drift])


@pytest.mark.parametrize(('drift', 'cause', 'size', 'tolerance'), [
    # the bank's dead times are a control period (10 ms) apart: the reading is within one
    (['lathe_sim.pmc_dead_time_s=0.12'], 'PMC dead time', 0.04, 0.01),
    # K_s d is identified to 0.01 %, and the monitor's gain is the ratio of two means of
    # hundreds of samples of a 1 % noise: 2 % covers both with a wide margin
    (['lathe_sim.specific_cutting_force_n_mm2=3080.0'], 'process gain', 0.40, 0.02),
    # the bank's time scales are x1.2 apart: the reading is within one step
    (['lathe_sim.servo_time_constant_s=0.306'], 'servo', 1.8, 1.8 * 0.2),
])
def test_the_monitor_names_what_drifted_within_5_s_of_cutting(
        commissioned: list[str], drift: list[str], cause: str, size: float,
        tolerance: float) -> None:
    result = simulate(job(commissioned, *drift))
    named = result.trace['drift_alarm']
    assert named.any(), 'no drift alarm'
    first = named.argmax()
    assert CAUSES[int(named[first])] == cause, result.drift
    assert result.metrics['drift_alarm_s'] <= 5.0
    assert result.trace['drift_size'][-1] == pytest.approx(size, abs=tolerance), result.drift
    assert result.metrics['drift_alarms'] == 1.0   # one cause, named once
    assert result.drift.startswith(cause) and result.drift.endswith(
        're-commission (identify this session)')


def test_a_friction_drift_is_read_within_5_s_of_cutting(commissioned: list[str]) -> None:
    # The estimator subtracts the identified friction: 25 % more adds a quarter of it (about
    # 22 N of its 89 N at the programmed feed) to the estimate. In a cut at one depth and
    # feed that level is all there is to see, and a 5 % process gain gives the same level:
    # the alarm reads it as both, the better fit first, and says what would tell them apart.
    result = simulate(job(commissioned, 'lathe_sim.friction_at_min_feed_a=0.75',
                          'lathe_sim.friction_at_max_feed_a=0.4375'))
    assert result.metrics['drift_alarm_s'] <= 5.0
    assert CAUSES[int(result.trace['drift_alarm'][-1])] in ('friction', 'process gain')
    found = re.search(r'friction ([+-]\d+) %', result.drift)
    assert found is not None, result.drift
    # 25 % of the friction, read through the identified friction curve and the 0.7 % model
    # error the identification left on the force (4 N of 500 N, 5 % of the friction's 89 N)
    assert int(found.group(1)) == pytest.approx(25, abs=5)
    assert 'an air move re-zeroes the friction' in result.drift


def test_no_drift_alarm_on_the_machine_as_commissioned(commissioned: list[str]) -> None:
    result = simulate(job(commissioned))
    assert not result.trace['drift_alarm'].any(), result.drift
    assert result.metrics['drift_alarms'] == 0.0 and result.drift == ''


def test_the_monitor_is_off_without_an_identified_model() -> None:
    result = simulate(population.job_experiment(MACHINE).with_sets(
        [*JOB, 'lathe_sim.pmc_dead_time_s=0.12']))
    assert not result.trace['drift_alarm'].any()
    assert 'drift_alarms' not in result.metrics


def test_no_drift_alarm_on_the_population_machines_that_do_not_drift() -> None:
    # The generator's first machine that keeps its parameters between commissioning and the
    # job, commissioned and cut on its own job (bench_drift.py runs many).
    steady = [m for m in population.draw(12, seed=16) if not m.drift][:1]
    for machine in steady:
        ident, cut_depth = population.identify_machine(machine)
        identified, monitor = population.identified_sets(machine, ident, cut_depth)
        result = simulate(population.job_experiment(machine).with_sets(identified + monitor))
        assert not result.trace['drift_alarm'].any(), f'{machine.describe()}: {result.drift}'
