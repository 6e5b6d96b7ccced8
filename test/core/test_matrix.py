"""The robustness matrix's bands (issue: regulation that holds on a real machine).

Fig. 8 on fifteen machines (PMC dead time 0-120 ms, first- and second-order servos, K_s x 0.7
and x 1.4, current noise, force fluctuation, the 8-bit table), the SMC tuned from the machine's
model. Bands from the issue: steady <= 5 N (1 % of F_ref); ripple p-p <= 20 N (35 N at 0.1 A
of current noise); full-run mean <= 15 N up to 80 ms of dead time and <= 20 N at 120 ms (not
held where the reference is out of reach for part of the run); and better than the fixed-gain
PI in steady and mean everywhere. test/bench/bench_matrix.py prints the whole table.
"""

from __future__ import annotations

import numpy as np
import pytest

from turning_force.commands.robustness import MATRIX, Scenario, run_scenario, scenario_experiment

# Rows that restate Fig. 8's own values (servo 0.17 s, 0.02 A of noise): the machine of 'dead
# time 0 ms', with the same bands. They run in make test-all.
FIG8_AGAIN = ('servo tau 0.17 s', 'current noise 0.02 A')


@pytest.mark.parametrize('scenario', [
    pytest.param(s, id=s.name, marks=(pytest.mark.slow,) if s.name in FIG8_AGAIN else ())
    for s in MATRIX])
def test_the_identified_smc_holds_its_bands(scenario: Scenario, experiments_dir):
    smc = run_scenario(scenario_experiment(experiments_dir, scenario, 'smc'))
    pi = run_scenario(scenario_experiment(experiments_dir, scenario, 'pi'))
    assert smc['steady_mean_abs_error_n'] <= 5.0
    assert smc['ripple_p2p_n'] <= scenario.max_ripple_n
    if scenario.max_mean_n is not None:
        assert smc['reachable_fraction'] == 1.0
        assert smc['mean_abs_error_n'] <= scenario.max_mean_n
    assert smc['steady_mean_abs_error_n'] < pi['steady_mean_abs_error_n']
    assert smc['mean_abs_error_n'] < pi['mean_abs_error_n']


def test_an_unreachable_reference_is_reported_and_left_out(experiments_dir):
    # K_s x 0.7: at 1 mm even 150 % gives 1540 * 1 * 0.3 = 462 N < 500 N. The controller
    # pins the feed at 150 % from engagement and says so once it has sat there for
    # unreachable_after_s (1 s, after the engagement transient); at the 4 s step to 2 mm the
    # reference is reachable again. The steady figure leaves that span out and
    # reachable_fraction says how much was left out.
    from turning_force.core.kernel.simulate import simulate

    scenario = next(s for s in MATRIX if s.name == 'K_s x 0.7')
    result = simulate(scenario_experiment(experiments_dir, scenario, 'smc'))
    t, reachable = result.trace['t_s'], result.trace['reference_reachable']
    out = t[reachable == 0.0]
    assert 1.0 <= out[0] <= 2.0          # pinned from the start; reported 1 s later
    assert 3.99 <= out[-1] <= 4.05       # reachable again at the step to 2 mm
    fraction = result.metrics['reachable_fraction']
    assert fraction == pytest.approx(1.0 - (out[-1] - out[0] + 0.01) / 12.0, abs=0.01)
    assert result.metrics['steady_mean_abs_error_n'] <= 5.0


def test_a_reference_a_few_newtons_out_of_reach_stays_out_through_the_cut_s_fluctuation(
        experiments_dir):
    # K_s 1650 N/mm^2: at 1 mm, 150 % gives 1650 * 1 * 0.3 = 495 N, 5 N short of the
    # reference; the cut's own fluctuation (5 % of the force, 25 N) takes the estimate across
    # the reference many times a second. The predictive law holds 150 % (it does not dip on
    # noise), and the reference is out of reach all the same: flagged from unreachable_after_s
    # after engagement (1 s) to the step to 2 mm at 4 s, and not after. A sample's crossing
    # restarted the clock: the flag never came.
    from turning_force.core.kernel.simulate import simulate

    scenario = next(s for s in MATRIX if s.name == 'K_s x 0.7')
    result = simulate(scenario_experiment(experiments_dir, scenario, 'smc').with_sets([
        'lathe_sim.specific_cutting_force_n_mm2=1650.0', 'lathe_sim.force_noise_fraction=0.05',
        'force_controller.controller=mpc']))
    t, reachable = result.trace['t_s'], result.trace['reference_reachable']
    assert np.all(reachable[(t >= 2.5) & (t < 3.95)] == 0.0)
    assert np.all(reachable[t >= 4.5] == 1.0)
