"""The batch API (core/batch.py): replay_chain and run_core, the compiled loops, against the same
chain stepped one block at a time as the nodes step it (ControlChain: the plant, the estimator,
the controller and the gate each called per block), field for field; run_core's result against
simulate's; its currents against the plant's; replay of a closed-loop run's currents against
the run.

Every comparison is to the bit (``assert_array_equal``, NaN equal to NaN): both run the same
compiled functions in the same order, and the issue's 1e-9 is kept for the recorded reference
session only (recorded through BLAS, test_reference_bag.py)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from test_kernel import EXPERIMENTS, FIG8, FILES

from turning_force.commands import robustness
from turning_force.core.control import drift as drift_monitor
from turning_force.core.control.law import CS_DRIFT, CS_LAW
from turning_force.core.errors import NoCutError
from turning_force.core.estimation.settings import EstimateStatus
from turning_force.core.experiment import Experiment, load_experiment
from turning_force.core.kernel import batch
from turning_force.core.kernel.batch import (
    ChainTrace,
    CoreRun,
    CurrentArrays,
    InputArrays,
    pmc_codes,
    replay_chain,
    run_core,
)
from turning_force.core.kernel.chain import ControlChain
from turning_force.core.kernel.simulate import TRACE_NAMES, SimulationResult, simulate
from turning_force.core.metrics import compute_metrics
from turning_force.core.plant.drive import CurrentBlock
from turning_force.core.plant.lathe import LathePlant
from turning_force.core.pmc.overrides import get_table
from turning_force.core.pmc.settings import Reason
from turning_force.core.pmc.shopfloor import InputValues

# Long enough for the engagement and the first depth step of every file (fig8's at 4 s).
MAX_S = 6.0


def shortened(e: Experiment) -> Experiment:
    if e.run.duration_s <= MAX_S:
        return e
    return e.with_sets([f'experiment.duration_s={MAX_S}'])


def assert_same_chain(got: ChainTrace, expected: ChainTrace) -> None:
    for f in dataclasses.fields(ChainTrace):
        a, b = getattr(got, f.name), getattr(expected, f.name)
        if isinstance(b, np.ndarray):
            assert a.dtype == b.dtype, f.name
            np.testing.assert_array_equal(a, b, err_msg=f.name)
    assert got.estimate_detail == expected.estimate_detail


def assert_same_run(got: CoreRun, expected: CoreRun) -> None:
    for name, values in expected.result.trace.items():
        np.testing.assert_array_equal(got.result.trace[name], values, err_msg=name)
    metrics = {k: v for k, v in expected.result.metrics.items() if k != 'realtime_factor'}
    assert {k: v for k, v in got.result.metrics.items() if k != 'realtime_factor'} == metrics
    for f in dataclasses.fields(CurrentArrays):
        np.testing.assert_array_equal(getattr(got.currents, f.name),
                                      getattr(expected.currents, f.name), err_msg=f.name)
    assert_same_chain(got.chain, expected.chain)
    assert set(got.plant) == set(expected.plant)
    for name, values in expected.plant.items():
        np.testing.assert_array_equal(got.plant[name], values, err_msg=name)


def stepped(e: Experiment) -> CoreRun:
    """The closed loop one block at a time, as the graph's nodes run it: the plant, then
    ControlChain (estimator, controller, gate: each a compiled function called per block)."""
    chain = ControlChain(e.estimator, e.controller, e.bridge)
    applied = e.plant.approach_override_pct
    plant = LathePlant(e.plant, initial_override_pct=applied)
    n = round(e.run.duration_s / e.run.control_period_s)
    m = e.plant.samples_per_block
    currents = CurrentArrays.empty(n, m, 1.0 / e.plant.sample_rate_hz)
    trace = ChainTrace._empty(n)
    rows = np.empty((n, len(TRACE_NAMES)))
    plant_rows = {name: np.empty(n) for name in ('force_n', 'depth_mm', 'feed_mm_rev',
                                                  'feed_rate_mm_min', 'override_pct',
                                                  'spindle_speed_rpm')}
    command = None
    for k in range(n):
        block = plant.step(applied)
        b = block.currents
        currents.t0_s[k] = b.t0_s
        currents.phase_u_a[k], currents.phase_v_a[k] = b.phase_u_a, b.phase_v_a
        currents.rotor_angle_rad[k], currents.feed_rate_mm_min[k] = (b.rotor_angle_rad,
                                                                     b.feed_rate_mm_min)
        step = chain.step(b, inputs=block.inputs)
        reference_now = chain.controller.reference_force_n   # the tool's, with a tools file
        trace._put(k, step, reference_now)
        command = step.command or command
        pct, sliding, reach, oscillating, drift, drift_size = (
            (applied, 0.0, 1.0, 0.0, 0.0, 0.0) if command is None else
            (command.override_pct, command.sliding_variable, float(command.reachable),
             float(command.oscillating), float(command.drift), command.drift_size))
        rows[k] = (b.t0_s + len(b) * b.sample_period_s, block.force_n[-1],
                   step.estimate.force_n, step.estimate.force_rate_n_s,
                   reference_now if e.controller.tools_file else e.controller.reference_force_n,
                   block.depth_mm[-1], block.feed_mm_rev[-1],
                   pct, applied, sliding, reach, oscillating, block.spindle_speed_rpm,
                   int(step.decision.reason), drift, drift_size,
                   *drift_monitor.adopted(chain.controller.arrays[1][CS_DRIFT:CS_LAW]))
        plant_rows['spindle_speed_rpm'][k] = block.spindle_speed_rpm
        plant_rows['force_n'][k], plant_rows['depth_mm'][k] = (block.force_n[-1],
                                                                block.depth_mm[-1])
        plant_rows['feed_mm_rev'][k] = block.feed_mm_rev[-1]
        plant_rows['feed_rate_mm_min'][k] = b.feed_rate_mm_min[-1]
        plant_rows['override_pct'][k] = applied
        applied = step.decision.applied_pct
    plant_rows['specific_cutting_force_n_mm2'] = e.plant.material_at(currents.t_end_s)
    t = {name: rows[:, i] for i, name in enumerate(TRACE_NAMES)}
    try:
        metrics = compute_metrics(t['t_s'], t['force_n'], t['reference_n'], t['depth_mm'],
                                  t['applied_override_pct'],
                                  e.plant.depth_profile.change_times_s(), e.metric_settings,
                                  reachable=t['reference_reachable'] > 0.5,
                                  estimate_n=t['estimated_force_n'],
                                  oscillation_alarm=t['oscillation_alarm'])
    except NoCutError:
        metrics = {}
    result = SimulationResult(t, metrics)
    return CoreRun(result, currents, trace, plant_rows, list(chain.cuts))


def assert_simulates(run: CoreRun, e: Experiment) -> None:
    """run_core's result is simulate's: every trace column, every metric."""
    result = simulate(e)
    for name, values in result.trace.items():
        np.testing.assert_array_equal(run.result.trace[name], values, err_msg=name)
    for name, value in result.metrics.items():
        if name != 'realtime_factor':
            assert run.result.metrics[name] == value, name


def plant_inputs(e: Experiment, currents: CurrentArrays,
                 spindle_speed_rpm: np.ndarray | None = None) -> InputArrays:
    """The simulated machine's inputs at each block's end, as the core loop hands them on (the
    spindle speed the run recorded, where its input is wired)."""
    ends = currents.t_end_s

    def at(k: int) -> InputValues:
        inputs = e.plant.inputs_at(float(ends[k]))
        if spindle_speed_rpm is None or not e.plant.spindle_speed_wired:
            return inputs
        return dataclasses.replace(inputs, spindle_speed_rpm=float(spindle_speed_rpm[k]))

    return InputArrays.collect(at, len(currents))


def replayed_stepwise(e: Experiment, currents: CurrentArrays, changes: list[tuple[float, bool]],
                      inputs: object = None) -> ChainTrace:
    """Replay one block at a time through ControlChain (what replay does with blocks no one
    array holds)."""
    return batch._replay_blocks(e, currents.block, len(currents), changes, inputs, None)


def replays_itself(run: CoreRun, e: Experiment) -> ChainTrace:
    """Open loop over the run's own currents: the same chain, row for row."""
    trace = replay_chain(e, run.currents, [(0.0, e.bridge.armed)],
                         plant_inputs(e, run.currents, run.result.trace['spindle_speed_rpm']))
    assert_same_chain(trace, run.chain)
    return trace


