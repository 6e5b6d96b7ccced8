"""The population of simulated machines (commands/population.py): seeded, inside the issue's
ranges, every job and drift a valid experiment, and the commissioning flow runs end to end."""

from __future__ import annotations

import math
from dataclasses import replace

import pytest

from turning_force.commands.population import (
    DRIVE,
    JOBS,
    commission,
    draw,
    identified_sets,
    identify_machine,
    job_experiment,
    park_drifts,
    run_job,
)
from turning_force.core.kernel.simulate import simulate
from turning_force.core.verification import (
    BAND_RIPPLE_N,
    BAND_STEADY_N,
    entry_depths_mm,
    entry_override_pct,
    verify,
)

# Issue 16's interrupted cut: three entries, at 1, 2 and 3 mm.
INTERRUPTED = ['lathe_sim.depth_times_s=[0.0, 3.0, 4.0, 7.0, 8.0]',
               'lathe_sim.depth_mm=[1.0, 0.0, 2.0, 0.0, 3.0]', 'experiment.duration_s=11.0',
               'lathe_sim.depth_interpolation=step', 'force_controller.quantiser=error_feedback']


def test_the_same_seed_draws_the_same_machines_and_another_seed_others():
    assert draw(20, 7) == draw(20, 7)
    assert draw(20, 7) != draw(20, 8)


def test_every_parameter_is_inside_its_range():
    machines = draw(300, 3)
    for m in machines:
        p = m.plant
        assert 0.0 <= p['pmc_dead_time_s'] <= 0.15
        assert 0.6 <= p['cutting_exponent'] <= 1.0
        # K_s keeps Park's force at 0.2 mm/rev (2200 N/mm^2 x 0.2 mm/rev at g = 1), x0.8-1.5.
        at_park = p['specific_cutting_force_n_mm2'] * 0.2 ** p['cutting_exponent'] / (2200 * 0.2)
        assert 0.8 - 1e-3 <= at_park <= 1.5 + 1e-3
        assert 0.01 <= p['current_noise_a'] <= 0.1 and 0.0 <= p['force_noise_fraction'] <= 0.05
        assert 500.0 <= p['spindle_speed_rpm'] <= 1500.0
        assert 0.02 <= p['cutting_time_constant_s'] <= 0.2
        if p['servo_model'] == 'first_order':
            assert 0.1 <= p['servo_time_constant_s'] <= 0.35
        else:
            assert 6.0 <= p['servo_natural_freq_rad_s'] <= 20.0
            assert 0.3 <= p['servo_damping'] <= 1.0
    # 70 % first-order servos and a third drifting, within what 300 draws allow (3 sd).
    first = sum(m.plant['servo_model'] == 'first_order' for m in machines) / len(machines)
    drifting = sum(bool(m.drift) for m in machines) / len(machines)
    assert abs(first - 0.7) < 3 * math.sqrt(0.7 * 0.3 / 300)
    assert abs(drifting - 1 / 3) < 3 * math.sqrt(2 / 9 / 300)
    assert {m.job for m in machines} == set(JOBS)


def test_every_machine_is_a_valid_experiment_before_and_after_its_drift(experiments_dir):
    for m in draw(40, 11):
        before = job_experiment(m, after_drift=False, experiments=experiments_dir)
        after = job_experiment(m, experiments=experiments_dir)
        assert before.plant.pmc_dead_time_s == m.plant['pmc_dead_time_s']
        assert (before.plant == after.plant) == (not m.drift)


def test_the_commissioning_flow_runs_on_a_machine(experiments_dir):
    machine = draw(1, 15)[0]
    done = commission(machine, experiments_dir, plants=5)
    assert any(s.startswith('force_controller.model_dead_time_s=') for s in done.identified)
    assert any(s.startswith('force_estimator.kalman_force_noise_n=') for s in done.identified)
    # The verification ran every candidate and chose one holding no fewer plants than the
    # defaults; its settings are the identified ones and the law's.
    laws = {next((a for a in p.sets if a.startswith('force_controller.controller=')), 'defaults')
            for p in done.predictions}
    assert laws == {'force_controller.controller=smc', 'force_controller.controller=mpc',
                    'force_controller.controller=pi', 'defaults'}
    defaults = next(p for p in done.predictions if p.name == 'defaults')
    assert done.chosen.in_band >= defaults.in_band
    assert done.chosen.name == 'defaults' or done.chosen.sets[:len(done.identified)] == \
        done.identified
    metrics = run_job(machine, done.chosen.sets, experiments_dir)
    assert math.isfinite(metrics['steady_mean_abs_error_n'])


