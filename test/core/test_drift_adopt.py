"""The predictive law takes a lag drift the drift monitor names into its model
(``drift_adopt_model``, issue 16 item 2's drift, issue 15's predictive law): the dead time's
queue keeps the levels pending in their order, the servo is the bank's member, and on the
generated machines of bench_drift.py that rang or limit-cycled on the commissioned model after
their servo or PMC dead time drifted, the loop ends in band; an unchanged machine is untouched.
"""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from test_drift import generated

from turning_force.commands import population
from turning_force.core.control import ControllerSettings, drift, make_controller, predictor
from turning_force.core.control.law import CS_DRIFT, OUT_PCT, OUT_SIZE
from turning_force.core.control.laws import mpc, smc
from turning_force.core.control.predictor import model_matrices
from turning_force.core.kernel.simulate import SimulationResult, simulate

PERIOD_S = 0.01
SERVO_S, TAU_C_S = 0.17, 0.05


def pending(cs: np.ndarray, cp: np.ndarray) -> list[float]:
    """The levels in the law's dead-time queue, the oldest (the next to reach the servo)
    first."""
    dead = int(cp[mpc.P_DEAD] + cs[mpc.S_SHIFT])
    at = int(cs[mpc.S_QIDX])
    return [float(cs[mpc.S_QUEUE + (at + j) % dead]) for j in range(dead)]


def test_a_new_dead_time_keeps_the_pending_levels_in_their_order() -> None:
    law = make_controller(ControllerSettings(
        controller='mpc', model_dead_time_s=0.05, model_servo_time_constant_s=SERVO_S,
        model_cutting_time_constant_s=TAU_C_S, initial_override_pct=50.0))
    cp, cs, _ = law.arrays
    for level in (10.0, 20.0, 30.0, 40.0, 50.0, 60.0, 70.0):   # the ring wraps once
        mpc.sent(cp, cs, level)
    assert pending(cs, cp) == [30.0, 40.0, 50.0, 60.0, 70.0]
    # 20 ms longer: the machine applies the oldest level two periods more
    assert mpc.adopt(cp, cs, drift.DEAD_TIME, 0.02)
    assert pending(cs, cp) == [30.0, 30.0, 30.0, 40.0, 50.0, 60.0, 70.0]
    mpc.sent(cp, cs, 80.0)
    assert pending(cs, cp) == [30.0, 30.0, 40.0, 50.0, 60.0, 70.0, 80.0]
    # the bank's member is relative to the commissioned 50 ms: 20 ms shorter drops the oldest
    assert mpc.adopt(cp, cs, drift.DEAD_TIME, -0.02)
    assert pending(cs, cp) == [60.0, 70.0, 80.0]
    # a drift that is no lag is not the law's
    assert not mpc.adopt(cp, cs, drift.GAIN, 0.4)
    assert pending(cs, cp) == [60.0, 70.0, 80.0]


def test_a_servo_drift_is_the_banks_member_with_the_commissioned_dead_time() -> None:
    law = make_controller(ControllerSettings(
        controller='mpc', model_dead_time_s=0.05, model_servo_time_constant_s=SERVO_S,
        model_cutting_time_constant_s=TAU_C_S, initial_override_pct=50.0))
    cp, cs, _ = law.arrays
    mpc.adopt(cp, cs, drift.DEAD_TIME, 0.03)
    scale = drift.SERVO_RATIO ** 6   # what the monitor names for a servo x1.8 (x1.77)
    assert mpc.adopt(cp, cs, drift.SERVO, scale)
    assert cp[mpc.P_SCALES + int(cs[mpc.S_MODEL])] == pytest.approx(scale)
    assert cs[mpc.S_SHIFT] == 0.0 and len(pending(cs, cp)) == 5
    phi, gamma = model_matrices('first_order', SERVO_S * scale, 60.0, 0.7, TAU_C_S,
                                step_s=PERIOD_S)
    at = mpc.P_PHI + mpc.MODEL_SIZE * int(cs[mpc.S_MODEL])
    np.testing.assert_array_equal(cp[at:at + 2], phi[0])
    np.testing.assert_array_equal(cp[at + 3:at + 5], phi[1])
    np.testing.assert_array_equal(cp[at + 9:at + 11], gamma)
    # back to the commissioned model (a tool change: the law is reset after)
    assert mpc.adopt(cp, cs, drift.NONE, 0.0)
    assert cs[mpc.S_MODEL] == 0.0 and cs[mpc.S_SHIFT] == 0.0