@pytest.mark.parametrize('path', FILES, ids=[p.stem for p in FILES])
def test_every_experiment_file(path):
    e = shortened(load_experiment(path))
    run = run_core(e)
    assert_same_run(run, stepped(e))
    assert run.cuts == stepped(e).cuts
    assert_simulates(run, e)
    replays_itself(run, e)


def _matrix_rows() -> list[object]:
    """Every (scenario, controller) of the matrix; in ``make test`` each scenario once, the
    controllers taken in turn (every scenario and every law held to the stepped loop), the other
    rows in ``make test-all`` (marked slow: about 5 s each)."""
    laws = sorted(robustness.CONTROLLERS)
    rows = []
    for i, scenario in enumerate(robustness.MATRIX):
        for j, law in enumerate(laws):
            marks = () if j == i % len(laws) else (pytest.mark.slow,)
            rows.append(pytest.param(scenario, law, marks=marks, id=f'{law}-{scenario.name}'))
    return rows


@pytest.mark.parametrize(('scenario', 'controller'), _matrix_rows())
def test_the_robustness_matrix(scenario, controller):
    e = robustness.scenario_experiment(EXPERIMENTS, scenario, controller).with_sets(
        ['experiment.duration_s=4.5'])
    run = run_core(e)
    assert_same_run(run, stepped(e))
    replays_itself(run, e)


