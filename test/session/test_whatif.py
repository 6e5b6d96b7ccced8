"""Closed-loop what-if replay (issue 18 item 2): a candidate tried on a recorded cut, on the
machine identified from the commissioning session, predicts what a real run of it gives.

On simulated machines the truth is known: the candidate's real run on the true machine is the
check. The issue's bounds: the steady error within 20 % or 1 N of the real run's, and two
candidates ranked as their real runs rank."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from turning_force.cli import main
from turning_force.commands.core_session import record_core
from turning_force.core.experiment import load_experiment
from turning_force.core.kernel.simulate import simulate
from turning_force.session.whatif import REALISATIONS, typical, what_if

EXPERIMENTS = Path(__file__).resolve().parents[2] / 'config' / 'experiments'
# Two of the commissioning issue's machines: a Kienzle material, a noisy drive.
MACHINES = {
    'kienzle': ['lathe_sim.cutting_exponent=0.8',
                'lathe_sim.specific_cutting_force_n_mm2=1600.0'],
    'noisy drive': ['lathe_sim.current_noise_a=0.1', 'lathe_sim.force_noise_fraction=0.05'],
}
CANDIDATES = (('force_controller.controller=mpc',), ('force_controller.smc_epsilon_n=60.0',))
STEADY = 'steady_mean_abs_error_n'


def close(predicted: float, real: float) -> bool:
    return abs(predicted - real) <= max(0.2 * real, 1.0)


@pytest.mark.parametrize('machine', sorted(MACHINES))
def test_a_candidate_on_a_recorded_cut_predicts_its_real_run(tmp_path, capfd, machine):
    sets = MACHINES[machine]
    record_core(load_experiment(EXPERIMENTS / 'commissioning.yaml').with_sets(sets),
                tmp_path / 'commissioning')
    job = load_experiment(EXPERIMENTS / 'park1998_fig8.yaml').with_sets(sets)
    record_core(job, tmp_path / 'job')
    results = {}
    for candidate in CANDIDATES:
        result = what_if(tmp_path / 'job', candidate, [tmp_path / 'commissioning'])
        real = simulate(job.with_sets(list(candidate))).metrics[STEADY]
        assert close(result.predicted[STEADY], real), (candidate, result.predicted[STEADY], real)
        results[candidate] = (result.predicted[STEADY], real)
        # The prediction is one of the noise draws, shown with their range.
        low, high = result.spread
        assert low <= result.predicted[STEADY] <= high
        # The model's replay of the recorded settings is the fit the user is shown.
        assert close(result.replayed[STEADY], result.recorded[STEADY])
    (p1, r1), (p2, r2) = results.values()
    assert (p1 < p2) == (r1 < r2)   # ranked as the real runs rank
    # The command prints the same, in JSON where asked.
    assert main(['replay', str(tmp_path / 'job'), '--closed-loop', '--identified-from',
                 str(tmp_path / 'commissioning'), '--json', '--set', CANDIDATES[0][0]]) == 0
    printed = json.loads(capfd.readouterr().out)
    assert printed['predicted'][STEADY] == results[CANDIDATES[0]][0]


def test_the_typical_draw_is_the_likelier_outcome_not_between_two():
    # A loop with two outcomes (the oscillation alarm rising in some draws and not in others):
    # the median (51 N) is neither, and a run comes within 20 % of it in none of the draws;
    # the typical draw is within 20 % of three, and of the two clusters of three the one
    # nearer the median.
    draws = [30.0, 30.2, 30.5, 51.0, 120.0, 121.0, 122.0]
    assert typical(draws) == 30.5
    # One outcome: the draw nearest the median of those most others are near.
    assert typical([4.3, 4.4, 4.5, 4.6, 4.7]) == 4.5
    # Not forces (no 1 N floor): 20 % alone.
    assert typical([0.1, 0.5, 0.52, 0.53, 0.9], in_newtons=False) == 0.52
    assert REALISATIONS % 2 == 1