def smc_predictor(dead_time_s: float, servo_s: float) -> tuple[np.ndarray, np.ndarray]:
    """The parameters and state of a sliding mode law with its Smith predictor on a machine
    model of ``dead_time_s`` and a first-order servo ``servo_s``, at rest at 50 %."""
    law = make_controller(ControllerSettings(
        controller='smc', smc_predictor=True, model_dead_time_s=dead_time_s,
        model_servo_time_constant_s=servo_s, model_cutting_time_constant_s=TAU_C_S,
        initial_override_pct=50.0))
    cp, cs, _ = law.arrays
    return cp, cs


def law_run(cp: np.ndarray, cs: np.ndarray, levels: list[float]) -> list[tuple[float, ...]]:
    """The sliding mode law's request, and the feed z its predictor's machine and design
    models give the process, for each level sent after a force of 400 N plus the level (a
    force that moves with the feed: the predictor learns its gain from it)."""
    out = np.zeros(OUT_SIZE)
    rows = []
    for level in levels:
        smc.step(cp, cs, 400.0 + level, 0.0, out)
        smc.sent(cp, cs, level)
        machine = smc.S_MODEL + predictor.S_MX + int(cp[smc.P_MODEL + predictor.M_NX]) - 1
        design = smc.S_MODEL + predictor.S_DX + int(cp[smc.P_MODEL + predictor.D_NX]) - 1
        rows.append((float(out[OUT_PCT]), float(cs[machine]), float(cs[design])))
    return rows


# A staircase of levels, each held 3 control periods, over the dead times and lags compared.
STAIRS = [float(level) for level in np.repeat([60.0, 90.0, 30.0, 120.0, 70.0, 10.0], 3)]


def test_the_smc_predictor_adopts_a_dead_time_as_if_commissioned_with_it() -> None:
    # The drift monitor names the bank's member +30 ms (3 control periods) on a machine
    # commissioned with 50 ms, after 4 periods of levels sent: 40 ms of them are in the line
    # with 10 ms of the level held before them. The adopted line repeats that oldest level for
    # the 30 ms it lacked, which is what a line built for 80 ms holds (40 ms of the held level,
    # then the 40 ms sent), and the servo has seen only the held level on either: from then on
    # the law and its predictor are the ones commissioned with 80 ms, step for step, equal to
    # the last bit (the design model has no dead time: it is the same on both).
    drifted_cp, drifted_cs = smc_predictor(0.08, SERVO_S)
    cp, cs = smc_predictor(0.05, SERVO_S)
    assert law_run(cp, cs, STAIRS[:4]) == law_run(drifted_cp, drifted_cs, STAIRS[:4])
    assert smc.adopt(cp, cs, drift.DEAD_TIME, 0.03)
    assert law_run(cp, cs, STAIRS) == law_run(drifted_cp, drifted_cs, STAIRS)
    # the bank's longest delay (8 periods more: 130 ms) fits the state the Controller made
    cp, cs = smc_predictor(0.05, SERVO_S)
    longest = max(drift.DEAD_OFFSETS) * PERIOD_S
    drifted_cp, drifted_cs = smc_predictor(0.05 + longest, SERVO_S)
    assert cs.size >= smc.S_MODEL + predictor.STATE + round((0.05 + longest) / 1e-3)
    assert smc.adopt(cp, cs, drift.DEAD_TIME, longest)
    assert law_run(cp, cs, STAIRS) == law_run(drifted_cp, drifted_cs, STAIRS)
    # and a shorter one drops the oldest pending: 20 ms less is the line built for 30 ms
    drifted_cp, drifted_cs = smc_predictor(0.03, SERVO_S)
    cp, cs = smc_predictor(0.05, SERVO_S)
    assert smc.adopt(cp, cs, drift.DEAD_TIME, -0.02)
    assert law_run(cp, cs, STAIRS) == law_run(drifted_cp, drifted_cs, STAIRS)