FAULTS_AND_SETTINGS = {
    'sensor fault (NaN blocks, watchdog, restart)': [
        'lathe_sim.sensor_fault_start_s=2.0', 'lathe_sim.sensor_fault_duration_s=0.3'],
    'overload hold': ['pmc_bridge.overload_force_n=700.0'],
    'disarmed': ['pmc_bridge.armed=false'],
    'saturated current sensor': ['force_estimator.current_range_a=3.0'],
    'implausible currents': ['force_estimator.current_range_a=1.0'],
    'low-pass filter': ['force_estimator.force_filter=lowpass',
                        'force_estimator.lowpass_order=5'],
    'pole placement': ['force_controller.controller=adaptive_pp',
                       '/**.override_table=fanuc_8bit'],
    'adaptive SMC, 1 % force noise': ['force_controller.controller=adaptive_smc',
                                      'lathe_sim.force_noise_fraction=0.01'],
    'nonlinear surface, error feedback': ['force_controller.smc_surface=nonlinear',
                                          'force_controller.quantiser=error_feedback'],
    'dead time, second-order servo, predictor': [
        'lathe_sim.pmc_dead_time_s=0.08', 'force_controller.model_dead_time_s=0.08',
        'lathe_sim.servo_model=second_order', 'force_controller.model_servo_model=second_order',
        'force_controller.smc_epsilon_n=0.0'],
    'no predictor, park surface': ['force_controller.smc_predictor=false',
                                   'force_controller.smc_surface=park1998'],
    'taper, exponent 0.5, no process lag': [
        'lathe_sim.depth_interpolation=linear', 'lathe_sim.cutting_exponent=0.5',
        'lathe_sim.cutting_time_constant_s=0.0'],
    'exponent 0.95, ideal table': ['lathe_sim.cutting_exponent=0.95',
                                   '/**.override_table=ideal'],
    '20 kHz DAQ (200 samples a block: numpy sums them in halves)': [
        'lathe_sim.sample_rate_hz=20000.0'],
    'shop-floor settings that leave the override alone (no inputs wired)': [
        'pmc_bridge.overload_reaction=alarm', 'pmc_bridge.threading_stand_down=false',
        'pmc_bridge.operator_dial=product', 'pmc_bridge.engage_force_n=300.0',
        'lathe_sim.dynamometer=true'],
    'staircase (commissioning)': ['force_controller.controller=staircase',
                                  'force_controller.staircase_step_s=0.5'],
    'friction re-zero in air': [
        'lathe_sim.depth_times_s=[0.0, 2.0, 6.0]', 'lathe_sim.depth_mm=[0.0, 1.0, 2.0]',
        'lathe_sim.friction_at_min_feed_a=0.81'],
}


