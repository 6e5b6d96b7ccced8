"""The predictive law over the override levels (core/control/laws/mpc.py), against analysis: on
a plant that is its own model it holds the mean force on the reference between two levels,
through a dead time and with a cutting exponent; the switching penalty trades changes of level
for error; it does not wind up with the tool out of the cut; and it follows a taper's steadily
rising gain without the lag a held gain leaves, while a depth step is no trend; and at the end of
the gate's entry feed, or of a hold through a groove the gate does not see, it meets the
reference without the overshoot a gain learned from the force's rise left."""

from __future__ import annotations

import numpy as np
import pytest

from turning_force.core.control import ControllerSettings, make_controller
from turning_force.core.control.predictor import model_matrices
from turning_force.core.experiment import load_experiment
from turning_force.core.kernel.simulate import simulate
from turning_force.core.pmc.settings import Reason

PERIOD_S = 0.01
SERVO_S, TAU_C_S = 0.17, 0.05


def closed_loop(periods: int, gain: float | np.ndarray, exponent: float = 1.0,
                dead_time_s: float = 0.0, air: range = range(0), **changes: float
                ) -> tuple[np.ndarray, np.ndarray]:
    """The law on a noise-free plant that is exactly its model: PMC dead time, the first-order
    servo and the process lag at the control period, F = gain z^exponent (0 in ``air``; the
    gain one number, or one per period). Returns the forces and the levels sent."""
    gains = np.broadcast_to(np.asarray(gain, dtype=float), (periods,))
    settings = ControllerSettings(controller='mpc', model_dead_time_s=dead_time_s,
                                  model_cutting_exponent=exponent, initial_override_pct=50.0,
                                  quantiser='nearest', **changes)
    law = make_controller(settings)
    phi, gamma = model_matrices('first_order', SERVO_S, 60.0, 0.7, TAU_C_S, step_s=PERIOD_S)
    x = np.array([50.0, 50.0])
    queue = [50.0] * round(dead_time_s / PERIOD_S)
    forces, levels = np.empty(periods), np.empty(periods)
    for k in range(periods):
        forces[k] = 0.0 if k in air else gains[k] * x[-1] ** exponent
        levels[k] = law.update(float(forces[k]), 0.0).override_pct
        queue.append(levels[k])
        x = phi @ x + gamma * queue.pop(0)
    return forces, levels


# The force a level holds differs from the reference by about 16 N below and 80 N above (9.68
# N/%: 50 % gives 484 N, 60 % 581 N): the law must send both, in the proportion that averages
# to 500 N. A one-period pulse of 10 % through the 0.17 s servo moves the force by at most
# 9.68 x 10 x (1 - exp(-0.01 / 0.17)) = 5.5 N: the force stays within a few newtons of the mean.
# Without a switching penalty nothing but the error is charged: the mean is the reference to
# within a tenth of that pulse.
@pytest.mark.parametrize(('exponent', 'dead_time_s'), [(1.0, 0.0), (1.0, 0.1), (0.7, 0.08)])
def test_the_mean_force_sits_on_the_reference_between_two_levels(exponent, dead_time_s):
    gain = 484.0 / 50.0 ** exponent
    forces, levels = closed_loop(600, gain, exponent, dead_time_s, mpc_switch_penalty=0.0)
    steady = forces[-200:]
    assert abs(steady.mean() - 500.0) < 0.55
    assert np.ptp(steady) < 12.0
    assert set(np.unique(levels[-200:])) <= {50.0, 60.0}


def test_the_switching_penalty_trades_changes_of_level_for_error():
    free_forces, free_levels = closed_loop(600, 9.68, mpc_switch_penalty=0.0)
    held_forces, held_levels = closed_loop(600, 9.68, mpc_switch_penalty=5.0)
    changes = [np.count_nonzero(np.diff(levels[-300:])) for levels in (free_levels, held_levels)]
    errors = [np.abs(forces[-300:] - 500.0).mean() for forces in (free_forces, held_forces)]
    assert changes[1] < changes[0] / 2
    assert errors[1] > errors[0]