def test_the_smc_predictor_adopts_a_servo_as_if_commissioned_with_it() -> None:
    # The monitor names the servo x1.77 (SERVO_RATIO^6): the machine model is the one built
    # from tau_s x 1.772, and the law is designed for that servo (Park's Eq. 5 with it, the
    # predictor's design model too): the law commissioned on the drifted servo, to the bit.
    scale = drift.SERVO_RATIO ** 6
    drifted_cp, drifted_cs = smc_predictor(0.05, SERVO_S * scale)
    cp, cs = smc_predictor(0.05, SERVO_S)
    assert smc.adopt(cp, cs, drift.SERVO, 1.8)   # named x1.8: the bank's nearest, x1.77
    assert cs[smc.S_MODEL + predictor.S_MODEL] == 1 + drift.SERVO_POWERS.index(6)
    assert predictor.design_tau_s(cp, cs, smc.P_MODEL, smc.S_MODEL) == SERVO_S * scale
    assert law_run(cp, cs, STAIRS) == law_run(drifted_cp, drifted_cs, STAIRS)
    # a drift that is no lag is not the predictor's; a law without one takes none
    assert not smc.adopt(cp, cs, drift.GAIN, 0.4)
    plain = make_controller(ControllerSettings(controller='smc', smc_predictor=False))
    assert not smc.adopt(*plain.arrays[:2], drift.SERVO, 1.8)
    # back to the commissioned model at a tool change
    assert smc.adopt(cp, cs, drift.NONE, 0.0)
    assert cs[smc.S_MODEL + predictor.S_MODEL] == 0.0
    assert cs[smc.S_MODEL + predictor.S_SHIFT] == 0.0


def commissioned(seed: int, index: int, penalty: float, kalman_share: float
                 ) -> tuple[population.Machine, list[str]]:
    """bench_drift.py's machine ``index`` of ``seed`` with the settings the user's flow writes
    for it (population.commission): the identified model, the monitor, and the law the
    closed-loop verification chose, the predictive law with its penalty and horizon, and the
    Kalman filter's force noise at ``kalman_share`` of the identified (the verification's
    candidates; set here, not verified again, to keep the test short)."""
    machine, sets = generated(seed, index)
    noise = next(s for s in sets if s.startswith('force_estimator.kalman_force_noise_n='))
    kalman = kalman_share * float(noise.split('=')[1])
    return machine, [*sets, 'force_controller.controller=mpc',
                     'force_controller.mpc_horizon_s=0.6',
                     f'force_controller.mpc_switch_penalty={penalty!r}',
                     f'force_estimator.kalman_force_noise_n={kalman!r}']


def last_plateau(result: SimulationResult, depth_changes_s: list[float]) -> np.ndarray:
    """The force error [N] over the job's last depth, from 1.5 s after its step (the
    metrics' settle window) to the end."""
    t = result.trace['t_s']
    error = result.trace['force_n'] - result.trace['reference_n']
    return error[t >= depth_changes_s[-1] + 1.5]


def run(machine: population.Machine, sets: list[str], drifted: dict[str, float],
        adopt: bool) -> SimulationResult:
    return simulate(population.job_experiment(replace(machine, drifted=drifted)).with_sets(
        [*sets, f'force_controller.drift_adopt_model={str(adopt).lower()}']))


# The band (issue 15): steady error <= 5 N, ripple <= 25 N peak to peak. With the drifted
# servo or dead time in the model from the start the same loops hold 0.3-1.8 N steady
# (bench_drift.py seed 29); the adopted member is the bank's, within half its step of the
# drift (x1.77 for x1.8, +40 ms for +39 ms), so the band, not that figure, is the bound.
def test_a_servo_drift_named_is_taken_into_the_model_and_the_loop_ends_in_band() -> None:
    # bench_drift.py --seed 29, #5: a second-order servo (8.3 rad/s, damping 0.41) behind 47
    # ms, g 0.65, the 'steps' job (1, 2, 3 mm); its servo slowed x1.8, the commissioned mpc
    # rang and the oscillation alarm's reaction held the force 40-65 N off the reference.
    machine, sets = commissioned(29, 5, 0.25, 0.5)
    slower = {'servo_natural_freq_rad_s': machine.plant['servo_natural_freq_rad_s'] / 1.8}
    steps = population.job_experiment(machine).plant.depth_profile.change_times_s()
    adopted = run(machine, sets, slower, adopt=True)
    assert drift.CAUSES[int(adopted.trace['drift_alarm'][-1])] == 'servo', adopted.drift
    assert 'the mpc law predicts with the servo x1.77 until the tool changes' in adopted.drift
    assert adopted.metrics['oscillation_alarms'] == 0.0
    error = last_plateau(adopted, steps)
    assert abs(error.mean()) <= 5.0 and np.ptp(error) <= 25.0
    kept = last_plateau(run(machine, sets, slower, adopt=False), steps)
    assert abs(kept.mean()) > 5.0 or np.ptp(kept) > 25.0