@pytest.mark.parametrize('sets', FAULTS_AND_SETTINGS.values(), ids=FAULTS_AND_SETTINGS)
def test_faults_and_settings(sets):
    e = load_experiment(FIG8).with_sets([*sets, 'experiment.duration_s=8.0'])
    run = run_core(e)
    assert_same_run(run, stepped(e))
    assert run.cuts == stepped(e).cuts


def test_the_gate_s_outputs_on_the_compiled_loop_are_the_stepped_ones():
    # The gate's cut detector and overload reaction (stop): the same rows either way.
    e = load_experiment(FIG8).with_sets([
        'pmc_bridge.overload_reaction=stop', 'pmc_bridge.reaction_force_fraction=0.2',
        'pmc_bridge.reaction_delay_s=0.5', 'pmc_bridge.engage_force_n=300.0',
        'lathe_sim.force_noise_fraction=0.02', 'experiment.duration_s=4.0'])
    run, reference = run_core(e), stepped(e)
    assert_same_run(run, reference)
    chain = reference.chain
    assert chain.engaged.any() and not chain.engaged[0]
    assert chain.stop_request.any() and np.array_equal(chain.alarm, chain.stop_request)


def test_the_currents_are_the_plants():
    # Stepping the plant at the overrides the run applied gives every sample the run kept.
    e = load_experiment(FIG8).with_sets(['lathe_sim.current_noise_a=0.05',
                                         'lathe_sim.force_noise_fraction=0.03',
                                         'lathe_sim.pmc_dead_time_s=0.04',
                                         'experiment.duration_s=3.0'])
    run = run_core(e)
    plant = LathePlant(e.plant, initial_override_pct=run.plant['override_pct'][0])
    for k, applied in enumerate(run.plant['override_pct']):
        block = plant.step(float(applied))
        kept = run.currents.block(k)
        assert kept.t0_s == block.currents.t0_s
        for name in ('phase_u_a', 'phase_v_a', 'rotor_angle_rad', 'feed_rate_mm_min'):
            np.testing.assert_array_equal(getattr(kept, name), getattr(block.currents, name))
        assert run.plant['force_n'][k] == block.force_n[-1]
        assert run.plant['feed_rate_mm_min'][k] == block.currents.feed_rate_mm_min[-1]
    assert run.currents.samples_per_block == 10 and len(run.currents) == 300
    assert (run.plant['spindle_speed_rpm'] == e.plant.spindle_speed_rpm).all()


def fig8_run(*sets: str) -> tuple[Experiment, CoreRun]:
    e = load_experiment(FIG8).with_sets([*sets, 'experiment.duration_s=10.0'])
    return e, run_core(e)


def assert_replays_alike(e: Experiment, currents: CurrentArrays,
                         changes: list[tuple[float, bool]], inputs: object = None) -> ChainTrace:
    compiled = replay_chain(e, currents, changes, inputs)   # type: ignore[arg-type]
    assert_same_chain(compiled, replayed_stepwise(e, currents, changes, inputs))
    return compiled


def test_arming_late_and_disarming_mid_run():
    e, run = fig8_run()
    changes = [(0.0, False), (2.0049, True), (5.5, False), (7.0, True), (7.0, False),
               (8.3, True)]
    trace = assert_replays_alike(e, run.currents, changes)
    ends = run.currents.t_end_s
    reason = trace.reason
    assert (reason[ends < 2.0049] == Reason.DISARMED).all()
    assert (trace.applied_pct[ends < 2.0049] == 100.0).all()
    assert (reason[(ends > 2.1) & (ends < 5.5)] == Reason.NORMAL).all()
    assert (reason[(ends >= 5.5) & (ends < 8.3)] == Reason.DISARMED).all()
    assert not trace.armed[(ends >= 5.5) & (ends < 8.3)].any()
    assert trace.armed[ends >= 8.3].all()
    # The controller runs throughout: it is the gate that disarms.
    assert np.isfinite(trace.requested_override_pct).all()


