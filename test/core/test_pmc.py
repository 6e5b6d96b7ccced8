"""The override gate: the machine stays safe first."""

import math

import pytest

from turning_force.core.errors import ConfigError
from turning_force.core.estimation.settings import EstimateStatus
from turning_force.core.pmc.gate import OverrideGate
from turning_force.core.pmc.settings import BridgeSettings, Reason


def armed_gate(**changes):
    # No force comes in: the tool is out of the cut, so the entry feed is off here to show the
    # safety gate's decisions on the request as it is (test_shopfloor.py tests the entry feed).
    changes.setdefault('air_cut_override_pct', 0.0)
    gate = OverrideGate(BridgeSettings(armed=True, **changes), t_s=0.0)
    gate.on_command(113.0, 0.0)
    return gate


def test_starts_disarmed_at_the_programmed_feed():
    gate = OverrideGate(BridgeSettings())
    gate.on_command(40.0, 0.0)
    d = gate.decide(0.0)
    assert (d.applied_pct, d.reason, d.armed) == (100.0, Reason.DISARMED, False)
    assert d.requested_pct == 40.0


def test_armed_writes_the_quantised_request_and_its_bits():
    d = armed_gate().decide(0.005)
    assert (d.applied_pct, d.reason) == (110.0, Reason.NORMAL)
    assert d.code == 11 and d.bits == (False, False, True, False)  # ~1011, active low


def test_stale_command_goes_to_the_safe_override():
    gate = armed_gate(safe_override_pct=20.0, watchdog_period_s=0.05)
    assert gate.decide(0.05).reason == Reason.NORMAL       # on the limit: not yet stale
    d = gate.decide(0.0501)
    assert (d.applied_pct, d.reason) == (20.0, Reason.WATCHDOG)
    assert '0.050 s old' in d.detail
    gate.on_command(113.0, 0.06)
    assert gate.decide(0.06).reason == Reason.NORMAL        # a fresh command resumes


def test_after_arming_the_first_command_has_one_watchdog_period():
    gate = OverrideGate(BridgeSettings(armed=True, watchdog_period_s=0.05), t_s=1.0)
    waiting = gate.decide(1.04)
    assert (waiting.applied_pct, waiting.reason) == (100.0, Reason.WATCHDOG)
    assert waiting.detail == 'armed, waiting for the first feed command'
    late = gate.decide(1.06)
    assert (late.applied_pct, late.reason) == (0.0, Reason.WATCHDOG)
    assert 'no feed command in 0.060 s since arming' in late.detail


@pytest.mark.parametrize('bad', [math.nan, math.inf, -math.inf])
def test_non_finite_command_goes_to_the_safe_override(bad):
    gate = armed_gate(safe_override_pct=30.0)
    gate.on_command(bad, 0.01)
    d = gate.decide(0.01)
    assert (d.applied_pct, d.reason) == (30.0, Reason.INVALID_COMMAND)
    assert 'not finite' in d.detail


def test_overload_holds_the_feed_until_re_armed():
    gate = armed_gate(overload_force_n=1500.0)
    gate.on_estimate(1499.0)
    assert gate.decide(0.0).reason == Reason.NORMAL
    gate.on_estimate(1600.0)
    gate.on_estimate(400.0)        # the force falling back does not release the hold
    d = gate.decide(0.0)
    assert (d.applied_pct, d.reason) == (0.0, Reason.OVERLOAD_HOLD)
    assert '1600 N above overload_force_n 1500 N' in d.detail
    gate.disarm()
    assert gate.decide(0.0).reason == Reason.OVERLOAD_HOLD  # disarming is no way out
    gate.arm(0.0)
    gate.on_command(113.0, 0.0)
    assert gate.decide(0.0).reason == Reason.NORMAL


def test_arming_through_settings_clears_the_hold():
    gate = armed_gate()
    gate.on_estimate(1900.0)
    gate.reconfigure(gate.settings.replace(overload_force_n=1800.0), 0.0)
    gate.on_estimate(1900.0)
    assert gate.decide(0.0).reason == Reason.OVERLOAD_HOLD
    gate.on_estimate(500.0)
    gate.reconfigure(gate.settings.replace(armed=False), 0.0)
    gate.reconfigure(gate.settings.replace(armed=True), 0.0)
    gate.on_command(113.0, 0.0)
    assert gate.decide(0.0).reason == Reason.NORMAL


def test_re_arming_with_the_force_still_over_the_limit_keeps_the_hold():
    # Before: re-arming cleared the hold and wrote one NORMAL 150 % before the next estimate
    # latched it again. The gate now judges the last force at arming.
    gate = armed_gate(overload_force_n=1500.0)
    gate.on_command(150.0, 0.0)
    gate.on_estimate(1600.0)
    for _ in range(5):
        assert 'still over the limit' in gate.arm(0.0)
        d = gate.decide(0.0)
        assert (d.applied_pct, d.reason) == (0.0, Reason.OVERLOAD_HOLD)
    gate.on_estimate(1400.0)
    assert gate.arm(0.0) == ''
    gate.on_command(150.0, 0.0)
    assert gate.decide(0.0).applied_pct == 150.0


