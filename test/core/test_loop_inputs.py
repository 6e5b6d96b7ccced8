"""The loop's inputs from the machine beyond the force: the live spindle speed (a constant
surface speed facing cut, G96) and the axis feed the DAQ records against the override applied
(override cancel, feed hold, dry run: the feed-follow check)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from turning_force.core.control import ControllerSettings, make_controller
from turning_force.core.experiment import load_experiment
from turning_force.core.kernel.batch import run_core
from turning_force.core.plant.lathe import LathePlant
from turning_force.core.plant.settings import PlantSettings
from turning_force.core.pmc.gate import OverrideGate
from turning_force.core.pmc.settings import BridgeSettings, Reason

EXPERIMENTS = Path(__file__).resolve().parents[2] / 'config' / 'experiments'
FIG8 = EXPERIMENTS / 'park1998_fig8.yaml'
FACING = EXPERIMENTS / 'facing_g96.yaml'
QUIET = {'current_noise_a': 0.0}


def plant_run(settings: PlantSettings, override_pct: float, blocks: int):
    plant = LathePlant(settings, initial_override_pct=override_pct)
    return plant, [plant.step(override_pct) for _ in range(blocks)]


# --- the simulator: constant surface speed and the machine not following the override ------

def test_constant_surface_speed_follows_the_diameter_and_clamps():
    # G96: N = 1000 V / (pi D), D = D0 - 2 x (the cross slide's travel x takes the diameter
    # down twice as fast); at 60 mm and 94.25 m/min, 500 rpm; clamped at G50's 1500 rpm.
    s = PlantSettings(css_surface_speed_m_min=94.25, css_start_diameter_mm=60.0,
                      css_max_spindle_rpm=1500.0, depth_times_s=(0.0,), depth_mm=(0.0,),
                      **QUIET)
    plant = LathePlant(s, initial_override_pct=100.0)
    first = plant.step(100.0)
    assert first.spindle_speed_rpm == pytest.approx(1000 * 94.25 / (math.pi * 60.0), rel=1e-3)
    seen = []
    for _ in range(3000):
        b = plant.step(100.0)
        seen.append((plant.position_mm, b.spindle_speed_rpm, b.currents.feed_rate_mm_min[-1]))
    position, rpm, feed = np.array(seen).T
    diameter = 60.0 - 2.0 * position
    with np.errstate(divide='ignore'):   # past the centre: the clamp
        expected = np.where(diameter > 0, np.minimum(1000 * 94.25 / (math.pi * diameter),
                                                     1500.0), 1500.0)
    # The speed is taken at the last sample's start: one sample (1 ms) of travel behind the
    # position at the block's end, under 0.1 % here.
    np.testing.assert_allclose(rpm, expected, rtol=2e-3)
    assert rpm[-1] == 1500.0
    # G95: the axis feed follows the speed, 0.2 mm/rev at the speed (the servo 0.17 s behind
    # a ramp: within 5 % once the speed holds).
    assert feed[-1] == pytest.approx(0.2 * 1500.0, rel=0.05)


@pytest.mark.parametrize(('fault', 'expected_mm_min'), [
    ('override_cancel_span_s', 0.2 * 600.0),   # M49: 100 % whatever the override
    ('feed_hold_span_s', 0.0),
    ('dry_run_span_s', 1000.0),                # the dry-run rate
])
def test_the_machine_can_ignore_the_override(fault, expected_mm_min):
    s = PlantSettings(**{fault: (0.5, 10.0)}, depth_times_s=(0.0,), depth_mm=(0.0,), **QUIET)
    _, blocks = plant_run(s, 40.0, 300)
    before = blocks[40].currents.feed_rate_mm_min[-1]
    after = blocks[-1].currents.feed_rate_mm_min[-1]
    assert before == pytest.approx(0.4 * 0.2 * 600.0, rel=1e-6)
    # 2.5 s after the fault, 15 servo time constants: settled to far below 1e-3.
    assert after == pytest.approx(expected_mm_min, abs=1e-3 * 120.0)


def test_a_fault_span_is_checked():
    with pytest.raises(ValueError, match='override_cancel_span_s'):
        PlantSettings(override_cancel_span_s=(5.0, 4.0))


# --- the live spindle speed in the laws -----------------------------------------------------

def test_the_controller_takes_the_live_spindle_speed_and_falls_back():
    controller = make_controller(ControllerSettings(spindle_speed_rpm=600.0))
    assert controller.spindle_speed_rpm == 600.0
    controller.spindle_speed(1500.0)
    assert controller.spindle_speed_rpm == 1500.0
    controller.retune(controller.settings.replace(reference_force_n=400.0))
    assert controller.spindle_speed_rpm == 1500.0   # a retune keeps the live speed
    controller.spindle_speed(math.nan)               # unplugged: the parameter again
    assert controller.spindle_speed_rpm == 600.0


def _in_cut_ripple_n(force_n: np.ndarray, from_block: int) -> float:
    """The largest peak to peak of the true force over any 1 s window (100 blocks) from
    ``from_block`` on."""
    windows = np.lib.stride_tricks.sliding_window_view(force_n[from_block:], 100)
    return float(np.max(np.ptp(windows, axis=1)))


def test_a_g96_facing_cut_holds_the_band_with_the_speed_input():
    # The band: steady error <= 5 N, ripple <= 25 N p-p over the cut (after the
    # entry's first second), spindle 500 -> 1500 rpm.
    run = run_core(load_experiment(FACING))
    t = run.result.trace
    assert t['spindle_speed_rpm'][0] == pytest.approx(500.0, rel=1e-3)
    assert t['spindle_speed_rpm'][-1] == 1500.0
    assert int(Reason.FEED_NOT_FOLLOWING) not in set(run.chain.reason.tolist())
    assert run.result.metrics['steady_mean_abs_error_n'] <= 5.0
    assert _in_cut_ripple_n(t['force_n'], 100) <= 25.0


def test_without_the_speed_input_a_g96_cut_is_not_followed():
    # Unplugged, the loop reads spindle_speed_rpm (500 rpm, the start's): as the spindle
    # speeds up, the axis runs faster than the override allows at 500 rpm, and the feed-follow
    # check stops regulating (it cannot tell this from a feed that does not follow). The
    # force then runs at the programmed feed, 2200 * 2 * 0.2 = 880 N against 500 N.
    run = run_core(load_experiment(FACING).with_sets(['lathe_sim.spindle_speed_wired=false']))
    t = run.result.trace
    tripped = np.flatnonzero(run.chain.reason == int(Reason.FEED_NOT_FOLLOWING))
    assert tripped.size
    # 500 -> 500 (1 + 15 / applied %) rpm at least before the axis leaves the envelope.
    assert t['spindle_speed_rpm'][tripped[0]] > 600.0
    after = t['force_n'][tripped[0] + 100:]
    assert np.mean(np.abs(after - 500.0)) > 300.0


# --- the feed follows the override -----------------------------------------------------------

def _first_trip_s(run) -> float | None:
    tripped = np.flatnonzero(run.chain.reason == int(Reason.FEED_NOT_FOLLOWING))
    return float(run.result.trace['t_s'][tripped[0]]) if tripped.size else None


def test_override_cancel_mid_cut_stops_regulating_within_a_second():
    run = run_core(load_experiment(FIG8).with_sets(
        ['lathe_sim.override_cancel_span_s=[6.0, 12.0]']))
    trip = _first_trip_s(run)
    assert trip is not None and 6.0 < trip <= 7.0
    k = int(np.flatnonzero(run.chain.reason == int(Reason.FEED_NOT_FOLLOWING))[0])
    # Handed back: the programmed feed from then on, the alarm output set, latched.
    assert np.all(run.chain.reason[k:] == int(Reason.FEED_NOT_FOLLOWING))
    assert np.all(run.chain.applied_pct[k:] == 100.0)
    assert run.chain.alarm[k:].all()


def test_an_overload_hold_the_axis_does_not_obey_sets_the_stop_request():
    # Fig. 8 with override cancel from 6 s and the overload limit at 1,000 N: the gate hands
    # the feed back (6-7 s), and at the 3 mm step (8 s) the programmed feed cuts 1,320 N
    # (2200 N/mm^2 x 3 mm x 0.2 mm/rev). The overload hold writes 0 %, which the machine
    # ignores: the stop request (a feed hold apart from the override) is set, and the
    # decision says why.
    limit = ['pmc_bridge.overload_force_n=1000.0']
    run = run_core(load_experiment(FIG8).with_sets(
        [*limit, 'lathe_sim.override_cancel_span_s=[6.0, 12.0]']))
    t, chain = run.result.trace['t_s'], run.chain
    held = np.flatnonzero(chain.reason == int(Reason.OVERLOAD_HOLD))
    assert held.size and 8.0 <= t[held[0]] < 8.2
    assert not chain.stop_request[:held[0]].any()
    assert chain.stop_request[held[0]:].all()
    assert np.all(run.result.trace['force_n'][held[0] + 50:] > 1000.0)   # it still cuts
    # Obeyed, a hold stops the axis and asks for nothing more: Fig. 8's depth steps overshoot
    # by 264 N (the goldens), over a 700 N limit.
    obeyed = run_core(load_experiment(FIG8).with_sets(['pmc_bridge.overload_force_n=700.0']))
    assert np.any(obeyed.chain.reason == int(Reason.OVERLOAD_HOLD))
    assert not obeyed.chain.stop_request.any()


def test_the_gate_says_a_hold_is_not_obeyed():
    gate = gate_in_cut()
    gate.on_estimate(2500.0)   # over overload_force_n (2,000 N): held at 0 %
    decision = feed_blocks(gate, 0.5 * 120.0, 1)
    assert decision.reason == Reason.OVERLOAD_HOLD and not decision.stop_request
    # The axis runs on at 50 % (the envelope of 0 % applied closes within a few lags).
    decision = feed_blocks(gate, 0.5 * 120.0, 150, k0=201)
    assert decision.reason == Reason.OVERLOAD_HOLD and decision.applied_pct == 0.0
    assert decision.stop_request and decision.alarm
    assert 'the axis does not stop (at 50 % of the programmed feed' in decision.detail
    assert 'stop request set' in decision.detail


@pytest.mark.parametrize('path', sorted(EXPERIMENTS.glob('*.yaml')), ids=lambda p: p.stem)
def test_no_false_alarm_on_the_shipped_experiments(path):
    assert _first_trip_s(run_core(load_experiment(path))) is None


START_BLOCKS = 200


def gate_in_cut(**changes) -> OverrideGate:
    gate = OverrideGate(BridgeSettings(armed=True, spindle_speed_rpm=600.0,
                                       programmed_feed_mm_rev=0.2, **changes), t_s=0.0)
    # In the cut, the request 50 % applied for 2 s, the axis following: the lag envelope
    # (0.5 s) has closed on 50 % to within 50 exp(-4) = 1 %.
    for k in range(START_BLOCKS):
        t = (k + 1) * 0.01
        gate.on_estimate(500.0)
        gate.on_feed(0.5 * 120.0 if k else 120.0)
        gate.on_command(50.0, t)
        gate.answer(t)
    assert gate.engaged
    return gate


def feed_blocks(gate: OverrideGate, feed_mm_min: float, blocks: int, k0: int = 200,
                rpm: float = math.nan):
    decision = None
    for k in range(k0, k0 + blocks):
        t = (k + 1) * 0.01
        gate.on_estimate(500.0)
        gate.on_feed(feed_mm_min, rpm)
        gate.on_command(50.0, t)
        decision = gate.answer(t)
    return decision


def test_the_gate_hands_back_after_the_follow_time_and_says_why():
    gate = gate_in_cut()   # 30 % points above the applied 50 %, past the 15 % tolerance
    before = feed_blocks(gate, 0.8 * 120.0, 29)
    assert before.reason == Reason.NORMAL and not gate.feed_not_following
    after = feed_blocks(gate, 0.8 * 120.0, 1, k0=229)
    assert after.reason == Reason.FEED_NOT_FOLLOWING and after.applied_pct == 100.0
    assert after.alarm
    assert 'does not follow the override' in after.detail and '80 %' in after.detail
    assert 're-arm' in after.detail
    gate.arm(0.5)
    assert not gate.feed_not_following


def test_an_axis_that_stops_while_the_force_holds_is_not_following():
    # A feed hold as the gate sees it: the axis at 0 with the override steady at 50 %.
    gate = gate_in_cut()
    assert feed_blocks(gate, 0.0, 29).reason == Reason.NORMAL
    assert feed_blocks(gate, 0.0, 1, k0=229).reason == Reason.FEED_NOT_FOLLOWING


def test_an_underdamped_servo_may_overshoot_a_swing_of_the_override():
    # The override swings 0 -> 150 %: a servo of damping 0.3 overshoots by 37 % of the swing;
    # the envelope allows half of it (feed_follow_overshoot) beyond the tolerance.
    gate = gate_in_cut()
    for k in range(200, 260):   # a limit cycle between the ends of the table
        t = (k + 1) * 0.01
        gate.on_estimate(500.0)
        gate.on_feed(120.0 * (1.5 + 0.5) if k % 20 < 10 else -0.5 * 120.0)
        gate.on_command(150.0 if k % 20 < 10 else 0.0, t)
        assert gate.answer(t).reason == Reason.NORMAL


def test_the_gate_judges_the_feed_at_the_live_spindle_speed():
    # 1500 rpm given: 60 mm/min * 2.5 is the 50 % applied, not 125 % of 600 rpm's.
    gate = gate_in_cut()
    assert feed_blocks(gate, 150.0, 60, rpm=1500.0).reason == Reason.NORMAL
    assert feed_blocks(gate, 150.0, 60, k0=260).reason == Reason.FEED_NOT_FOLLOWING


def test_a_feed_inside_the_lag_envelope_or_unmeasured_is_not_judged():
    gate = gate_in_cut()
    assert feed_blocks(gate, math.nan, 100).reason == Reason.NORMAL
    # Off (feed_follow_time_s 0): never.
    off = gate_in_cut(feed_follow_time_s=0.0)
    assert feed_blocks(off, 0.0, 100).reason == Reason.NORMAL
