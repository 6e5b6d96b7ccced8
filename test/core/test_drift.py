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

import dataclasses
import math
import re
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import yaml
from test_batch import assert_same_chain, stepped

from turning_force.commands import population
from turning_force.core.control import ControllerSettings, drift, make_controller
from turning_force.core.control.drift import CAUSES, REZERO_STD
from turning_force.core.estimation.estimator import rezeroed_text
from turning_force.core.estimation.settings import EstimateStatus, ForceEstimate
from turning_force.core.experiment import Experiment, load_experiment
from turning_force.core.identify import Estimate, Identification
from turning_force.core.kernel.batch import run_core
from turning_force.core.kernel.chain import command_for
from turning_force.core.kernel.simulate import SimulationResult, simulate
from turning_force.core.plant.settings import PlantSettings

ROOT = Path(__file__).resolve().parents[2]
DRIVE = population.DRIVE   # the lathe's friction curve, which a friction drift scales

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


MORE_FRICTION = (f'lathe_sim.friction_at_min_feed_a={1.25 * DRIVE.friction_at_min_feed_a!r}',
                 f'lathe_sim.friction_at_max_feed_a={1.25 * DRIVE.friction_at_max_feed_a!r}')


def job(commissioned: list[str], *drift: str) -> Experiment:
    return population.job_experiment(MACHINE).with_sets([*JOB, *commissioned, *drift])


@pytest.mark.parametrize(('drift', 'cause', 'size', 'tolerance'), [
    # the bank's dead times are a control period (10 ms) apart: the reading is within one
    (['lathe_sim.pmc_dead_time_s=0.12'], 'PMC dead time', 0.04, 0.01),
    # K_s d is identified to 0.01 %, and the monitor's gain is the ratio of two means of
    # hundreds of samples of a 1 % noise: 2 % covers both with a wide margin
    (['lathe_sim.specific_cutting_force_n_mm2=3080.0'], 'process gain', 0.40, 0.02),
    # the bank's time scales are SERVO_RATIO (x1.1) apart: the reading is within one step
    (['lathe_sim.servo_time_constant_s=0.306'], 'servo', 1.8, 1.8 * (drift.SERVO_RATIO - 1.0)),
])
def test_the_monitor_names_what_drifted_within_5_s_of_cutting(
        commissioned: list[str], drift: list[str], cause: str, size: float,
        tolerance: float) -> None:
    result = simulate(job(commissioned, *drift))
    named = result.trace['drift_alarm']
    assert named.any(), 'no drift alarm'
    first = np.flatnonzero(named)[0]   # the first cause named
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
    # (The monitor alone: where its window tells the friction from a gain, the estimator takes
    # it off, below.)
    result = simulate(job(commissioned, *MORE_FRICTION,
                          'force_controller.drift_friction_correction=none'))
    assert result.metrics['drift_alarm_s'] <= 5.0
    assert CAUSES[int(result.trace['drift_alarm'][-1])] in ('friction', 'process gain')
    found = re.search(r'friction ([+-]\d+) %', result.drift)
    assert found is not None, result.drift
    # 25 % of the friction, read through the identified friction curve and the 0.7 % model
    # error the identification left on the force (4 N of 500 N, 5 % of the friction's 89 N)
    assert int(found.group(1)) == pytest.approx(25, abs=5)
    assert 'an air move re-zeroes the friction' in result.drift


def estimate_bias_n(result: SimulationResult, after_s: float = 4.0) -> float:
    """The estimate's mean error on the true force from ``after_s`` to the run's end."""
    t = result.trace
    late = t['t_s'] > after_s
    return float(np.mean(t['estimated_force_n'][late] - t['force_n'][late]))


def test_a_friction_drift_the_window_tells_from_a_gain_is_taken_off_the_estimate(
        commissioned: list[str]) -> None:
    # 25 % more friction lifts the estimate by a quarter of the identified friction's 89 N
    # at the programmed feed, 22 N (and a little more at the cut's slower feed), the force
    # held that much under the reference. The monitor reads it in the cut; where its window
    # tells it from a gain (the product's drift_friction_correction, decided) the estimator
    # takes it off, and from there on the estimate is the force to within the reading's own
    # error: its standard deviation 1 % of the friction (the alarm's +- 0.01), 1 N, three of
    # them. The run on the compiled loop and the one a block at a time (the nodes' chain)
    # correct alike, bit for bit, and the session's estimate detail says so.
    uncorrected = simulate(job(commissioned, *MORE_FRICTION,
                               'force_controller.drift_friction_correction=none'))
    assert estimate_bias_n(uncorrected) == pytest.approx(22.0, abs=3.0)
    e = job(commissioned, *MORE_FRICTION)
    run = run_core(e)
    assert abs(estimate_bias_n(run.result)) < 3.0
    assert run.result.drift.startswith('friction +2'), run.result.drift
    said = [text for text in run.chain.estimate_detail.values()
            if text.startswith('friction corrected in the cut by the drift monitor: 1.2')]
    assert said, run.chain.estimate_detail
    by_block = stepped(e)   # (its metrics leave the monitor's out: the traces say it all)
    for name, values in by_block.result.trace.items():
        np.testing.assert_array_equal(run.result.trace[name], values, err_msg=name)
    assert_same_chain(run.chain, by_block.chain)