def test_a_dead_time_drift_named_is_taken_into_the_model_and_the_loop_ends_in_band() -> None:
    # bench_drift.py --seed 29, #0: 78 ms of PMC dead time, a 0.16 s servo, g 0.62, the 'long'
    # job (a depth step every 3 s); the dead time grown to 117 ms. The commissioned mpc held
    # 46 N steady once: its loop rang after a depth step (857 N back, then 53 N), calmed, and
    # the oscillation detector took the next step's fall out of the calm spell for the fourth
    # swing (alarmed at 12.24 s), its reaction detuning an in-band loop (.update.OSC_CALM).
    machine, sets = commissioned(29, 0, 0.0, 0.5)
    longer = {'pmc_dead_time_s': 1.5 * machine.plant['pmc_dead_time_s']}
    adopted = run(machine, sets, longer, adopt=True)
    assert drift.CAUSES[int(adopted.trace['drift_alarm'][-1])] == 'PMC dead time'
    assert 'the mpc law predicts with' in adopted.drift and 'ms of dead time' in adopted.drift
    assert adopted.metrics['steady_mean_abs_error_n'] <= 5.0
    assert adopted.metrics['ripple_p2p_n'] <= 25.0
    kept = run(machine, sets, longer, adopt=False)
    assert kept.metrics['oscillation_alarms'] == 0.0


def test_an_unchanged_machine_is_untouched() -> None:
    # the same machine as it was commissioned: no alarm, so nothing adopted, the same trace
    machine, sets = commissioned(29, 5, 0.25, 0.5)
    on, off = (run(machine, sets, {}, adopt=adopt) for adopt in (True, False))
    assert not on.trace['drift_alarm'].any(), on.drift
    for name in ('force_n', 'applied_override_pct'):
        np.testing.assert_array_equal(on.trace[name], off.trace[name])


def test_a_servo_drift_between_two_members_is_named_before_the_first_depth_step() -> None:
    # bench_population.py --seed 15, #152: a second-order servo (7.7 rad/s, damping 0.42)
    # behind 91 ms, the 'steps' job (1, 2, 3 mm at 4 s apart), its servo x1.30 slower. On a
    # bank of x1.2 steps the drift sat halfway (in log) between x1.2 and x1.44: the x1.2
    # member left an eighth of the identified model's residual, slow (its lag-one correlation
    # at drift.RHO_MAX), a statistic of 10 against 16 once the entry's transient was in the
    # window; named at 8.65 s, after each depth step had rung for 2 s on the commissioned
    # model (108 N peak to peak a second after the first). On x1.1 steps the nearest member
    # is at most half a step, ln(1.1) / 2, off the drift: named at the entry.
    machine, sets = commissioned(15, 152, 0.0, 0.25)
    drifted = population.draw(153, 15)[152].drifted
    assert machine.plant['servo_model'] == 'second_order' and machine.job == 'steps'
    steps = population.job_experiment(machine).plant.depth_profile.change_times_s()
    adopted = run(machine, sets, drifted, adopt=True)
    named = adopted.trace['drift_alarm']
    assert drift.CAUSES[int(named[np.flatnonzero(named)[0]])] == 'servo', adopted.drift
    assert adopted.metrics['drift_alarm_s'] < steps[0]
    size = adopted.trace['drift_size'][-1]
    assert abs(math.log(size / 1.30)) <= 0.5 * math.log(drift.SERVO_RATIO), adopted.drift
    # the depth steps after the servo is adopted: in the band's 25 N peak to peak from a
    # second after each (the settle window the steady metric leaves out is 1.5 s)
    t, force = adopted.trace['t_s'], adopted.trace['force_n']
    for step_s in steps:
        after = (t >= step_s + 1.0) & (t < step_s + 2.0)
        assert np.ptp(force[after]) <= 25.0, step_s