def test_an_overload_hold_and_re_arming_under_it():
    # Held at 700 N; re-armed while the force is still over the limit, the hold stays; once
    # under it (the depth back to 1 mm after 8 s... here: the limit raised), it clears.
    e, run = fig8_run()
    held = e.with_sets(['pmc_bridge.overload_force_n=700.0'])
    trace = assert_replays_alike(held, run.currents, [(0.0, True), (3.0, False), (3.2, True),
                                                      (9.0, False), (9.5, True)])
    assert (trace.reason == Reason.OVERLOAD_HOLD).any()
    assert trace.alarm[trace.reason == Reason.OVERLOAD_HOLD].all()
    assert (trace.applied_pct[trace.reason == Reason.OVERLOAD_HOLD] == 0.0).all()


def test_nan_blocks_the_watchdog_and_a_stamp_jump():
    e, run = fig8_run()
    c = run.currents
    u, v = c.phase_u_a.copy(), c.phase_v_a.copy()
    t0 = c.t0_s.copy()
    u[300:320] = np.nan                 # a dead sensor for 0.2 s: watchdog, filter restart
    v[500, 3] = np.inf                  # one bad sample
    t0[700:] -= 0.5                     # the DAQ's clock goes back: refused, then followed
    broken = dataclasses.replace(c, t0_s=t0, phase_u_a=u, phase_v_a=v)
    trace = assert_replays_alike(e, broken, [(0.0, True)])
    status = trace.estimate_status
    assert (status[300:320] == EstimateStatus.INVALID_INPUT).all()
    assert status[500] == EstimateStatus.INVALID_INPUT
    assert trace.estimate_detail[300] == '10 non-finite samples'
    assert trace.estimate_detail[500] == '1 non-finite samples'
    assert 'is not after the previous' in trace.estimate_detail[700]
    assert (status[700:703] == EstimateStatus.INVALID_INPUT).any()
    assert np.isnan(trace.requested_override_pct[300:320]).all()
    assert trace.reference_reachable[300:320].all()
    assert (trace.reason[305:320] == Reason.WATCHDOG).all()
    assert trace.reason[299] == Reason.NORMAL and trace.reason[330] == Reason.NORMAL


def test_every_control_law_and_filter_replays_alike():
    e = load_experiment(FIG8).with_sets(['experiment.duration_s=6.0'])
    run = run_core(e.with_sets(['lathe_sim.force_noise_fraction=0.02']))
    for sets in (['force_controller.controller=adaptive_smc'],
                 ['force_controller.controller=adaptive_pp', '/**.override_table=fanuc_8bit'],
                 ['force_controller.controller=adaptive'],
                 ['force_controller.controller=staircase'],
                 ['force_estimator.force_filter=lowpass', 'force_controller.smc_surface=nonlinear',
                  'force_controller.quantiser=error_feedback'],
                 ['force_estimator.current_range_a=3.0']):
        assert_replays_alike(e.with_sets(sets), run.currents, [(0.0, True)])