def test_an_undecided_level_is_taken_for_friction_only_where_asked(
        commissioned: list[str]) -> None:
    # Steel 3 % harder: at one depth and feed, a level the monitor names friction (+16 %)
    # with the gain (+3 %) beside it. The product's correction (decided) leaves the estimate
    # alone; 'named' takes the level for friction and holds the force above the reference
    # by what it took off the estimate: 3 % of the 500 N reference, 15 N (the identified
    # model's error on the force, 0.7 %, is 3.5 N of it).
    harder = 'lathe_sim.specific_cutting_force_n_mm2=2266.0'
    decided = simulate(job(commissioned, harder))
    assert decided.drift.startswith('friction +') and ', or process gain +3 %' in decided.drift
    assert abs(estimate_bias_n(decided)) < 1.0
    named = simulate(job(commissioned, harder, 'force_controller.drift_friction_correction=named'))
    assert estimate_bias_n(named) == pytest.approx(-15.0, abs=3.5)


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


def generated(seed: int, index: int, job: str = '') -> tuple[population.Machine, list[str]]:
    """Machine ``index`` of the population's ``seed`` (bench_drift.py), commissioned as it is:
    the machine, and the identified model with the monitor's settings for its own job (or
    for ``job``, where given)."""
    machine = replace(population.draw(index + 1, seed)[index], drift='', drifted={})
    machine = replace(machine, job=job or machine.job)
    ident, cut_depth = population.identify_machine(machine)
    identified, monitor = population.identified_sets(machine, ident, cut_depth)
    return machine, identified + monitor


# The force's own lag test: what names a lag drift where the feed test is off
# (drift_feed_test); the tests of it below run with the feed test off, which would otherwise
# name each of their drifts at the first override step (test_the_feed_test_* below).
FORCE_ALONE = ['force_controller.drift_feed_test=false']


def assert_servo_drift_named(machine: population.Machine, sets: list[str]) -> None:
    """The machine's servo slowed x1.8 is named within 5 s, and nothing on it as it was."""
    p = machine.plant
    slower = ({'servo_time_constant_s': 1.8 * p['servo_time_constant_s']}
              if p['servo_model'] == 'first_order'
              else {'servo_natural_freq_rad_s': p['servo_natural_freq_rad_s'] / 1.8})
    result = simulate(population.job_experiment(replace(machine, drifted=slower)).with_sets(sets))
    named = result.trace['drift_alarm']
    assert CAUSES[int(named[np.flatnonzero(named)[0]])] == 'servo', result.drift
    assert result.metrics['drift_alarm_s'] <= 5.0
    # the bank's time scales are SERVO_RATIO (x1.1) apart: the reading is within one step
    assert result.trace['drift_size'][-1] == pytest.approx(
        1.8, abs=1.8 * (drift.SERVO_RATIO - 1.0)), result.drift
    unchanged = simulate(population.job_experiment(machine).with_sets(sets))
    assert not unchanged.trace['drift_alarm'].any(), unchanged.drift


def test_a_servo_drift_is_named_where_what_the_bank_leaves_is_slow() -> None:
    # bench_drift.py --seed 16, #1: a second-order servo (10.2 rad/s) behind 144 ms of PMC dead
    # time, on the 'long' job. Slowed x1.8, the bank's member x1.73 (its steps x1.2 then)
    # leaves a hundredth to a three-hundredth of the identified model's residual in the job's
    # first seconds; what it
    # leaves is slow (lag-one correlation 0.93 to 0.98: the bank's step, 1.8 against 1.73),
    # and counted at that correlation a 1 s window held about one independent sample: no
    # alarm. The estimate's own noise is less correlated than drift.RHO_MAX (0.9): 5
    # independent samples in a window, and a member that leaves less than exp(-16 / 5.3), a
    # twentieth, of the residual is a lag drift.
    machine, sets = generated(16, 1)
    assert machine.plant['servo_model'] == 'second_order'
    assert_servo_drift_named(machine, [*sets, *FORCE_ALONE])


def test_a_cause_found_through_another_s_lapse_stands_from_its_first_finding() -> None:
    # bench_drift.py --seed 53, #5: an 'interrupted' job, its first piece 3 s at 2 mm, where the
    # depth is known. Cut 40 % harder, the lag test found a servo member for one period as
    # the window first filled (1.2 s into the cut); the level's gain, found from 1.7 s on, was
    # that cause's lapse until the lapse outlasted the process's transient (5 tau_c, 0.70 s),
    # and stood from 0 at 2.4 s: 0.6 s of the 1 s it must stand when the piece ended, named
    # at 6.13 s in the second piece. It stands from its first finding: named in the first.
    machine = replace(population.draw(6, 53)[5], drift='', drifted={})
    assert machine.job == 'interrupted'
    # the law verification chooses (mpc; on 5 drawn plants as on 50: the monitor's subject)
    done = population.commission(machine, plants=5)
    assert 'force_controller.controller=mpc' in done.chosen.sets
    sets = done.written
    harder = {'specific_cutting_force_n_mm2': 1.4 * machine.plant['specific_cutting_force_n_mm2']}
    result = simulate(population.job_experiment(replace(machine, drifted=harder)).with_sets(sets))
    named = result.trace['drift_alarm']
    assert CAUSES[int(named[np.flatnonzero(named)[0]])] == 'process gain', result.drift
    first_piece_s = population.JOBS['interrupted'][0][1]
    assert result.metrics['drift_alarm_s'] < first_piece_s
    unchanged = simulate(population.job_experiment(machine).with_sets(sets))
    assert not unchanged.trace['drift_alarm'].any(), unchanged.drift