def test_no_windup_with_the_tool_out_of_the_cut():
    # Out of the cut the force is 0, but the law is a model of the feed, not an integrator: it
    # asks for the level that gives the reference at the process gain it learned, and re-enters
    # with it (an integrating law winds up to 150 % in air).
    forces, levels = closed_loop(700, 9.68, air=range(300, 500))
    assert levels[490:500].max() <= 60.0
    assert forces[500:].max() < 520.0


# A taper: the gain rises 10 % of its first value a second (a depth from 1 to 2 mm over 10 s),
# behind 100 ms of dead time. Held as last learned, the gain the law predicts with is late by the
# learning's lag ((1 - a) / a = 4.5 periods), the dead time (10), one period and the few periods
# after it that the first move is chosen for (the held tail takes the rest of the horizon):
# about 0.19 s, so the force runs about 500 N x 0.1 / 1.6 x 0.19 s = 6 N above the reference
# at 6 s. With the trend carried over that lead, the mean force between two levels is the
# reference again, within 1.5 N: the two-level test's 0.55 N, the trend's own noise left out of
# it (sqrt(b / 2) = 7 % of the 6 N on this ramp, whose innovations are all alike), the trend
# still to learn (it starts once the gain has settled after the first cut: a few % of 6 N at 4
# s) and a period's timing of the learned gain (0.3 N).
def test_a_taper_s_rising_gain_leaves_no_lag_with_the_trend():
    periods = 800
    gain = 9.68 * (1.0 + 0.1 * np.arange(periods) * PERIOD_S)
    held, _ = closed_loop(periods, gain, dead_time_s=0.1, mpc_switch_penalty=0.0,
                          mpc_trend_time_constant_s=0.0)
    carried, _ = closed_loop(periods, gain, dead_time_s=0.1, mpc_switch_penalty=0.0)
    window = slice(400, 800)
    assert 3.0 < held[window].mean() - 500.0 < 10.0
    assert abs(carried[window].mean() - 500.0) < 1.5


# A depth step (the gain x1.5 at 3 s) is a jump, not a trend: the gate keeps the few periods in
# which the learned gain moves to the new depth out of the trend, and the law settles on the
# reference as it does with no trend at all (within the two-level test's 0.55 N), with no
# lasting undershoot: a trend learned from the step would carry it over 0.3 s, 50 % of the gain
# for the first periods.
def test_a_depth_step_is_no_trend():
    periods = 700
    gain = np.where(np.arange(periods) < 300, 9.68, 1.5 * 9.68)
    held, _ = closed_loop(periods, gain, dead_time_s=0.1, mpc_switch_penalty=0.0,
                          mpc_trend_time_constant_s=0.0)
    carried, _ = closed_loop(periods, gain, dead_time_s=0.1, mpc_switch_penalty=0.0)
    assert abs(carried[-200:].mean() - 500.0) < 0.55
    assert carried[300:].min() > held[300:].min() - 5.0
    assert np.abs(carried[400:] - held[400:]).mean() < 2.0


def test_on_park_fig8_it_holds_the_band_with_fewer_changes_than_the_sliding_mode_law(fig8):
    # Park's Fig. 8 (the model the law assumes is the plant's: first-order 0.17 s servo,
    # tau_c = 0.05 s, no dead time). The paper's band is 25 N; the SMC's run today holds 1.4 N
    # steady with 32 changes of level a second.
    experiment = load_experiment(fig8)
    smc = simulate(experiment).metrics
    mpc = simulate(experiment.with_sets(['force_controller.controller=mpc'])).metrics
    assert mpc['steady_mean_abs_error_n'] < smc['steady_mean_abs_error_n']
    assert mpc['ripple_p2p_n'] < smc['ripple_p2p_n']
    assert mpc['override_changes_per_s'] <= smc['override_changes_per_s']


