"""The control chain: one block in, the PMC's next decision out, as the graph makes it."""

from __future__ import annotations

import math

import numpy as np

from turning_force.core.control import ControllerSettings, make_controller
from turning_force.core.estimation.estimator import ForceEstimator
from turning_force.core.estimation.settings import EstimateStatus
from turning_force.core.experiment import load_experiment
from turning_force.core.kernel.chain import ControlChain, command_for
from turning_force.core.kernel.simulate import simulate
from turning_force.core.plant.lathe import LathePlant
from turning_force.core.pmc.gate import OverrideGate
from turning_force.core.pmc.settings import Reason


def test_the_chain_is_the_nodes_pieces_in_the_graphs_order(experiments_dir):
    # The chain must decide exactly what the three nodes' pieces decide when composed by hand
    # in the graph's order (estimate -> gate.on_estimate -> command -> gate.on_command ->
    # answer): the graph and the core loop then cannot drift apart.
    e = load_experiment(experiments_dir / 'park1998_fig8.yaml')
    plant = LathePlant(e.plant)
    chain = ControlChain(e.estimator, e.controller, e.bridge)
    estimator, controller = ForceEstimator(e.estimator), make_controller(e.controller)
    gate = OverrideGate(e.bridge, t_s=0.0)
    applied = 100.0
    for _ in range(300):
        block = plant.step(applied).currents
        t_end = block.t0_s + len(block) * block.sample_period_s
        step = chain.step(block)
        estimate = estimator.update(block)
        gate.on_estimate(estimate.force_n, estimate.status)
        command = command_for(controller, estimate)
        if command is not None:
            gate.on_command(command.override_pct, t_end, command.reachable)
        by_hand = gate.answer(t_end)
        assert step.decision == by_hand
        assert step.command == command
        applied = by_hand.applied_pct


def test_no_command_on_an_estimate_that_says_nothing_new():
    controller = make_controller(ControllerSettings())
    from turning_force.core.estimation.settings import ForceEstimate

    for status in (EstimateStatus.INVALID_INPUT, EstimateStatus.STALE):
        assert command_for(controller, ForceEstimate(0.0, 400.0, 0.0, 0.0, 0.0, status)) is None
    assert command_for(controller, ForceEstimate(0.0, math.nan, 0.0, 0.0, 0.0)) is None
    assert command_for(controller, ForceEstimate(0.0, 400.0, 0.0, 0.0, 0.0)) is not None


def test_a_sensor_fault_trips_the_watchdog_and_the_loop_recovers(experiments_dir):
    # 0.3 s of NaN currents from t = 2 s: the estimator refuses the blocks, the controller is
    # silent, after watchdog_period_s (0.05 s) the gate writes the safe override (feed hold);
    # when the sensor is back the filter restarts and the loop regulates again.
    e = load_experiment(experiments_dir / 'park1998_fig8.yaml').with_sets([
        'lathe_sim.sensor_fault_start_s=2.0', 'lathe_sim.sensor_fault_duration_s=0.3',
        'experiment.duration_s=4.0'])
    trace = simulate(e).trace
    t, applied = trace['t_s'], trace['applied_override_pct']
    assert np.all(np.isfinite(trace['estimated_force_n']))
    # Blocks ending in (2.0, 2.3] are NaN; the decision after block k applies from k+1.
    held = (t > 2.0 + 0.05 + 0.02) & (t <= 2.3)
    assert np.all(applied[held] == 0.0)
    before = (t > 1.0) & (t <= 2.0)
    assert np.all(applied[before] > 0.0)
    # Back on the reference within a second of the sensor's return (the feed restarts from a
    # hold, like a depth step from zero).
    back = t > 3.4
    assert np.max(np.abs(trace['force_n'][back] - 500.0)) < 25.0


def test_air_cut_runs_disarmed_at_the_programmed_feed(experiments_dir):
    e = load_experiment(experiments_dir / 'air_cut.yaml')
    assert not e.bridge.armed
    trace = simulate(e).trace
    assert np.all(trace['applied_override_pct'] == 100.0)


def test_a_hold_in_the_core_loop_is_the_gates(experiments_dir):
    e = load_experiment(experiments_dir / 'park1998_fig8.yaml').with_sets(
        ['pmc_bridge.overload_force_n=700.0', 'experiment.duration_s=6.0'])
    chain_reasons = []
    plant = LathePlant(e.plant)
    chain = ControlChain(e.estimator, e.controller, e.bridge)
    applied = 100.0
    for _ in range(600):
        step = chain.step(plant.step(applied).currents)
        chain_reasons.append(step.decision.reason)
        applied = step.decision.applied_pct
    assert Reason.OVERLOAD_HOLD in chain_reasons
    first = chain_reasons.index(Reason.OVERLOAD_HOLD)
    assert set(chain_reasons[first:]) == {Reason.OVERLOAD_HOLD}
    assert 4.0 <= first * 0.01 <= 4.5   # the first depth step, at 4 s, passes 700 N


def test_friction_drift_is_re_zeroed_before_the_cut(experiments_dir):
    # Friction 35 % above what the estimator was calibrated with biased the regulated force by
    # 32 N (steady). With a 2 s air move before the cut the estimator re-zeroes the friction
    # and the bias is gone; switched off, it stays. Analysis: at the cut's feeds the extra
    # friction is 0.35 x 0.5 A = 0.17 A, 28 N by Eq. 26's slope.
    sets = ['lathe_sim.depth_times_s=[0.0, 2.0, 6.0, 10.0]',
            'lathe_sim.depth_mm=[0.0, 1.0, 2.0, 3.0]', 'experiment.duration_s=14.0',
            'lathe_sim.friction_at_min_feed_a=0.81', 'lathe_sim.friction_at_max_feed_a=0.4725',
            'force_controller.quantiser=error_feedback', 'force_controller.smc_epsilon_n=0.0']
    e = load_experiment(experiments_dir / 'park1998_fig8.yaml').with_sets(sets)
    off = simulate(e.with_sets(['force_estimator.rezero_below_n=0.0'])).metrics
    on = simulate(e).metrics
    assert off['steady_mean_abs_error_n'] > 20.0
    assert on['steady_mean_abs_error_n'] < 3.0