def test_a_servo_drift_is_read_in_the_process_lags_transient() -> None:
    # bench_drift.py --seed 16, #2: a 0.34 s servo behind 102 ms of PMC dead time, and a slow
    # process (tau_c 0.164 s) on the 'long' job (a depth step every 3 s). The override moves
    # most in the second after an entry or a step, while the force still rises with tau_c.
    # Waiting five tau_c for that transient to die away (0.82 s of each 3 s segment) left the
    # bank the quiet part: the x1.73 member at 60 % of the identified one's residual, a
    # statistic of 11 to 15 against 16, named at 11 s (never, where each step emptied the
    # window). The transient's shape is known, the process lag's free decay exp(-t / tau_c):
    # fitted with it, the window starts a tau_c after the entry and holds the loop's moves.
    machine, sets = generated(16, 2)
    assert machine.job == 'long' and machine.plant['cutting_time_constant_s'] > 0.15
    assert_servo_drift_named(machine, [*sets, *FORCE_ALONE])


def test_lag_drifts_are_named_on_a_taper() -> None:
    # bench_drift.py --seed 29, #0 (78 ms of dead time, a 0.16 s servo) on the 'taper' job: 1
    # to 2.5 mm over 12 s, its K_s d 12 % a second higher at the start. Fitted with one gain
    # over a 1 s window, the ramp is in every member's residual (lag-one correlation 1.0, the
    # best member's share of it back to 1 within 2 s) and no drift was named in 12 s. With the
    # gain's ramp in the fit (F = K y + R t y + c) the members are compared on what the feed
    # did: each drift named within 5 s, none on the machine as it was.
    machine, sets = generated(29, 0, 'taper')
    sets = [*sets, *FORCE_ALONE]
    p = machine.plant
    drifts = {'PMC dead time': (0.5 * p['pmc_dead_time_s'], {
                  'pmc_dead_time_s': 1.5 * p['pmc_dead_time_s']}),
              'servo': (1.8, {'servo_time_constant_s': 1.8 * p['servo_time_constant_s']})}
    for cause, (size, change) in drifts.items():
        result = simulate(population.job_experiment(replace(machine, drifted=change)).with_sets(
            sets))
        named = result.trace['drift_alarm']
        assert CAUSES[int(named[np.flatnonzero(named)[0]])] == cause, result.drift
        assert result.metrics['drift_alarm_s'] <= 5.0
        # within one step of the bank: a control period, or SERVO_RATIO (x1.1)
        step = 0.01 if cause == 'PMC dead time' else (drift.SERVO_RATIO - 1.0) * size
        assert result.trace['drift_size'][-1] == pytest.approx(size, abs=step), result.drift
    unchanged = simulate(population.job_experiment(machine).with_sets(sets))
    assert not unchanged.trace['drift_alarm'].any(), unchanged.drift


def test_a_depth_step_starts_a_segment_of_the_window() -> None:
    # bench_drift.py --seed 37, #4: 145 ms of PMC dead time and a 0.28 s servo on the 'long'
    # job (1.5 mm, then 2.5 mm from 3 s, and on). With 72 ms more dead time the loop cycles;
    # by 3 s the bank's +80 ms member left a thirtieth of the identified model's residual, a
    # statistic of 17 against 16. The step to 2.5 mm, which no member follows, put the same
    # residual on every member of a window fitted with one gain: the statistic fell to 1, and
    # no drift was named in 24 s. The step now ends a segment (drift.STEP_SIGMAS), each
    # segment fitted with its own gain and the members compared over all of them: named at
    # 3.2 s of cutting (4.9 s where the step restarted the window, the evidence before it
    # lost), within a step of the bank. That first reading is the one the law takes into its
    # model (drift_adopt_model); with the loop on it, the monitor, which still compares with
    # the identified model, reads later sizes less well (+60 ms at the end).
    machine, sets = generated(37, 4)
    sets = [*sets, *FORCE_ALONE]
    assert machine.job == 'long'
    longer = {'pmc_dead_time_s': 1.5 * machine.plant['pmc_dead_time_s']}
    result = simulate(population.job_experiment(replace(machine, drifted=longer)).with_sets(
        sets))
    named = result.trace['drift_alarm']
    first = np.flatnonzero(named)[0]
    assert CAUSES[int(named[first])] == 'PMC dead time', result.drift
    assert result.metrics['drift_alarm_s'] <= 5.0
    assert result.trace['drift_size'][first] == pytest.approx(
        0.5 * machine.plant['pmc_dead_time_s'], abs=0.01), result.drift
    unchanged = simulate(population.job_experiment(machine).with_sets(sets))
    assert not unchanged.trace['drift_alarm'].any(), unchanged.drift