def entered(tau_c_s: float, penalty: float, gap_s: float = 0.0) -> np.ndarray:
    """The force over 3 s from an entry into the cut. The plant has the law's dead time (0.1
    s), servo (0.17 s), lag and exponent, the lag on the force as in the simulator: F' = (K d
    z_s^g - F) / tau_c, z_s the feed after the dead time and the servo, so the depth enters
    through the lag as the feed does. The gate's entry feed (30 %) holds until the force is at
    95 % of what that feed gives (450 N: the reference needs 33 %); then the law regulates.
    With ``gap_s``, the tool is in air for that long from 1.5 s (a groove: the force falls
    toward 0 behind the lag, the axis still feeding as measured)."""
    exponent, dead_time_s, entry = 0.7, 0.1, 30.0
    settings = ControllerSettings(
        controller='mpc', model_cutting_time_constant_s=tau_c_s, model_cutting_exponent=exponent,
        model_dead_time_s=dead_time_s, quantiser='error_feedback', mpc_switch_penalty=penalty)
    law = make_controller(settings)
    gain = 450.0 / entry ** exponent
    lag, servo = np.exp(-PERIOD_S / tau_c_s), np.exp(-PERIOD_S / SERVO_S)
    feed, force, queue = entry, 0.0, [entry] * round(dead_time_s / PERIOD_S)
    for _ in range(20):   # the approach in air
        law.update(0.0, 0.0)
        law.applied(entry, False, int(Reason.AIR_CUT))
    entering, forces = True, np.empty(300)
    for k in range(forces.size):
        depth = 0.0 if 150 <= k < 150 + round(gap_s / PERIOD_S) else 1.0
        before = force
        force = lag * force + (1.0 - lag) * depth * gain * feed ** exponent
        law.feed(feed / 100.0 * settings.programmed_feed_rate_mm_min)
        request = law.update(force, (force - before) / PERIOD_S).override_pct
        entering = entering and force < 0.95 * 450.0
        applied = entry if entering else request
        law.applied(applied, True, int(Reason.AIR_CUT if entering else Reason.NORMAL))
        queue.append(applied)
        feed = servo * feed + (1.0 - servo) * queue.pop(0)
        forces[k] = force
    return forces


# At the entry feed's end the force is at 95 % of what the entry feed gives and still rising.
# The law's model rests on the entry level (the PMC held it), so a gain learned as F / z^g from
# the rising force came out low (its smoothing lags the rise too), the law asked for more than
# the reference needs and overshot it by 7-24 N on these cases. With the model's lagged feed put
# where the force's asymptote (F + tau_c dF/dt) says, the gain is the cut's and the law meets the
# reference without overshoot beyond the quantiser's own pulses: 10 % for one period through the
# 0.17 s servo and a 0.1-0.2 s lag moves the force by 2-3 N here (10.5 N/% at 33 %: 0.7 x 500 N
# / 33 %, times 0.57 % of feed, times the two lags' peak of 0.34-0.47), and the error feedback
# may send two in a row.
@pytest.mark.parametrize('tau_c_s', [0.1, 0.2])
@pytest.mark.parametrize('penalty', [0.0, 0.5])
def test_the_entry_feed_s_end_meets_the_reference_without_overshoot(tau_c_s, penalty):
    forces = entered(tau_c_s, penalty)
    assert forces.max() - 500.0 < 5.0
    assert abs(forces[-100:].mean() - 500.0) < 1.0   # and regulates: the two-level test's band


# A groove the gate does not see (0.15 s of air: the force falls to 184-236 N, over the gate's
# exit threshold): the loop holds its level through it (update._fall) with the law at rest on
# it, as at the entry feed, and the force's rise at the end of the hold is the cut's lag again.
# Learned from it as F / z^g, the gain came out low and the law overshot the reference by 13-20
# N after the groove; from the asymptote, by no more than the entry's bound above.
@pytest.mark.parametrize('tau_c_s', [0.15, 0.2])
def test_the_end_of_a_hold_through_a_groove_meets_the_reference_without_overshoot(tau_c_s):
    forces = entered(tau_c_s, 0.0, gap_s=0.15)
    assert forces[150:170].min() > 150.0   # far over exit_force_n (50 N): the gate saw nothing
    assert forces[150:].max() - 500.0 < 5.0
    assert abs(forces[-50:].mean() - 500.0) < 1.0