def test_a_law_that_holds_most_plants_is_not_lost_to_a_few_it_fails_on(experiments_dir):
    # Population seed 42's #92 (150 ms of dead time, a 7 rad/s servo damped at 0.4, a taper):
    # the predictive law held 32 of 51 plants, the sliding mode law 6, yet scored worse while a
    # plant far out counted 10 times the band (verification.MAX_COST): 7.33 N on the machine
    # against the oracle's 2.24 N; now 2.54 N, in band.
    machine = draw(93, 42)[92]
    assert not machine.drift
    done = commission(machine, experiments_dir)
    assert 'force_controller.controller=mpc' in done.chosen.sets
    metrics = run_job(machine, done.written, experiments_dir)
    assert metrics['steady_mean_abs_error_n'] <= BAND_STEADY_N
    assert metrics['ripple_p2p_n'] <= BAND_RIPPLE_N


@pytest.fixture(scope='module')
def park_commissioned(experiments_dir):
    """Park's Fig. 8 machine with Kim's 80 ms dead time, commissioned before it drifts (every
    drift case is the same machine until then)."""
    return commission(park_drifts()[0], experiments_dir, plants=5).chosen.sets


@pytest.mark.parametrize('drift', ['dead time +50 %', 'feed friction +25 %'])
def test_a_drifted_machine_recommissions_from_its_own_production_cut(experiments_dir,
                                                                   park_commissioned, drift):
    """Issue 16: the job cut with the commissioned file on the drifted machine (a production
    session, no air move), ``identify`` on that session, the job cut again with what it wrote:
    in band (steady <= 5 N, ripple <= 25 N). The friction drift is out of band before (issue
    16 measured 23 N steady): the estimator's friction no longer the machine's."""
    machine = next(m for m in park_drifts() if m.drift == drift)
    before = run_job(machine, park_commissioned, experiments_dir)
    again = commission(machine, experiments_dir, plants=5, production=park_commissioned)
    after = run_job(machine, again.chosen.sets, experiments_dir)
    assert after['steady_mean_abs_error_n'] <= BAND_STEADY_N
    assert after['ripple_p2p_n'] <= BAND_RIPPLE_N
    if drift.startswith('feed friction'):
        assert before['steady_mean_abs_error_n'] > 4 * BAND_STEADY_N
    assert any(s.startswith('force_estimator.friction_at_min_feed_a=') for s in again.identified)


def test_a_production_cut_keeps_a_right_friction_curve(experiments_dir):
    """A gain drift leaves the friction as commissioned: re-identification keeps the prior
    curve. Generator seed 29 #5 ('steps' job), K_s +40 %, cut with its commissioned file: the
    cut's friction errors come out at 2.3 and 0.9 of their standard deviations, and at the old
    significance of 2 the curve moved by 0.023 A (3.7 N of force: re-identified, 4.45 N steady
    against 0.80 N with the running file)."""
    base = draw(6, 29)[5]
    base = replace(base, drift='', drifted={})
    drifted = replace(base, drift='process gain', drifted={
        'specific_cutting_force_n_mm2': 1.4 * base.plant['specific_cutting_force_n_mm2']})
    running = commission(base, experiments_dir, plants=2).written
    ident, _ = identify_machine(drifted, experiments_dir, production=running)
    assert ident.kept == ('friction',)
    assert ident.friction.model == 'prior'
    errors = [ident.process[f'friction_error_at_{end}_a'] for end in ('min', 'max')]
    assert max(abs(e.value) / e.std for e in errors) > 2.0   # what the old test passed