def stepped_force(step_n: float) -> np.ndarray:
    """The monitor's state on a cut whose force, the identified model's to a 2 N noise under
    an override swept slowly (80 to 100 %, 2 s a period), steps by ``step_n`` once the window
    is full (a depth step, the tool leaving the work) for STEP_PERIODS control periods."""
    settings = ControllerSettings(drift_monitor=True, drift_ksd_min_n_mm=4000.0,
                                  drift_ksd_max_n_mm=4000.0, drift_friction_n=90.0,
                                  drift_friction_std=0.01, drift_ksd_std=0.01)
    dp = drift.drift_fill(settings)
    ds = np.zeros(drift.STATE)
    noise = np.random.default_rng(7).normal(0.0, 2.0, 400)
    y = drift.DS_MODELS + drift.Y   # the identified member's output
    for k in range(300 + drift.STEP_PERIODS):
        drift.drift_applied(ds, 90.0 + 10.0 * math.sin(math.pi * k * 0.01))
        force = 500.0 * ds[y] + noise[k] + (step_n if k >= 300 else 0.0)
        drift.drift_step(dp, ds, force, True, math.nan)
        if k == 299:
            assert ds[drift.DS_IN_CUT] > 2.0 and ds[drift.DS_S1] > 90.0   # the window full
    return ds


@pytest.mark.parametrize('drop_n', [200.0, -200.0])
def test_a_step_of_the_force_either_way_ends_the_segment(drop_n: float) -> None:
    # A force 200 N lower (or higher) at one feed: 100 sigmas of the 2 N noise, which no
    # member follows. STEP_PERIODS of it end the segment, its samples out of the sums; the
    # next starts after the process's transient. The earlier segment's fits stay in the
    # window (CARRY): the identified member's, fitted to noise alone, 2 N squared over a
    # window's weight of about 95 samples less the 5 dropped (chi-square with 90 degrees of
    # freedom: within 30 % at 2 sigmas).
    ds = stepped_force(drop_n)
    assert ds[drift.DS_IN_CUT] == 0.0 and ds[drift.DS_S1] == 0.0 and ds[drift.DS_STEP] == 0.0
    carried = ds[drift.DS_MODELS + drift.CARRY]
    assert carried == pytest.approx(4.0 * ds[drift.DS_COUNT], rel=0.3)


def test_a_friction_drift_is_named_at_the_jobs_start_without_an_air_move() -> None:
    # bench_drift.py --seed 29, #2 on the 'deep' job: 1 mm for 5 s from the start, where the
    # depth is known (drift_first_s), then 3.5 mm; no air move. 25 % more friction adds 22 N
    # to the estimate (the identified friction is 85 N); the model predicts the start's force
    # to 0.75 % (drift.model_error: the slow part of its residual, 3.7 N), so 22 N is a level
    # at 6 sigmas (4 raise it). At one depth and nearly one feed it is also a 4.6 % harder
    # steel: named friction first (the estimator subtracts a friction no air move has
    # measured), the gain beside it (the monitor alone, without its correction).
    machine, sets = generated(29, 2)
    assert machine.job == 'deep'
    more = {'friction_at_min_feed_a': 1.25 * DRIVE.friction_at_min_feed_a,
            'friction_at_max_feed_a': 1.25 * DRIVE.friction_at_max_feed_a}
    drifted = population.job_experiment(replace(machine, drifted=more)).with_sets(sets)
    alone = simulate(drifted.with_sets(['force_controller.drift_friction_correction=none']))
    corrected = simulate(drifted)
    for result in (alone, corrected):
        named = result.trace['drift_alarm']
        first = np.flatnonzero(named)[0]
        assert CAUSES[int(named[first])] == 'friction', result.drift
        assert result.metrics['drift_alarm_s'] <= 5.0
        # read through the identified gain at 1 mm: the model's error on the force (0.8 % of
        # 480 N) is 4.2 % of the friction, two of them
        assert result.trace['drift_size'][first] == pytest.approx(0.25, abs=0.09)
        # nothing else named: the 3.5 mm step ends a segment (drift.STEP_SIGMAS), and
        # the window at 3.5 mm and 14 % override, where the loop cycles and the member a
        # control period longer fits the estimate better on this machine unchanged too, names
        # no dead time (drift.DELAY_STD; it named +10 ms at 9.7 s)
        assert set(named[first:].tolist()) == {float(drift.FRICTION)}, result.drift
    found = re.search(r'^friction ([+-]\d+) %.*, or process gain ([+-]\d+) %', alone.drift)
    assert found is not None, alone.drift
    assert int(found.group(1)) == pytest.approx(25, abs=9)
    # the same level as a gain: 22 N of some 480 N
    assert int(found.group(2)) == pytest.approx(4.6, abs=1.5)
    unchanged = simulate(population.job_experiment(machine).with_sets(sets))
    assert not unchanged.trace['drift_alarm'].any(), unchanged.drift


# --- what the monitor can tell only with what it is told: the depth at the job's start, the
# friction the re-zero measures in air, the tool in use ------------------------------------

PARK_GAIN = next(m for m in population.park_drifts() if m.drift.startswith('process gain'))


@pytest.fixture(scope='module')
def park_identified() -> tuple[Identification, float]:
    """Park's Fig. 8 lathe with Kim's 80 ms dead time, commissioned as it was."""
    return population.identify_machine(replace(PARK_GAIN, drifted={}))