def test_the_machines_inputs():
    e, run = fig8_run()
    n = len(run.currents)
    wired = InputArrays(np.arange(n) % 7 == 0, np.full(n, 1, dtype=np.int8),
                        np.full(n, 0, dtype=np.int8), np.full(n, np.nan))
    # The decisions say what they saw.
    trace = assert_replays_alike(e, run.currents, [(0.0, True)], inputs=wired)
    assert (trace.program_enable[:7] == 1).all() and (trace.threading == 0).all()
    # A function of the block gives the same.
    again = replay_chain(e, run.currents, [(0.0, True)], inputs=lambda k: wired(k))
    assert_same_chain(again, trace)
    # Threading stands the gate down, and a dial lowers it, alike on both paths.
    threading = dataclasses.replace(wired, threading=np.full(n, 1, dtype=np.int8))
    stood_down = e.with_sets(['pmc_bridge.threading_stand_down=true'])
    trace = assert_replays_alike(stood_down, run.currents, [(0.0, True)], inputs=threading)
    assert (trace.reason[1:] == Reason.OPERATOR).all()
    dial = dataclasses.replace(wired, operator_dial_pct=np.full(n, 50.0))
    trace = assert_replays_alike(e.with_sets(['pmc_bridge.operator_dial=min']), run.currents,
                                 [(0.0, True)], inputs=dial)
    assert trace.applied_pct.max() <= 50.0
    assert (trace.operator_dial_pct[7:] == 50.0).all()


def head(trace: ChainTrace, n: int) -> ChainTrace:
    return dataclasses.replace(trace, estimate_detail={
        k: text for k, text in trace.estimate_detail.items() if k < n}, **{
        f.name: getattr(trace, f.name)[:n] for f in dataclasses.fields(ChainTrace)
        if isinstance(getattr(trace, f.name), np.ndarray)})


def test_short_replays_and_lists_of_blocks():
    e, run = fig8_run()
    short = [run.currents.block(k) for k in range(50)]
    # A list of blocks of one shape goes through the compiled loop, however short; one of
    # another length one block at a time.
    compiled = replay_chain(e, short, [(0.0, True)])
    odd = [*short[:-1], CurrentBlock(short[-1].t0_s, 1e-3, short[-1].phase_u_a[:5],
                                     short[-1].phase_v_a[:5], short[-1].rotor_angle_rad[:5],
                                     short[-1].feed_rate_mm_min[:5])]
    trace = replay_chain(e, odd, [(0.0, True)])
    assert_same_chain(head(trace, 49), head(compiled, 49))
    assert trace.estimate_status[-1] == EstimateStatus.OK   # a shorter block is estimated


def test_current_arrays():
    _, run = fig8_run()
    c = run.currents
    block = c.block(3)
    assert block.phase_u_a.base is not None and len(block) == 10   # a view
    again = CurrentArrays.from_blocks([c.block(k) for k in range(len(c))])
    for f in dataclasses.fields(CurrentArrays):
        np.testing.assert_array_equal(getattr(again, f.name), getattr(c, f.name))
    np.testing.assert_array_equal(c.t_end_s, run.result.trace['t_s'])


@pytest.mark.parametrize('table', ['fanuc_0t_4bit', 'fanuc_8bit', 'ideal'])
def test_pmc_codes_are_the_tables(table):
    t = get_table(table)
    applied = np.array([t.quantise(p) for p in np.linspace(0.0, t.max_pct, 97)])
    np.testing.assert_array_equal(pmc_codes(t, applied), [t.encode(p)[0] for p in applied])
    if not t.continuous:
        with pytest.raises(ValueError, match='not a level'):
            pmc_codes(t, np.array([t.levels_pct[1] + 0.5]))


def test_input_arrays_carry_the_last_given():
    given = np.array([False, True, False, True, False])
    inputs = InputArrays(given, np.array([0, 1, 0, 0, 0], dtype=np.int8),
                         np.array([0, -1, 0, 1, 0], dtype=np.int8),
                         np.array([math.nan, 80.0, 0.0, math.nan, 0.0]))
    assert inputs(0) is None
    assert inputs(1) == InputValues(True, None, 80.0)
    assert inputs(3) == InputValues(False, True, None)
    enable, threading, dial, _ = inputs.seen()
    np.testing.assert_array_equal(enable, [-1, 1, 1, 0, 0])
    np.testing.assert_array_equal(threading, [-1, -1, -1, 1, 1])
    np.testing.assert_array_equal(dial, [math.nan, 80.0, 80.0, math.nan, math.nan])