def test_a_servo_drift_is_taken_once_not_each_size_the_monitor_names_after() -> None:
    # bench_population.py --seed 15, #9: a second-order servo (14.3 rad/s) behind 112 ms, the
    # 'deep' job, drifted x1.39 between commissioning and the job. The monitor names x1.33
    # (x1.44 on a bank of x1.2 steps); later, with the loop on the adopted model, it read
    # x2.49, which taken too made the loop cycle (45.9 N steady); the commissioned model kept
    # throughout holds 14.9 N.
    # The feed test names x1.46 at the entry's override step and x1.33 a second later (the
    # drift lies halfway between them, in log): the law keeps the first.
    machine = population.draw(10, 15)[9]
    _, sets = commissioned(15, 9, 0.25, 0.5)
    adopted = simulate(population.job_experiment(machine).with_sets(sets))
    named = adopted.trace['drift_size'][adopted.trace['drift_alarm'] == drift.SERVO]
    taken = adopted.trace['drift_adopted_size']
    assert len(set(named)) > 1, adopted.drift   # named anew with another size
    assert set(taken[taken > 0]) == {named[0]}, adopted.drift   # taken once: the first
    assert abs(math.log(named[0] / 1.39)) <= math.log(drift.SERVO_RATIO), adopted.drift
    assert f'the mpc law predicts with the servo x{named[0]:.2f}' in adopted.drift
    assert adopted.metrics['oscillation_alarms'] == 0.0
    assert adopted.metrics['steady_mean_abs_error_n'] <= 5.0
    kept = simulate(population.job_experiment(machine).with_sets(
        [*sets, 'force_controller.drift_adopt_model=false']))
    assert kept.metrics['steady_mean_abs_error_n'] > 5.0


# bench_drift.py --seed 16, #2: 102 ms of PMC dead time, a 0.34 s first-order servo, g 0.91,
# tau_c 0.16 s, the 'long' job (a depth step every 3 s); the closed-loop verification chose
# the sliding mode law with its predictor, the integral surface, lambda 10 and the balance's
# boundary layer. With the commissioned model kept, a servo slowed x1.8 leaves it ringing
# (the oscillation alarm's reaction holds it 38 N off) and a dead time +50 % 25 N off; the
# law commissioned on the drifted servo from the start holds 2.4 N. The adopted member is the
# bank's, a twentieth off the drift at most (x1.77 for x1.8, +40-50 ms for +51 ms), and the
# switch comes 2.3-2.6 s into the job: the band (steady <= 5 N, ripple <= 25 N), not that
# figure, is the bound.
SMC_CHOSEN = ['force_controller.controller=smc', 'force_controller.smc_surface=integral',
              'force_controller.smc_lambda_per_s=10.0', 'force_controller.smc_epsilon_n=0.0']


@pytest.fixture(scope='module')
def smc_machine() -> tuple[population.Machine, list[str]]:
    machine, sets = generated(16, 2)
    return machine, [*sets, *SMC_CHOSEN]


def smc_drifted(machine: population.Machine, change: str) -> dict[str, float]:
    p = machine.plant
    return ({'servo_time_constant_s': 1.8 * p['servo_time_constant_s']} if change == 'servo'
            else {'pmc_dead_time_s': 1.5 * p['pmc_dead_time_s']})


@pytest.mark.parametrize('change', ['servo', 'dead time'])
def test_the_smc_predictor_takes_a_lag_drift_and_the_loop_ends_in_band(
        smc_machine: tuple[population.Machine, list[str]], change: str) -> None:
    machine, sets = smc_machine
    adopted = run(machine, sets, smc_drifted(machine, change), adopt=True)
    assert 'the smc law predicts with' in adopted.drift, adopted.drift
    assert adopted.metrics['steady_mean_abs_error_n'] <= 5.0, adopted.metrics
    assert adopted.metrics['ripple_p2p_n'] <= 25.0, adopted.metrics
    kept = run(machine, sets, smc_drifted(machine, change), adopt=False)
    assert kept.metrics['steady_mean_abs_error_n'] > 5.0, kept.metrics