@pytest.mark.parametrize(('force_n', 'status', 'why'), [
    (300.0, EstimateStatus.SATURATED, 'current sensor saturated'),
    (math.nan, EstimateStatus.OK, 'not finite'),
    (math.inf, EstimateStatus.OK, 'not finite'),
])
def test_a_force_the_sensor_cannot_read_counts_as_an_overload(force_n, status, why):
    gate = armed_gate()
    gate.on_command(120.0, 0.0)
    assert gate.on_estimate(force_n, status)
    d = gate.decide(0.0)
    assert (d.applied_pct, d.reason) == (0.0, Reason.OVERLOAD_HOLD)
    assert why in d.detail


def test_an_invalid_or_stale_estimate_is_not_judged():
    # It repeats the last good force: a hold from it would be a hold on old news, and its
    # silence is the watchdog's business.
    gate = armed_gate(overload_force_n=1500.0)
    for status in (EstimateStatus.INVALID_INPUT, EstimateStatus.STALE):
        assert not gate.on_estimate(1e9, status)
    gate.on_command(120.0, 0.0)
    assert gate.decide(0.0).reason == Reason.NORMAL


@pytest.mark.parametrize('requested', [1e9, 1.7e308, -50.0, 150.000001, -1e-9])
def test_a_command_outside_the_table_is_invalid_not_clamped(requested):
    # Before: 1e9 % and 1.7e308 % became 150 % NORMAL, -50 % became 0 % NORMAL.
    gate = armed_gate(safe_override_pct=0.0)
    gate.on_command(requested, 0.0)
    d = gate.decide(0.0)
    assert (d.applied_pct, d.reason) == (0.0, Reason.INVALID_COMMAND)
    assert 'outside the fanuc_0t_4bit range [0, 150] %' in d.detail


@pytest.mark.parametrize('requested', [0.0, 150.0])
def test_the_ends_of_the_table_are_valid_commands(requested):
    gate = armed_gate()
    gate.on_command(requested, 0.0)
    assert gate.decide(0.0).reason == Reason.NORMAL


def test_bad_bridge_settings():
    with pytest.raises(ConfigError, match=r'pmc_bridge.safe_override_pct = 200.0: outside '
                                          r'\[0, 100\) %'):
        BridgeSettings(safe_override_pct=200.0)
    with pytest.raises(ConfigError, match=r'pmc_bridge.watchdog_period_s = 0.005: shorter'):
        BridgeSettings(watchdog_period_s=0.005)


def test_the_core_loop_runs_through_the_gate(experiments_dir):
    # Fig. 8's first depth step peaks at about 760 N; with a 700 N overload limit the feed is
    # held from then on and the force dies away, as the graph's bridge would do it.
    from turning_force.core.experiment import load_experiment
    from turning_force.core.kernel.simulate import simulate

    experiment = load_experiment(experiments_dir / 'park1998_fig8.yaml').with_sets(
        ['pmc_bridge.overload_force_n=700.0', 'experiment.duration_s=6.0'])
    trace = simulate(experiment).trace
    held = trace['applied_override_pct'][trace['t_s'] > 4.3]
    assert held.max() == 0.0
    assert trace['force_n'][-1] < 1.0


@pytest.mark.parametrize(('changes', 'message'), [
    # The watchdog's override must hold or reduce the feed: before, 150 (and 254 on the 8-bit
    # table) were accepted, so a dead controller could run the machine at full feed.
    ({'safe_override_pct': 150.0}, r'safe_override_pct = 150.0: outside \[0, 100\)'),
    ({'safe_override_pct': 254.0, 'override_table': 'fanuc_8bit'}, r'outside \[0, 100\)'),
    ({'safe_override_pct': 99.0}, r'fanuc_0t_4bit PMC would apply 100 %'),
    ({'overload_force_n': 1e300}, r'overload_force_n = 1e\+300: outside \(0, 100000\] N'),
    ({'overload_force_n': 6000.0}, r'above max_feed_force_n \(5000 N\)'),
])
def test_safety_settings_are_bounded_to_what_is_safe(changes, message):
    with pytest.raises(ConfigError, match=message):
        BridgeSettings(**changes)


def test_a_reduced_safe_feed_is_accepted():
    assert BridgeSettings(safe_override_pct=50.0).safe_override_pct == 50.0
    assert BridgeSettings(safe_override_pct=94.0).safe_override_pct == 94.0   # 90 % applied
