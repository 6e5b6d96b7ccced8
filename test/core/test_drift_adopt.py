"""The predictive law takes a lag drift the drift monitor names into its model
(``drift_adopt_model``, issue 16 item 2's drift, issue 15's predictive law): the dead time's
queue keeps the levels pending in their order, the servo is the bank's member, and on the
generated machines of bench_drift.py that rang or limit-cycled on the commissioned model after
their servo or PMC dead time drifted, the loop ends in band; an unchanged machine is untouched.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from test_drift import generated

from turning_force.commands import population
from turning_force.core.control import ControllerSettings, drift, make_controller
from turning_force.core.control.laws import mpc
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
    scale = drift.SERVO_RATIO ** 3   # what the monitor names for a servo x1.8 (x1.73)
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
# drift (x1.73 for x1.8, +40 ms for +39 ms), so the band, not that figure, is the bound.
def test_a_servo_drift_named_is_taken_into_the_model_and_the_loop_ends_in_band() -> None:
    # bench_drift.py --seed 29, #5: a second-order servo (8.3 rad/s, damping 0.41) behind 47
    # ms, g 0.65, the 'steps' job (1, 2, 3 mm); its servo slowed x1.8, the commissioned mpc
    # rang and the oscillation alarm's reaction held the force 40-65 N off the reference.
    machine, sets = commissioned(29, 5, 0.25, 0.5)
    slower = {'servo_natural_freq_rad_s': machine.plant['servo_natural_freq_rad_s'] / 1.8}
    steps = population.job_experiment(machine).plant.depth_profile.change_times_s()
    adopted = run(machine, sets, slower, adopt=True)
    assert drift.CAUSES[int(adopted.trace['drift_alarm'][-1])] == 'servo', adopted.drift
    assert 'the mpc law predicts with the servo x1.73 until the tool changes' in adopted.drift
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


def test_a_servo_drift_is_taken_once_not_each_size_the_monitor_names_after() -> None:
    # bench_population.py --seed 15, #9: a second-order servo (14.3 rad/s) behind 112 ms, the
    # 'deep' job, drifted x1.39 between commissioning and the job. The monitor names x1.44 at
    # 2.39 s; later, with the loop on the adopted model, x2.49, which taken too made the loop
    # cycle (45.9 N steady); the commissioned model kept throughout holds 14.9 N.
    machine = population.draw(10, 15)[9]
    _, sets = commissioned(15, 9, 0.25, 0.5)
    adopted = simulate(population.job_experiment(machine).with_sets(sets))
    assert 'the mpc law predicts with the servo x1.44' in adopted.drift
    assert adopted.metrics['oscillation_alarms'] == 0.0
    assert adopted.metrics['steady_mean_abs_error_n'] <= 5.0
    kept = simulate(population.job_experiment(machine).with_sets(
        [*sets, 'force_controller.drift_adopt_model=false']))
    assert kept.metrics['steady_mean_abs_error_n'] > 5.0