def test_a_ring_the_alarm_caught_before_the_drift_was_named_is_let_go_once_it_is(
        smc_machine: tuple[population.Machine, list[str]]) -> None:
    # The same machine, its dead time +50 %, named from the force alone (the feed test off:
    # it names the drift at the first override step) over a window of 2 s
    # (drift_memory_s), the entry feed held for cut_settle_s only (the rise limit off): the
    # drifted loop rings after the second depth step and the oscillation alarm is raised
    # (4.4 s) before the drift is named (5 periods later). (With the entry held until the force is
    # established, this loop enters from a settled cut and does not ring: 5.0 N steady, 14 N
    # ripple with the commissioned model kept.) The reaction's detuned
    # law would hold the loop to the end (25 N steady, the commissioned model kept); the model
    # taken is the ring's cure, and the reaction lets go: the loop, now on the adopted model,
    # rings no more (no second alarm) and ends in band.
    machine, sets = smc_machine
    late = run(machine, [*sets, 'force_controller.drift_memory_s=2.0',
                         'force_controller.drift_feed_test=false',
                         'pmc_bridge.entry_rise_limit_per_s=0.0'],
               smc_drifted(machine, 'dead time'), adopt=True)
    alarm, taken = late.trace['oscillation_alarm'], late.trace['drift_adopted']
    raised, adopted = np.argmax(alarm > 0), np.argmax(taken > 0)
    assert alarm.any() and taken.any() and raised < adopted, (raised, adopted)
    assert drift.CAUSES[int(taken[adopted])] == 'PMC dead time'
    assert not alarm[adopted:].any()   # let go at the adoption, not raised again
    assert late.metrics['oscillation_alarms'] == 1.0
    assert late.metrics['steady_mean_abs_error_n'] <= 5.0, late.metrics
    assert late.metrics['ripple_p2p_n'] <= 25.0, late.metrics


def test_the_graph_says_which_model_the_law_predicts_with(
        smc_machine: tuple[population.Machine, list[str]], tmp_path: Path) -> None:
    # The node graph in lock-step on the same machine, its dead time +50 %: the core loop's
    # trace says from when the law predicts with which member (drift_adopted), and
    # force_controller's /diagnostics, which the session records, says it in words under
    # 'model' ('commissioned' before).
    from rosbags.highlevel import AnyReader

    from turning_force.commands.run import run_lockstep
    from turning_force.session.bag import typestore

    machine, sets = smc_machine
    experiment = population.job_experiment(replace(machine, drifted=smc_drifted(
        machine, 'dead time'))).with_sets([*sets, 'experiment.duration_s=4.0'])
    core = simulate(experiment)
    taken = core.trace['drift_adopted']
    assert taken.any() and drift.CAUSES[int(taken[-1])] == 'PMC dead time'
    at_s = core.trace['t_s'][np.argmax(taken > 0)]
    # the member taken, as the alarm first named it: a whole number of control periods
    size = core.trace['drift_adopted_size'][-1]
    assert size == pytest.approx(round(size / PERIOD_S) * PERIOD_S, abs=1e-12) and size > 0.0
    run_lockstep(experiment, tmp_path / 'session')
    models: list[tuple[float, str]] = []
    with AnyReader([tmp_path / 'session'], default_typestore=typestore()) as reader:
        topic = [c for c in reader.connections if c.topic == '/diagnostics']
        for connection, stamp_ns, raw in reader.messages(connections=topic):
            for status in reader.deserialize(raw, connection.msgtype).status:
                if status.name.endswith('force_controller'):
                    models += [(stamp_ns, v.value) for v in status.values if v.key == 'model']
    # the feed test names the drift at the first override step, before the first report
    # when that step comes in the first second
    assert models and all(value == 'commissioned' for stamp, value in models
                          if stamp * 1e-9 < at_s - PERIOD_S)
    said = drift.adopted_text(experiment.controller, drift.DEAD_TIME, size)
    assert said.startswith('the smc law predicts with') and said.endswith(
        'ms of dead time until the tool changes')
    assert models[-1][1] == said, models
    # said at the first report (once a second, on the simulator's clock) after the law took
    # it, not before
    first_said_s = min(stamp for stamp, value in models if value == said) * 1e-9
    assert at_s - PERIOD_S <= first_said_s <= at_s + 1.0, (first_said_s, at_s)


