"""The papers' scenarios through the core loop, checked against the papers' numbers.

Each bound is the paper's own figure or the experiment's allowed error; where the paper gives a
shape rather than a number, the bound says what the shape means and why the tolerance.
"""

import math

import pytest

from turning_force.commands.papers import settled_forces
from turning_force.core.experiment import load_experiment
from turning_force.core.kernel.simulate import simulate


@pytest.fixture(scope='module')
def results(experiments_dir):
    out = {}
    for name in ('park1998_fig1', 'park1998_fig2', 'park1998_fig7', 'park1998_fig8',
                 'park1998_fig11', 'park1998_fig13', 'park1998_fig14', 'hwang1990_example1'):
        experiment = load_experiment(experiments_dir / f'{name}.yaml')
        result = simulate(experiment)
        out[name] = (experiment, result)
    return out


def steady(results, name):
    return results[name][1].metrics['steady_mean_abs_error_n']


def test_smc_with_the_four_bit_override_is_within_parks_figure(results):
    # Park Fig. 8: 8.9 N average tracking error with the 16-level override.
    assert steady(results, 'park1998_fig8') <= 8.9


def test_adaptive_with_the_four_bit_override_is_clearly_worse(results):
    # Park: 61.9 N against 8.9 N, a factor of 7. The quantised override breaks the adaptive
    # loop's linear parametrisation; ours must be at least three times worse than the SMC.
    assert steady(results, 'park1998_fig2') >= 3 * steady(results, 'park1998_fig8')


def test_adaptive_holds_the_force_with_the_eight_bit_override(results):
    # Park Fig. 1: with 1 % steps the adaptive controller regulates; its steady error is a
    # fraction of the four-bit case's.
    assert steady(results, 'park1998_fig1') < 0.5 * steady(results, 'park1998_fig2')


def test_smc_is_nearly_the_same_with_ideal_and_four_bit_override(results):
    # Park Figs. 7 vs 8: the quantisation changes little. The 0.17 s servo averages the
    # dither between two levels, so the steady errors differ by less than 2 N (a 10 % level
    # is 44-132 N of force here), and the transients (mean with them) by less than 10 %.
    fig7, fig8 = results['park1998_fig7'][1].metrics, results['park1998_fig8'][1].metrics
    assert abs(fig7['steady_mean_abs_error_n'] - fig8['steady_mean_abs_error_n']) < 2.0
    assert fig8['mean_abs_error_n'] == pytest.approx(fig7['mean_abs_error_n'], rel=0.10)


@pytest.mark.parametrize(('name', 'paper_n'), [
    ('park1998_fig11', 8.3), ('park1998_fig13', 4.4), ('park1998_fig14', 5.9)])
def test_parks_experiments_stay_within_their_allowed_error(results, name, paper_n):
    experiment, result = results[name]
    assert result.metrics['steady_mean_abs_error_n'] <= experiment.run.allowed_error_n
    assert result.metrics['steady_mean_abs_error_n'] <= paper_n


def test_hwang_and_chen_example_1_returns_to_1000_n_after_each_step(results):
    # Hwang & Chen Fig. 4: back at the 1000 N reference after each depth step (k = 40, 70).
    # Noise-free as in the paper: within 1 N (0.1 %) over the last 0.1 s of each depth.
    experiment, result = results['hwang1990_example1']
    forces = settled_forces(result, experiment.plant.depth_profile.change_times_s())
    assert len(forces) == 3
    for force in forces:
        assert force == pytest.approx(1000.0, abs=1.0)


def test_same_file_and_seed_give_identical_metrics(results):
    experiment, first = results['park1998_fig8']
    again = simulate(experiment)
    for name, value in first.metrics.items():
        if name != 'realtime_factor':
            assert again.metrics[name] == value, name
    other = simulate(experiment.with_sets(['lathe_sim.seed=2']))
    assert other.metrics['steady_mean_abs_error_n'] != first.metrics['steady_mean_abs_error_n']
    assert math.isfinite(other.metrics['steady_mean_abs_error_n'])