def test_the_model_error_is_the_slow_part_of_the_commissioning_residual(
        park_identified: tuple[Identification, float]) -> None:
    # A residual of white noise (10 N, its estimate +- 0.1 N) alone: the slow part is what
    # the two variances' difference cannot rule out, one standard deviation of it:
    # sqrt(2 sqrt(2) 10 x 0.1) = 1.68 N. With 5 N of slow misfit added in quadrature, the
    # misfit and that: sqrt(25 + 2.83) = 5.28 N.
    ident = park_identified[0]
    white = replace(ident, process=replace(ident.process, residual_rms=10.0),
                    force_noise_n=Estimate(10.0, 0.1, 'N'))
    assert drift.model_error(white) == pytest.approx(1.682, abs=1e-3)
    slow = replace(white, process=replace(ident.process, residual_rms=math.hypot(10.0, 5.0)))
    assert drift.model_error(slow) == pytest.approx(5.276, abs=1e-3)


@pytest.mark.parametrize(('depth_mm', 'friction_n'), [(1.0, 87.6), (3.0, 94.7)])
def test_the_friction_share_is_the_one_at_the_feed_the_jobs_start_holds(
        park_identified: tuple[Identification, float], depth_mm: float,
        friction_n: float) -> None:
    # Park's steel (K_s 2200 N/mm^2, g 1, 0.2 mm/rev at 600 rpm: 120 mm/min programmed) holds
    # 500 N at 1 mm with 500 / 440 = 114 % override (136 mm/min), at 3 mm with 38 % (45.5
    # mm/min). The lathe's friction (Park Eq. 25: 0.60 A at 6 mm/min, 0.35 A at 300) there is
    # 0.551 A and 0.596 A, 87.6 N and 94.7 N by Eq. 26's 0.00629 A/N; at the programmed feed
    # it is 89.4 N, which the monitor measured a friction drift against before, wherever the
    # cut ran. The commissioning identified the curve, K_s and g to a tenth of a percent:
    # 0.5 N.
    _, monitor = population.identified_sets(PARK_GAIN, *park_identified,
                                            (depth_mm, depth_mm))
    written = next(float(a.split('=')[1]) for a in monitor
                   if a.startswith('force_controller.drift_friction_n='))
    assert written == pytest.approx(friction_n, abs=0.5)


def test_a_gain_drift_is_named_at_the_start_of_a_job_over_several_depths(
        park_identified: tuple[Identification, float]) -> None:
    # Fig. 8's job cuts 1, 2 and 3 mm (4 s each). The force gives K_s d: 40 % harder steel at
    # 1 mm is a 1.4 mm cut, inside the job's 1-3 mm, until the 3 mm step at 8 s. The job's
    # start is at a known depth (1 mm until its first step: identify --job writes it), and
    # there the gain is seen.
    identified, monitor = population.identified_sets(PARK_GAIN, *park_identified)
    # The first change at 4 s of the program; the cut's clock starts once the force passes
    # engage_force_n (100 N) at the 30 % entry feed: 500 / 1.14 x 0.3 = 132 N steady through
    # tau_c = 0.05 s, 0.05 ln(132 / 32) = 0.071 s after the entry (to the identified model's
    # own K_s and tau_c: within 5 ms).
    first_s = next(float(a.split('=')[1]) for a in monitor
                   if a.startswith('force_controller.drift_first_s='))
    assert first_s == pytest.approx(4.0 - 0.071, abs=0.005)
    drifted = population.job_experiment(PARK_GAIN).with_sets(identified + monitor)
    result = simulate(drifted)
    named = result.trace['drift_alarm']
    assert CAUSES[int(named[np.flatnonzero(named)[0]])] == 'process gain', result.drift
    assert result.metrics['drift_alarm_s'] <= 5.0
    # the gain of a 1 % noise's mean over hundreds of samples, and K_s d to 1.3 %
    assert result.trace['drift_size'][-1] == pytest.approx(0.40, abs=0.02)
    # Without the start's depth it is not seen within 5 s: a depth is all it could be.
    blind = simulate(drifted.with_sets(['force_controller.drift_first_s=0.0']))
    assert not blind.metrics.get('drift_alarm_s', math.inf) <= 5.0, blind.drift
    # ... and the start's narrow range says nothing on the machine as it was.
    unchanged = simulate(population.job_experiment(replace(PARK_GAIN, drifted={})).with_sets(
        identified + monitor))
    assert not unchanged.trace['drift_alarm'].any(), unchanged.drift


