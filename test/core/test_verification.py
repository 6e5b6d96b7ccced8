"""Closed-loop verification of identified settings (core/verification.py), on the machines of
issue 15's table, where the commissioning flow used to make regulation far worse than the
defaults: identified, verified on Park's Fig. 8 job, and cut. What it chooses holds the band on
all three, and the identified plant is the machine near enough that the prediction is the cut's
outcome (the issue: within 20 % or 1 N). The fast spindle's job runs at 270-290 mm/min, near
where the simulated machine's friction levels off (its curve ends at 300 mm/min, the staircase
reaches 360): identification fits that end with the curve, or the estimate would carry 2-3 N of
friction error the identified plant does not have."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from turning_force.commands.population import draw, run_job
from turning_force.core.experiment import assignments, load_experiment
from turning_force.core.identify import Estimate, identify
from turning_force.core.kernel.record import record
from turning_force.core.kernel.simulate import simulate
from turning_force.core.verification import (
    BAND_RIPPLE_N,
    BAND_STEADY_N,
    CANDIDATES,
    DRIFT_SIZES,
    FLOORS,
    MAX_COST,
    cost,
    draw_plants,
    drifted_plants,
    estimates,
    plant_sets,
    verify,
)

MACHINES = {   # issue 15's table; each --set given to the commissioning and to the job
    'kienzle': ['lathe_sim.cutting_exponent=0.8', 'lathe_sim.specific_cutting_force_n_mm2=1600.0'],
    'noisy drive': ['lathe_sim.current_noise_a=0.1', 'lathe_sim.force_noise_fraction=0.05'],
    'fast spindle': ['/**.spindle_speed_rpm=1200.0'],
}


def commissioned(experiments_dir, sets, plants=10):
    commissioning = load_experiment(experiments_dir / 'commissioning.yaml').with_sets(sets)
    ident = identify([record(commissioning).recording])
    job = load_experiment(experiments_dir / 'park1998_fig8.yaml').with_sets(sets)
    depths = [d for d in job.plant.depth_mm if d > 0]
    found = ident.parameters((min(depths), max(depths)), 1.0, job.controller.reference_force_n)
    identified = [a for node, params in found.items() for a in assignments(node, params)]
    return ident, job, verify(job, ident, identified, 1.0, plants=plants, seed=3)


@pytest.mark.parametrize('machine', list(MACHINES))
def test_what_verification_chooses_holds_the_band_as_predicted(experiments_dir, machine):
    _, job, predictions = commissioned(experiments_dir, MACHINES[machine])
    chosen = predictions[0]
    defaults = next(p for p in predictions if p.name == 'defaults')
    assert chosen.in_band >= defaults.in_band
    outcome = simulate(job.with_sets(list(chosen.sets))).metrics
    assert outcome['steady_mean_abs_error_n'] <= BAND_STEADY_N
    assert outcome['ripple_p2p_n'] <= BAND_RIPPLE_N
    for predicted, metric in ((chosen.steady_n, 'steady_mean_abs_error_n'),
                              (chosen.mean_n, 'mean_abs_error_n')):
        assert abs(outcome[metric] - predicted) <= max(0.2 * predicted, 1.0), metric


def test_the_identified_plant_is_the_machine(experiments_dir):
    # The Kienzle machine: what the simulator is told to be, from the identification alone.
    ident, job, _ = commissioned(experiments_dir, MACHINES['kienzle'], plants=1)
    plant = job.with_sets(plant_sets(ident, 1.0, job.plant.current_per_force_a_n)).plant
    assert plant.cutting_exponent == pytest.approx(0.8, abs=0.05)
    # K_s at the programmed feed: the force it gives there, whatever the exponent's error.
    assert plant.specific_cutting_force_n_mm2 * 0.2 ** plant.cutting_exponent == pytest.approx(
        1600.0 * 0.2 ** 0.8, rel=0.05)
    assert plant.cutting_time_constant_s == pytest.approx(0.05, rel=0.1)
    assert plant.servo_time_constant_s == pytest.approx(0.17, rel=0.1)
    assert plant.pmc_dead_time_s == pytest.approx(0.0, abs=0.011)


def test_a_drawn_exponent_turns_the_force_about_the_feed_it_was_fitted_at(experiments_dir):
    # A production cut knows the exponent to a few hundredths at best (one depth, the feeds
    # the loop chose). Drawn with a spread of 0.1 (3 x 0.033) about the Kienzle machine's,
    # the plants' force at the feed where the fit states G's spread is the gain's draw alone
    # (normal, 15 % floor: all of 200 within 4 of it, 60 %), while their exponents spread:
    # the force elsewhere differs, the curve turned about that feed. Drawn apart, an exponent
    # 0.3 off moved it by 100^0.3 = x4 at 100 mm/min.
    ident, job, _ = commissioned(experiments_dir, MACHINES['kienzle'], plants=1)
    g = ident.process['cutting_exponent']
    ident = replace(ident, process=replace(ident.process, parameters={
        **ident.process.parameters, 'cutting_exponent': Estimate(g.value, 0.1 / 3.0)}))
    pivot = ident.process['gain_feed_mm_min'].value
    assert 50.0 < pivot < 400.0   # the staircase's median feed, mm/min
    centre = estimates(ident)
    plants = draw_plants(ident, 200, seed=5)
    exponents = np.array([p['exponent'] for p in plants])
    at_pivot = np.array([p['gain'] * pivot ** p['exponent'] for p in plants])
    nominal = centre['gain'] * pivot ** centre['exponent']
    assert np.ptp(exponents) > 0.3
    assert np.max(np.abs(at_pivot / nominal - 1.0)) < 4.0 * FLOORS['relative']
    # and each drawn plant is one the simulator runs (K_s within its bound)
    for drawn in plants[:20]:
        job.with_sets(plant_sets(ident, 1.0, job.plant.current_per_force_a_n, drawn))


def test_the_drifted_plants_are_issue_16s_drifts_of_the_identified_plant(experiments_dir):
    # Each drift of the population's generator at its smallest, middle and largest size,
    # applied to the identified plant alone: dead time +20, 35, 50 ms; process gain (the
    # force at every feed), the servo's lag and the friction curve x1.2, 1.35, 1.5. One
    # verification holds the identified plant, the drawn ones and these.
    ident, job, predictions = commissioned(experiments_dir, MACHINES['kienzle'], plants=2)
    per = job.plant.current_per_force_a_n

    def plant(values=None):
        return job.with_sets(plant_sets(ident, 1.0, per, values)).plant

    nominal = plant()
    drifted = [plant(values) for values in drifted_plants(ident)]
    assert len(drifted) == 4 * len(DRIFT_SIZES)
    assert {p.plants for p in predictions} == {1 + 2 + len(drifted)}
    for (added_s, factor), (dead, gain, servo, friction) in zip(
            DRIFT_SIZES, (drifted[k:k + 4] for k in range(0, len(drifted), 4)), strict=True):
        assert dead.pmc_dead_time_s == pytest.approx(nominal.pmc_dead_time_s + added_s)
        assert gain.specific_cutting_force_n_mm2 == pytest.approx(
            factor * nominal.specific_cutting_force_n_mm2)
        assert servo.servo_time_constant_s == pytest.approx(
            factor * nominal.servo_time_constant_s)
        for key in ('friction_at_min_feed_a', 'friction_at_max_feed_a'):
            assert getattr(friction, key) == pytest.approx(factor * getattr(nominal, key))
        # and nothing else moved
        assert dead.replace(pmc_dead_time_s=nominal.pmc_dead_time_s) == nominal
        assert friction.replace(friction_at_min_feed_a=nominal.friction_at_min_feed_a,
                                friction_at_max_feed_a=nominal.friction_at_max_feed_a) == nominal


def test_the_defaults_win_over_a_candidate_that_holds_fewer_plants(experiments_dir):
    _, _, predictions = commissioned(experiments_dir, [], plants=4)
    defaults = next(p for p in predictions if p.name == 'defaults')
    # Those holding no fewer plants than the defaults, and no more than 1 N worse on the
    # identified plant, come first, the lowest score first; the chosen one is the first: never
    # one the defaults beat.
    allowed = [p for p in predictions
               if p.in_band >= defaults.in_band and p.steady_n <= defaults.steady_n + 1.0]
    assert defaults in allowed
    assert predictions[:len(allowed)] == allowed
    assert [p.score for p in allowed] == sorted(p.score for p in allowed)


def test_the_sliding_mode_and_pi_candidates_are_verified_with_error_feedback_too():
    # Park's Fig. 8 file rounds the request to the nearest level, as the paper's PMC did, and a
    # job file may. Population seed 42's #138 (a 9.2 rad/s servo damped at 0.34, slowed x1.39
    # by the job, interrupted cuts): PI rounded cycles between two levels, far out of the band;
    # with the product's error feedback the levels average to the request, in the band's ripple.
    machine = replace(draw(139, 42)[138], approach_s=1.0)
    experiments = Path(__file__).resolve().parents[2] / 'config' / 'experiments'
    cut = {quantiser: run_job(machine, ['force_controller.controller=pi',
                                        f'force_controller.quantiser={quantiser}'], experiments)
           for quantiser in ('nearest', 'error_feedback')}
    assert cut['nearest']['ripple_p2p_n'] > 2.0 * BAND_RIPPLE_N
    assert cut['error_feedback']['ripple_p2p_n'] <= BAND_RIPPLE_N
    assert cut['error_feedback']['steady_mean_abs_error_n'] < \
        0.5 * cut['nearest']['steady_mean_abs_error_n']
    # so each of those candidates goes to the plants with the job's quantiser and with it
    for name, sets in CANDIDATES.items():
        if sets is not None and sets[0] in ('force_controller.controller=smc',
                                            'force_controller.controller=pi'):
            twin = name.removesuffix(', error feedback')
            assert CANDIDATES[twin] is not None
            assert 'force_controller.quantiser=error_feedback' not in CANDIDATES[twin]
            assert CANDIDATES[twin + ', error feedback'] == (
                *CANDIDATES[twin], 'force_controller.quantiser=error_feedback')


def test_the_score_is_the_distance_from_the_band():
    # In band below 1, the steady error first; a ripple over the band adds its excess; a run
    # far out (or none) counts as MAX_COST at most.
    assert cost(2.5, 20.0) == pytest.approx(0.5)
    assert cost(2.5, 50.0) == pytest.approx(1.5)
    assert cost(500.0, 20.0) == MAX_COST
    assert cost(float('nan'), 20.0) == MAX_COST