def test_the_depths_a_program_enters_the_work_at():
    assert entry_depths_mm(job_experiment(draw(1, 15)[0]).with_sets(
        INTERRUPTED).plant.depth_profile) == (1.0, 2.0, 3.0)
    starts = {job: entry_depths_mm(job_experiment(replace(draw(1, 15)[0], job=job))
                                   .plant.depth_profile) for job in JOBS}
    assert starts == {'steps': (1.0,), 'taper': (1.0,), 'long': (1.5,), 'deep': (1.0,),
                      'interrupted': (2.0, 2.0, 2.0)}


def test_identify_lowers_the_entry_feed_where_the_deepest_entry_would_overshoot(
        experiments_dir):
    # Population seed 42's #11: K_s 1788 N/mm^2 and Kienzle's g 0.64 cut 887 N at 3 mm and the
    # product's 30 % entry feed, 1915 x 0.3^0.64 (the force falls slower than the feed): 20 %
    # gives 684 N, 10 % 438 N: the highest level whose force settles under the 500 N reference.
    machine = replace(draw(12, 42)[11], drift='', drifted={})
    job = job_experiment(machine, experiments=experiments_dir).with_sets(INTERRUPTED)
    ident, cut_depth = identify_machine(machine, experiments_dir)
    assert entry_override_pct(ident, job, (1.0, 2.0, 3.0), cut_depth) == 10.0
    assert entry_override_pct(ident, job, (1.0,), cut_depth) is None   # 296 N at 1 mm
    identified, monitor = identified_sets(machine, ident, cut_depth, depths_mm=(1.0, 3.0),
                                          experiments=experiments_dir)
    assert 'pmc_bridge.air_cut_override_pct=10.0' in identified
    chosen = verify(job, ident, tuple(identified), cut_depth, plants=5,
                    seed=machine.seed + machine.index, monitor=tuple(monitor))[0]
    written = [*chosen.sets, *monitor]
    # The bound: at most 100 N over the reference at any entry, in band in the cut.
    clean = simulate(job.with_sets(written)).metrics
    assert clean['entry_overshoot_n'] <= 100.0
    assert clean['steady_mean_abs_error_n'] <= BAND_STEADY_N
    hot = simulate(job.with_sets([*written, 'pmc_bridge.air_cut_override_pct=30.0'])).metrics
    assert hot['entry_overshoot_n'] > 300.0


def test_a_friction_drift_is_read_in_the_jobs_approach_in_air(experiments_dir):
    """The population's friction drifts of 39-50 % (seed 42 #27, #43, #88, #108, #122: 32-43
    N under the reference throughout) read over rezero_below_n in air, and their jobs never
    left the work: no re-zero. A real program approaches the work in air first. Park's Fig. 8
    machine commissioned, its friction 46 % up, its job after a second's approach at the entry
    feed (30 %): with what identify writes for a job that starts in air
    (``rezero_start_in_air``) the approach reads the friction (the alarm says so before the
    cut), and the job is in band (2.7 N measured; the scale read at the approach's feed
    carries the identified curve's shape to the cut's, drift.REZERO_STD). Without it, the
    drift monitor tells the friction from a gain in the cut at 2.3 s and corrects it: 7.0 N
    (42.6 N with the monitor off)."""
    machine = replace(park_drifts()[0], approach_s=1.0, drift='friction x1.46', drifted={
        key: 1.46 * getattr(DRIVE, key)
        for key in ('friction_at_min_feed_a', 'friction_at_max_feed_a')})
    written = commission(machine, experiments_dir, plants=2).written
    assert 'force_estimator.rezero_start_in_air=True' in written
    read = run_job(machine, written, experiments_dir)
    assert read['steady_mean_abs_error_n'] <= BAND_STEADY_N
    assert read['ripple_p2p_n'] <= BAND_RIPPLE_N
    assert read['drift_alarm_s'] < 0.0   # named in the approach
    unread = run_job(machine, [s for s in written if 'rezero_start_in_air' not in s],
                     experiments_dir)
    assert unread['steady_mean_abs_error_n'] > BAND_STEADY_N