def test_a_friction_re_zero_in_air_and_its_notes():
    e = load_experiment(FIG8).with_sets([
        'lathe_sim.depth_times_s=[0.0, 2.0, 6.0]', 'lathe_sim.depth_mm=[0.0, 1.0, 2.0]',
        'lathe_sim.friction_at_min_feed_a=0.81', 'experiment.duration_s=3.0'])
    run = run_core(e)
    assert_same_run(run, stepped(e))
    assert any('re-zeroed' in text for text in run.chain.estimate_detail.values())
    replays_itself(run, e)


# The tool in the cut three times: 1, 2 and 3 mm from 0, 3 and 6 s, out of it from 2, 5 and 8 s.
IN_AND_OUT = ['experiment.duration_s=9.0',
              'lathe_sim.depth_times_s=[0.0, 2.0, 3.0, 5.0, 6.0, 8.0]',
              'lathe_sim.depth_mm=[1.0, 0.0, 2.0, 0.0, 3.0, 0.0]']


@pytest.mark.parametrize('sets', [
    [],
    ['pmc_bridge.overload_force_n=900.0'],         # events past 720 N, then a hold
    ['pmc_bridge.overload_force_n=900.0', 'lathe_sim.force_noise_fraction=0.05',
     'pmc_bridge.engage_time_s=0.05'],
    ['pmc_bridge.overload_force_n=700.0'],
], ids=['cuts', 'events', 'noisy-debounce', 'hold'])
def test_the_cut_log_of_the_compiled_loop_is_the_gates(sets):
    """CoreRun.cuts (the compiled loop's) against the gate's own cut log stepped block by
    block: equal, field for field; and what analysis says of them."""
    e = load_experiment(FIG8).with_sets([*IN_AND_OUT, *sets])
    compiled = run_core(e)
    reference = stepped(e)
    assert compiled.cuts == reference.cuts
    cuts = reference.cuts
    if not sets:
        # Analysis: the force rises and falls with tau_c = 50 ms past the 100 N engage and 50 N
        # exit thresholds, so a cut starts within a block or two of the depth's step in and
        # ends within 0.15 s of its step out (the debounce's blocks are taken off).
        assert [c.index for c in cuts] == [1, 2, 3]
        for cut, t_in, t_out in zip(cuts, (0.0, 3.0, 6.0), (2.0, 5.0, 8.0), strict=True):
            assert t_in <= cut.start_s <= t_in + 0.03 and t_out <= cut.end_s <= t_out + 0.15
            assert cut.complete and not cut.breakage and cut.overload_events == 0
        assert cuts[0].min_override_pct >= 50.0   # 1 mm holds 500 N near 114 %
    else:
        # The 2 mm entry overshoots past the reaction's limit (0.8 x overload_force_n) and past
        # overload_force_n: the hold (0 %) ends the cut and the feed stays held.
        assert len(cuts) == 2 and cuts[1].min_override_pct == 0.0
        assert cuts[1].overload_events >= 1 and cuts[1].max_force_n > e.bridge.overload_force_n


@settings(max_examples=10, derandomize=True, deadline=None,
          suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(st.tuples(st.floats(0.05, 0.8), st.sampled_from([0.0, 0.0, 0.5, 1.0, 2.5])),
                min_size=2, max_size=8),
       st.sampled_from([0.01, 0.03, 0.05]), st.sampled_from([650.0, 900.0, 2000.0]))
def test_any_schedule_of_cuts_logs_as_the_gate_does(steps, engage_time_s, overload_force_n):
    """Depth steps in and out of the cut, some shorter than the engagement's debounce, at
    overload limits that hold, only raise events, or neither: the rows' cut log is the gate's."""
    times = [0.0]
    for length, _ in steps[:-1]:
        times.append(round(times[-1] + length, 2))
    e = load_experiment(FIG8).with_sets([
        f'experiment.duration_s={times[-1] + steps[-1][0] + 0.3:.2f}',
        f'lathe_sim.depth_times_s={times}', f'lathe_sim.depth_mm={[d for _, d in steps]}',
        f'pmc_bridge.engage_time_s={engage_time_s}',
        f'pmc_bridge.overload_force_n={overload_force_n}'])
    assert run_core(e).cuts == stepped(e).cuts