def test_a_friction_drift_is_measured_by_the_re_zero_in_an_air_move() -> None:
    # A generated machine (bench_drift.py --seed 16, #3) on an interrupted job (2 mm, out of
    # the work at 3 s and 7 s): in the cut, 25 % more friction is some 22 N of the estimate,
    # a level the job's start (at its known depth) sees against the model's own error
    # (drift.model_error: 1.8 N here) but cannot tell from a 5 % gain: named friction first,
    # the gain beside it. In the air move the estimator re-zeroes the friction: its scale is
    # the friction drift, measured, and the gain is dropped.
    machine = replace(population.draw(4, seed=16)[3], drift='', drifted={})
    assert machine.job == 'interrupted'
    ident, cut_depth = population.identify_machine(machine)
    identified, monitor = population.identified_sets(machine, ident, cut_depth)
    drifted = replace(machine, drifted={
        'friction_at_min_feed_a': 1.25 * DRIVE.friction_at_min_feed_a,
        'friction_at_max_feed_a': 1.25 * DRIVE.friction_at_max_feed_a})
    result = simulate(population.job_experiment(drifted).with_sets(identified + monitor))
    t, named = result.trace['t_s'], result.trace['drift_alarm']
    assert CAUSES[int(named[np.flatnonzero(named)[0]])] == 'friction', result.drift
    # a window's worth of the cut (1 s after the entry's 5 tau_c) and the cause standing 1 s
    assert result.metrics['drift_alarm_s'] <= 3.0
    # the air move begins 3 s into the cut; the re-zero 0.3 s later, its scale then rises
    # with a 0.3 s time constant: the scale the re-zero reaches is 1.25 through the
    # identified curve's shape (REZERO_STD)
    assert result.trace['drift_size'][-1] == pytest.approx(0.25, abs=2 * REZERO_STD)
    assert result.drift.startswith('friction +') and ' or ' not in result.drift
    # The first air move re-zeroes 0.3 s (3.7-4.0 s): the scale goes 1 - exp(-1) = 63 % of
    # the way, to 1.16, beyond 4 REZERO_STD: friction, named again. The 9 N it left are a
    # level in the next cut that the monitor, the friction re-zeroed, names a 1.5 % gain
    # until the second air move finishes the reading (it read 1.19 and kept friction
    # while the re-zero took the cut's tail and the re-entry's rise for friction, 3 % more).
    air = (t > 3.5) & (t < 4.0)
    assert (named[air] == drift.FRICTION).all()
    assert (named[t > 8.0] == drift.FRICTION).all() and result.metrics['drift_alarms'] <= 3.0
    # the machine as it was: the re-zero finds the identified friction, and the level at
    # each entry is the identified one within its error (the friction's within REZERO_STD
    # after the re-zero): no alarm
    unchanged = simulate(population.job_experiment(machine).with_sets(identified + monitor))
    assert not unchanged.trace['drift_alarm'].any(), unchanged.drift


def test_a_re_zero_that_finds_the_friction_unchanged_names_the_gain_of_an_undecided_level(
        ) -> None:
    # A level in a cut at one depth and feed is a gain or a friction drift; named friction
    # (the better fit) with a gain beside it, an air move that finds the identified friction
    # turns it to the gain. One that finds it changed keeps it friction, sized by the scale.
    settings = ControllerSettings(drift_monitor=True, drift_ksd_min_n_mm=4000.0,
                                  drift_ksd_max_n_mm=4000.0, drift_friction_n=90.0,
                                  drift_friction_std=0.01, drift_ksd_std=0.01)
    dp = drift.drift_fill(settings)
    ds = np.zeros(drift.STATE)
    ds[drift.DS_ALARM], ds[drift.DS_ALARM_SIZE], ds[drift.DS_ALARM_ALT] = (
        drift.FRICTION, 0.29, 0.05)
    ds[drift.DS_ALARMS] = 1.0
    drift.drift_rezeroed(dp, ds, 1.01)   # within 4 x 2.5 %: the identified friction ...
    # ... once the reading is over (the scale converges through the air move from the one
    # before: an early reading near 1 says little): a control period without one
    drift.drift_step(dp, ds, math.nan, False, 100.0)
    assert drift.alarm(ds)[0] == drift.FRICTION
    drift.drift_step(dp, ds, math.nan, False, 100.0)
    assert drift.alarm(ds)[:2] == (drift.GAIN, 0.05) and ds[drift.DS_ALARMS] == 2.0
    # a reading beyond the band names the friction once it has stood REZERO_STAND_S
    periods = round(drift.REZERO_STAND_S / dp[drift.D_PERIOD])
    for _ in range(periods - 1):
        drift.drift_rezeroed(dp, ds, 1.3)
    assert drift.alarm(ds)[0] == drift.GAIN
    drift.drift_rezeroed(dp, ds, 1.3)
    assert drift.alarm(ds)[:2] == (drift.FRICTION, pytest.approx(0.3))