def test_an_adopted_servo_starts_from_the_feed_the_levels_applied_gave() -> None:
    # The model's state at an adoption is the new model's answer to the overrides the PMC
    # applied (the drift monitor's ring of them), not the commissioned model's: 150 % applied
    # from 40 periods into the ring (30 % before), 5 periods of dead time, a first-order servo
    # of 0.17 s adopted x1.46 (the bank's SERVO_RATIO^4). The feed the model holds is the
    # continuous servo's at the end of the last level that has left the dead time, 19
    # periods after the step (the zero-order hold is exact at the periods' ends):
    # 150 - 120 exp(-0.19 / (0.17 x 1.4641)) = 94.07 %, where the commissioned servo's
    # would be 110.75 % and the law's state before the adoption its held 30 %.
    law = make_controller(ControllerSettings(
        controller='mpc', model_dead_time_s=0.05, model_servo_time_constant_s=SERVO_S,
        model_cutting_time_constant_s=TAU_C_S, initial_override_pct=30.0))
    cp, cs, _ = law.arrays
    ring = np.full(drift.HISTORY, 0.30)
    ring[40:] = 1.50
    at = 10   # the ring's newest; the oldest is the next place
    for j, ratio in enumerate(ring):
        cs[CS_DRIFT + drift.DS_HIST + (at + 1 + j) % drift.HISTORY] = ratio
    cs[CS_DRIFT + drift.DS_AT], cs[CS_DRIFT + drift.DS_STARTED] = at, 1.0
    assert cs[mpc.S_X] == 30.0
    size = drift.SERVO_RATIO ** 4
    assert mpc.adopt(cp, cs, drift.SERVO, size)
    # the ring's levels 0 to HISTORY - 6 have left the dead time: the last ends at
    # HISTORY - 5 periods, the step at 40
    elapsed_s = (drift.HISTORY - 5 - 40) * PERIOD_S
    assert elapsed_s == pytest.approx(0.19)
    expected = 150.0 - 120.0 * math.exp(-elapsed_s / (SERVO_S * size))
    assert cs[mpc.S_X] == pytest.approx(expected, rel=1e-9)


def test_a_slow_underdamped_servo_named_at_the_entry_is_regulated_from_the_next_period() -> None:
    # bench_population.py --seed 42 --approach-s 1.0, #116: a second-order servo (7.7 rad/s,
    # damping 0.34) behind 6 ms, tau_c 0.19 s, the 'steps' job, its servo x1.36 slower after
    # commissioning; the verification chose the predictive law. The entry's first request
    # (150 %, 1.48 s) sets the slow axis going. Named from the force (stop 32) it was named
    # at 2.4 s, after the force had overshot to 618 N and rung: 13.1 N steady (the sweep on
    # the true machine: 0.83 N). The feed test names it at 1.60 s, 0.12 s after the step,
    # before the force is half way up; with the model's state taken from the levels applied
    # the law brakes the axis in time: 1.4 N steady, the entry's overshoot 10 N (6.2 N and
    # 73 N with the state the commissioned model left).
    machine = replace(population.draw(117, 42)[116], approach_s=1.0)
    assert machine.drift.startswith('servo') and machine.plant['servo_model'] == 'second_order'
    # the predictive law, chosen on 5 drawn plants as on 50 (the monitor is the subject)
    done = population.commission(machine, plants=5)
    assert 'force_controller.controller=mpc' in done.chosen.sets
    result = simulate(population.job_experiment(machine).with_sets(done.written))
    t, named = result.trace['t_s'], result.trace['drift_alarm']
    first = np.flatnonzero(named)[0]
    assert drift.CAUSES[int(named[first])] == 'servo', result.drift
    assert result.trace['force_n'][first] < 0.5 * result.trace['reference_n'][first]
    assert result.metrics['steady_mean_abs_error_n'] <= 5.0, result.metrics
    assert result.metrics['ripple_p2p_n'] <= 25.0, result.metrics
    assert result.metrics['entry_overshoot_n'] <= 100.0, result.metrics
    assert t[first] <= 2.0