def test_a_re_zero_reading_beyond_the_band_for_less_than_its_stand_names_nothing() -> None:
    # A feed's transient in air (a servo ringing down to a stop through the stick region:
    # population seed 15's #101) read half the friction for 0.05 s, then the move's readings
    # found it as identified: nothing is named, and a reading that stands beyond is.
    settings = ControllerSettings(drift_monitor=True, drift_ksd_min_n_mm=4000.0,
                                  drift_ksd_max_n_mm=4000.0, drift_friction_n=90.0,
                                  drift_friction_std=0.01, drift_ksd_std=0.01)
    dp = drift.drift_fill(settings)
    ds = np.zeros(drift.STATE)
    periods = round(drift.REZERO_STAND_S / dp[drift.D_PERIOD])
    for scale in [0.5] * (periods // 2) + [1.02] * periods:
        drift.drift_rezeroed(dp, ds, scale)
    drift.drift_step(dp, ds, math.nan, False, 100.0)
    drift.drift_step(dp, ds, math.nan, False, 100.0)   # the reading is over
    assert drift.alarm(ds)[0] == drift.NONE
    for _ in range(periods // 2):   # a transient, then the reading paused
        drift.drift_rezeroed(dp, ds, 0.5)
    drift.drift_step(dp, ds, math.nan, False, 100.0)
    drift.drift_step(dp, ds, math.nan, False, 100.0)
    for _ in range(periods // 2):   # does not add to the next reading's
        drift.drift_rezeroed(dp, ds, 0.5)
    assert drift.alarm(ds)[0] == drift.NONE
    for _ in range(periods - periods // 2):
        drift.drift_rezeroed(dp, ds, 0.5)
    assert drift.alarm(ds)[:2] == (drift.FRICTION, pytest.approx(-0.5))


def test_a_tool_change_ends_the_drift_alarm(park_identified: tuple[Identification, float],
                                            tmp_path: Path) -> None:
    # Two tools in one program (config/experiments/two_tools.yaml) on Park's machine: T1 cuts
    # steel 40 % harder than the steel its model was identified on (2 mm, 0.5-5 s), and the
    # monitor names the gain; at 5.5 s the turret indexes to T2, whose section turns the
    # monitor off (no model of T2 was identified): T1's alarm does not stand over T2's cut.
    tools = yaml.safe_load((ROOT / 'config' / 'tools' / 'two_tools.yaml').read_text())
    tools['tools'][2]['force_controller']['drift_monitor'] = False
    tools_file = tmp_path / 'tools.yaml'
    tools_file.write_text(yaml.safe_dump(tools))
    ident, cut_depth = park_identified
    machine = replace(PARK_GAIN, drifted={})
    identified, monitor = population.identified_sets(machine, ident, cut_depth, (2.0, 2.0))
    experiment = load_experiment(ROOT / 'config' / 'experiments' / 'two_tools.yaml').with_sets([
        *machine.sets(after_drift=False), f'/**.tools_file={str(tools_file)!r}',
        'lathe_sim.tool_specific_cutting_force_n_mm2=[3080.0, 1400.0]',
        *identified, *monitor])
    result = simulate(experiment)
    t, named = result.trace['t_s'], result.trace['drift_alarm']
    assert CAUSES[int(named[t < 5.5].max())] == 'process gain'
    assert not named[t > 5.51].any() and result.drift == ''


def test_the_nodes_pass_the_re_zero_from_the_estimate_to_the_monitor() -> None:
    # force_controller has the estimate's message, not the estimator: the re-zero's scale
    # comes in its detail line (estimator.rezeroed_text), which command_for reads, as the
    # per-block chain and the node do. A line that is no re-zero tells the monitor nothing.
    settings = ControllerSettings(drift_monitor=True, drift_ksd_min_n_mm=4000.0,
                                  drift_ksd_max_n_mm=4000.0, drift_friction_n=90.0,
                                  drift_friction_std=0.01, drift_ksd_std=0.01)
    controller = make_controller(settings)
    in_air = ForceEstimate(0.0, 3.0, 0.0, 0.5, 0.4, EstimateStatus.OK, rezeroed_text(1.0))
    assert command_for(controller, in_air) is not None and controller.drift == ''
    for detail in ('', 'friction re-zeroed in air: x1.3', 'phase current 31 A beyond the '
                   'sensor range'):
        command_for(controller, dataclasses.replace(in_air, detail=detail))
        assert controller.drift == ''
    for _ in range(round(drift.REZERO_STAND_S / settings.control_period_s)):   # standing beyond
        command_for(controller, dataclasses.replace(in_air, detail=rezeroed_text(1.3)))
    assert controller.drift.startswith('friction +30 % (identified 1.00, now 1.30 +- 0.03)')


@pytest.mark.parametrize('job', sorted(population.JOBS))
def test_a_programs_approach_in_air_leaves_its_known_start_as_it_was(job) -> None:
    # The monitor knows K_s d where the program's depth is known: from its first contact to
    # its first depth change (drift.first_cut). A program that approaches the work in air
    # first (population.approached: a second of depth 0 before the job) has the same start,
    # counted from the contact; before, a start in air gave none (0 s, no depth).
    program = population.JOBS[job]
    bare = PlantSettings(depth_times_s=program[0], depth_mm=program[1],
                         depth_interpolation=program[2]).depth_profile
    times, depths, interpolation, _ = population.approached(program, 1.0)
    approached = PlantSettings(depth_times_s=times, depth_mm=depths,
                               depth_interpolation=interpolation).depth_profile
    assert approached.depth_mm[0] == 0.0 and approached.at(np.array([0.99]))[0] == 0.0
    assert drift.first_cut(approached) == drift.first_cut(bare)
    assert drift.first_cut(bare)[0] > 0.0


@pytest.mark.parametrize('drift_change', [['lathe_sim.pmc_dead_time_s=0.12'],
                                          ['lathe_sim.servo_time_constant_s=0.306']])
def test_the_feed_test_names_a_lag_drift_at_the_first_override_step(
        commissioned: list[str], drift_change: list[str]) -> None:
    # The dead time +50 % and servo x1.8 on Park's machine: the axis feed the DAQ
    # measures against the bank's members names the drift once the first override step has
    # come through the (drifted) dead time and the servo has answered for a few periods, and
    # stood FEED_STAND_S: within the dead time and 0.1 s of the step (0.14-0.15 s measured),
    # where the force alone (FORCE_ALONE) names it 1.7-2.0 s later.
    result = simulate(job(commissioned, *drift_change))
    applied, t = result.trace['applied_override_pct'], result.trace['t_s']
    step_s = t[np.flatnonzero(np.diff(applied) != 0.0)[0] + 1]
    named = result.trace['drift_alarm']
    first = np.flatnonzero(named)[0]
    dead_s = 0.12 if 'dead' in drift_change[0] else MACHINE.plant['pmc_dead_time_s']
    assert t[first] <= step_s + dead_s + 0.1, (t[first], step_s)
    cause, size = (('PMC dead time', 0.04) if 'dead' in drift_change[0] else ('servo', 1.8))
    assert CAUSES[int(named[first])] == cause, result.drift
    step = 0.01 if cause == 'PMC dead time' else (drift.SERVO_RATIO - 1.0) * size
    assert result.trace['drift_size'][first] == pytest.approx(size, abs=step), result.drift
    alone = simulate(job(commissioned, *drift_change, *FORCE_ALONE))
    assert alone.metrics['drift_alarm_s'] >= result.metrics['drift_alarm_s'] + 1.0


def feed_session(slower: float, rpm_per_period: float = 0.0, follows: bool = True) -> str:
    """The drift monitor fed in air, block by block through command_for as the chain and the
    node feed it: 30 % for 0.5 s, then 100 %, through 50 ms of PMC dead time and a
    first-order servo ``slower`` times the identified 0.17 s; the measured feed is the
    servo's mean over each block, sampled every millisecond. ``rpm_per_period``: the spindle
    speed's change each period, relative (G96); ``follows`` False: the axis keeps the feed of
    the first level (a ladder that does not copy the override to *FV, override cancel). What
    the monitor says at the end."""
    settings = ControllerSettings(
        drift_monitor=True, drift_ksd_min_n_mm=4000.0, drift_ksd_max_n_mm=4000.0,
        drift_ksd_std=0.01, model_dead_time_s=0.05, model_servo_time_constant_s=0.17,
        model_cutting_time_constant_s=0.05)
    controller = make_controller(settings)
    full = settings.programmed_feed_mm_rev * settings.spindle_speed_rpm
    pole = math.exp(-1e-3 / (0.17 * slower))
    levels = [30.0] * 50 + [100.0] * 70
    feed, rpm = 0.30 * full, settings.spindle_speed_rpm
    for k, level in enumerate(levels):
        controller.applied(level, False, 0)
        level_in = levels[k - 5] if k >= 5 and follows else 30.0   # through the dead time
        commanded = level_in / 100.0 * full * rpm / settings.spindle_speed_rpm
        samples = []
        for _ in range(10):
            feed = pole * feed + (1.0 - pole) * commanded
            samples.append(feed)
        estimate = ForceEstimate(0.01 * (k + 1), 0.0, 0.0, 0.5, 0.4, EstimateStatus.OK, '',
                                 float(np.mean(samples)))
        rpm *= 1.0 + rpm_per_period
        controller.spindle_speed(rpm)
        assert command_for(controller, estimate) is not None
    return controller.drift


def test_the_feed_test_reads_the_servo_in_air_and_waits_while_the_spindle_speed_moves() -> None:
    # The override's step in air is enough: no cut, no force. x1.5 is named as the bank's
    # nearest member, x1.46; the identified servo is not named at all. Under G96 the feed
    # follows the spindle speed too (through the servo's lag, which the bank on the override
    # alone does not model): at 3 %/s the test waits, and names nothing.
    assert feed_session(1.5).startswith('servo slower: time scale x1.46'), feed_session(1.5)
    assert feed_session(1.0) == ''
    assert feed_session(1.5, rpm_per_period=0.0003) == ''
    assert feed_session(1.5, rpm_per_period=0.0001).startswith('servo slower')


def test_a_feed_that_does_not_follow_the_override_names_no_lag() -> None:
    # The override steps 30 -> 100 % and the axis stays at 30 % (override cancel, a ladder
    # that does not copy the module's inputs to *FV; the gate's feed-follow check hands back
    # after feed_follow_time_s): the slowest member, whose feed has moved least, misses the
    # axis less than the identified one, but by 40-70 % of the programmed feed. No member
    # follows the feed within FEED_FIT: no lag drift is named, and no law takes one.
    assert feed_session(1.0, follows=False) == ''
    assert feed_session(1.5, follows=False) == ''


@pytest.mark.slow   # three machines commissioned in full: a minute (make test-all)
def test_no_feed_test_alarm_on_population_machines_between_whole_periods() -> None:
    # Population seed 42 with a 1 s approach, machines whose lag did not drift: #56 (59 ms of
    # dead time, a 0.10 s servo: the bank holds 5.9 periods by interpolating the override,
    # and a member a period longer, its feed still at rest, misses the first period of the
    # response by nothing: FEED_FLOOR), #7 (25 ms, 0.14 s) and #35 (36 ms, 0.10 s).
    for index in (7, 35, 56):
        machine = replace(population.draw(index + 1, 42)[index], approach_s=1.0)
        assert not machine.drift
        sets = population.commission(machine).written
        result = simulate(population.job_experiment(machine).with_sets(sets))
        assert not result.trace['drift_alarm'].any(), (index, result.drift)
