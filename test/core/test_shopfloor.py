"""What a machinist expects of the override gate: program enable, threading, the operator's dial,
rise limit, feed floor, air cut, overload reactions, tool breakage, teach-in and the cut log,
each behind the safety gate's own order (overload hold, disarmed, watchdog, invalid command)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from turning_force.core.errors import ConfigError
from turning_force.core.experiment import load_experiment
from turning_force.core.kernel.chain import ControlChain
from turning_force.core.kernel.simulate import simulate
from turning_force.core.plant.lathe import LathePlant
from turning_force.core.plant.settings import PlantSettings
from turning_force.core.pmc.gate import OverrideGate
from turning_force.core.pmc.overrides import get_table
from turning_force.core.pmc.settings import BridgeSettings, Reason
from turning_force.core.pmc.shopfloor import (
    InputValues,
    TaughtTool,
    load_teach_file,
    save_teach_file,
    taught_reference,
)

PERIOD_S = 0.01
EXPERIMENTS = Path(__file__).resolve().parents[2] / 'config' / 'experiments'
ENABLED = InputValues(program_enable=True, threading=False)


def gate_with(**changes) -> OverrideGate:
    """An armed gate; the entry feed off unless asked for, so that each behaviour is seen on
    its own (the tool is out of the cut until a test's force says otherwise)."""
    changes.setdefault('air_cut_override_pct', 0.0)
    return OverrideGate(BridgeSettings(armed=True, **changes), t_s=0.0)


def block(gate: OverrideGate, k: int, force_n: float, request_pct: float = 120.0,
          inputs: InputValues | None = None, reachable: bool = True):
    """One control block through the gate, as the chain runs it; the block ends at
    (k + 1) * 10 ms."""
    t_s = (k + 1) * PERIOD_S
    if inputs is not None:
        gate.on_inputs(inputs)
    gate.on_estimate(force_n)
    gate.on_command(request_pct, t_s, reachable)
    return gate.answer(t_s)


def engage(gate: OverrideGate, k0: int = 0, blocks: int = 3, force_n: float = 500.0,
           request_pct: float = 120.0) -> int:
    """Blocks of cutting force: the tool is in the cut (two blocks past engage_force_n)."""
    for k in range(k0, k0 + blocks):
        block(gate, k, force_n, request_pct)
    assert gate.engaged
    return k0 + blocks


# --- defaults ------------------------------------------------------------------------------


def test_the_defaults_leave_the_request_as_it_was():
    # Off or conservative by default: without inputs and with the default settings the gate
    # writes the quantised request, as before the shop-floor behaviours, whatever the force.
    rng = np.random.default_rng(3)
    gate, table = gate_with(), get_table('fanuc_0t_4bit')
    for k in range(500):
        request = float(rng.uniform(0.0, 150.0))
        d = block(gate, k, float(rng.uniform(0.0, 1900.0)), request)
        assert (d.applied_pct, d.reason) == (table.quantise(request), Reason.NORMAL)
        assert not (d.alarm or d.stop_request)


# --- program enable and threading ----------------------------------------------------------


def test_the_bridge_acts_only_while_the_program_enables_it():
    gate = gate_with(program_enable_required=True)
    off = block(gate, 0, 500.0, 40.0, InputValues(program_enable=False))
    # Standing down to the programmed feed may write more than the request: the option is off.
    assert (off.applied_pct, off.reason) == (100.0, Reason.OPERATOR)
    assert 'has not enabled adaptive feed' in off.detail
    on = block(gate, 1, 500.0, 40.0, InputValues(program_enable=True))
    assert (on.applied_pct, on.reason) == (40.0, Reason.NORMAL)
    assert on.inputs == InputValues(program_enable=True)


def test_program_enable_required_without_the_input_stands_down():
    d = block(gate_with(program_enable_required=True), 0, 500.0, 40.0, InputValues())
    assert (d.applied_pct, d.reason) == (100.0, Reason.OPERATOR)
    assert 'no program-enable input' in d.detail


def test_the_program_enable_input_is_ignored_unless_required():
    d = block(gate_with(), 0, 500.0, 40.0, InputValues(program_enable=False))
    assert (d.applied_pct, d.reason) == (40.0, Reason.NORMAL)


def test_thread_cutting_and_tapping_stand_down_to_the_programmed_feed():
    gate = gate_with()
    d = block(gate, 0, 500.0, 60.0, InputValues(threading=True))
    assert (d.applied_pct, d.reason) == (100.0, Reason.OPERATOR)
    assert 'thread cutting or tapping' in d.detail
    assert block(gate, 1, 500.0, 60.0, InputValues(threading=False)).applied_pct == 60.0
    kept_on = gate_with(threading_stand_down=False)
    assert block(kept_on, 0, 500.0, 60.0, InputValues(threading=True)).applied_pct == 60.0


@pytest.mark.parametrize('inputs', [InputValues(threading=True),
                                    InputValues(program_enable=False)])
def test_the_safety_gate_comes_before_a_stand_down(inputs):
    # Overload hold, watchdog and invalid commands keep precedence over standing down.
    gate = gate_with(program_enable_required=True, overload_force_n=1500.0)
    gate.on_inputs(inputs)
    gate.on_command(60.0, 0.0)
    gate.on_estimate(1600.0)
    assert (gate.decide(0.0).applied_pct, gate.decide(0.0).reason) == (0.0,
                                                                        Reason.OVERLOAD_HOLD)
    gate = gate_with(program_enable_required=True, safe_override_pct=20.0)
    gate.on_inputs(inputs)
    gate.on_command(60.0, 0.0)
    stale = gate.decide(0.2)
    assert (stale.applied_pct, stale.reason) == (20.0, Reason.WATCHDOG)
    gate.on_command(math.nan, 0.2)
    assert gate.decide(0.2).reason == Reason.INVALID_COMMAND


# --- the operator's dial --------------------------------------------------------------------


@pytest.mark.parametrize(('mode', 'request_pct', 'dial', 'applied', 'reason'), [
    ('min', 120.0, 80.0, 80.0, Reason.OPERATOR),      # the dial is lower: it wins
    ('min', 60.0, 80.0, 60.0, Reason.NORMAL),         # the request is lower
    ('product', 120.0, 80.0, 100.0, Reason.OPERATOR),  # 96 %, the 0-T's nearest level 100
    ('product', 120.0, 150.0, 120.0, Reason.NORMAL),  # a dial over 100 % never raises it
    ('ignore', 120.0, 30.0, 120.0, Reason.NORMAL),
])
def test_the_operators_dial_keeps_precedence(mode, request_pct, dial, applied, reason):
    gate = gate_with(operator_dial=mode)
    d = block(gate, 0, 500.0, request_pct, InputValues(operator_dial_pct=dial))
    assert (d.applied_pct, d.reason) == (applied, reason)


def test_the_dial_lowers_the_programmed_feed_too_but_never_a_hold():
    gate = OverrideGate(BridgeSettings(overload_force_n=1500.0), t_s=0.0)   # disarmed
    gate.on_inputs(InputValues(operator_dial_pct=50.0))
    disarmed = gate.decide(0.0)
    assert (disarmed.applied_pct, disarmed.reason) == (50.0, Reason.DISARMED)
    assert "the operator's dial at 50 %" in disarmed.detail
    gate.on_estimate(1600.0)
    assert gate.decide(0.0).applied_pct == 0.0
    threading = gate_with()
    d = block(threading, 0, 500.0, 60.0, InputValues(threading=True, operator_dial_pct=70.0))
    assert (d.applied_pct, d.reason) == (70.0, Reason.OPERATOR)


# --- rise limit and feed floor --------------------------------------------------------------


def test_the_override_rises_at_the_limit_and_falls_at_once():
    # 10 %/s (Haas) at 10 ms: 0.1 % per period on a continuous override, from the 100 % the
    # PMC starts at.
    gate = gate_with(override_table='ideal', rise_rate_pct_s=10.0)
    for k in range(50):
        d = block(gate, k, 500.0, 150.0)
        assert d.applied_pct == pytest.approx(100.0 + 0.1 * (k + 1), abs=1e-9)
        assert d.reason == Reason.RISE_LIMIT
    fall = block(gate, 50, 500.0, 40.0)
    assert (fall.applied_pct, fall.reason) == (40.0, Reason.NORMAL)
    assert block(gate, 51, 500.0, 41.0).applied_pct == pytest.approx(40.1)


def test_after_a_hold_the_feed_rises_from_zero():
    gate = gate_with(override_table='ideal', rise_rate_pct_s=50.0, overload_force_n=1500.0)
    block(gate, 0, 500.0, 120.0)
    assert block(gate, 1, 1600.0, 120.0).reason == Reason.OVERLOAD_HOLD
    block(gate, 2, 400.0, 120.0)
    gate.arm(0.03)
    rising = [block(gate, k, 400.0, 120.0).applied_pct for k in range(3, 6)]
    np.testing.assert_allclose(rising, [0.5, 1.0, 1.5])


def test_on_the_0t_table_a_slow_rise_climbs_level_by_level():
    # 10 %/s with 10 % levels: one level a second, the nearest level of the ramp.
    gate = gate_with(rise_rate_pct_s=10.0)
    applied = [block(gate, k, 500.0, 150.0).applied_pct for k in range(300)]
    assert applied[:40] == [100.0] * 40
    assert applied[60:140] == [110.0] * 80      # 105 % is reached at 0.5 s
    assert applied[-1] == 130.0


def test_the_feed_floor_holds_while_cutting_only():
    gate = gate_with(min_cut_override_pct=30.0, overload_force_n=1500.0)
    out_of_cut = block(gate, 0, 10.0, 10.0)
    assert (out_of_cut.applied_pct, out_of_cut.reason) == (10.0, Reason.NORMAL)
    k = engage(gate, 1, request_pct=10.0)
    d = block(gate, k, 500.0, 10.0)
    assert (d.applied_pct, d.reason) == (30.0, Reason.FEED_FLOOR)
    assert block(gate, k + 1, 500.0, 60.0).applied_pct == 60.0
    assert block(gate, k + 2, 1600.0, 10.0).applied_pct == 0.0   # the hold comes first


# --- air cut and the cut detector ------------------------------------------------------------


def test_the_air_cut_override_until_the_cut_is_established_and_again_after_the_exit():
    # The entry feed: the air-cut override holds through the entry, until cut_settle_s (3
    # blocks here) after the force first passed engage_force_n, then the request goes through.
    gate = gate_with(air_cut_override_pct=100.0, engage_time_s=0.02, cut_settle_s=0.03)
    air = block(gate, 0, 5.0, 150.0)
    assert (air.applied_pct, air.reason, air.engaged) == (100.0, Reason.AIR_CUT, False)
    assert block(gate, 1, 5.0, 80.0).applied_pct == 80.0    # never above the request
    assert block(gate, 2, 300.0, 150.0).reason == Reason.AIR_CUT   # one block: not yet
    entering = block(gate, 3, 300.0, 150.0)
    assert (entering.applied_pct, entering.reason, entering.engaged) == (100.0, Reason.AIR_CUT,
                                                                         True)
    assert block(gate, 4, 300.0, 60.0).applied_pct == 60.0   # a lower request goes through
    entered = block(gate, 5, 300.0, 150.0)
    assert (entered.applied_pct, entered.reason, entered.engaged) == (150.0, Reason.NORMAL, True)
    # Between the thresholds (exit 50 N, engage 100 N) nothing changes: hysteresis.
    assert block(gate, 6, 70.0, 150.0).engaged
    assert block(gate, 7, 30.0, 150.0).engaged
    left = block(gate, 8, 30.0, 150.0)
    assert (left.applied_pct, left.reason, left.engaged) == (100.0, Reason.AIR_CUT, False)


def _entry_hold_s(gate: OverrideGate, force) -> float:
    """Seconds from the depth step (t = 0) to the first block the gate lets the request
    (150 %) through, with ``force(t)`` the force estimate at each block's end; the entry feed
    must have held while the tool was in the cut."""
    for k in range(400):
        t_s = (k + 1) * PERIOD_S
        answer = block(gate, k, force(t_s), 150.0)
        if answer.reason == Reason.NORMAL:
            return t_s
        assert answer.applied_pct == 30.0
    raise AssertionError('the entry feed held for 4 s')


@pytest.mark.parametrize('tau_c_s', [0.1, 0.2, 0.4])
def test_the_entry_feed_holds_until_the_force_is_established(tau_c_s):
    # A chip that forms slowly: after the depth step the force rises as 600 (1 - exp(-t /
    # tau_c)) at the entry feed. Its rise over its level is exp(-x) / (tau_c (1 - exp(-x))),
    # x = t / tau_c, which falls to entry_rise_limit_per_s (0.5 / s) at exp(-x) = 0.5 tau_c /
    # (1 + 0.5 tau_c), the force then within 5 %, 9 % and 17 % of its level: 0.30 s at 0.1 s,
    # 0.48 s at 0.2 s, 0.72 s at 0.4 s. The slope is the least squares one over the last 0.1 s,
    # the slope 0.05 s before; with the lag of its fall below the limit the hold ends up to
    # 0.15 s after; never before cut_settle_s (0.3 s after the engagement at 100 N).
    gate = gate_with(air_cut_override_pct=30.0)
    held = _entry_hold_s(gate, lambda t: 600.0 * (1.0 - math.exp(-t / tau_c_s)))
    x = -math.log(0.5 * tau_c_s / (1.0 + 0.5 * tau_c_s))
    engaged = -tau_c_s * math.log(1.0 - 100.0 / 600.0) + 0.02
    assert max(x * tau_c_s, engaged + 0.3) <= held <= max(x * tau_c_s + 0.15, engaged + 0.32)


def test_the_entry_feed_holds_cut_settle_s_only_where_asked_and_at_most_entry_hold_max_s():
    rising = lambda t: 600.0 * (1.0 - math.exp(-t / 0.4))   # noqa: E731
    # entry_rise_limit_per_s 0: the hold is cut_settle_s from the first block over 100 N
    # (0.08 s; the engagement a block later), as a fixed hold was
    gate = gate_with(air_cut_override_pct=30.0, entry_rise_limit_per_s=0.0)
    assert _entry_hold_s(gate, rising) == pytest.approx(0.08 + 0.3, abs=1e-9)
    # a force that keeps rising faster than the limit (a ramp of 2,000 N/s from 200 N: 10/s
    # down to 1.7/s over the first 0.5 s) is held no longer than entry_hold_max_s from the
    # first block over 100 N (0.01 s)
    gate = gate_with(air_cut_override_pct=30.0, entry_hold_max_s=0.5)
    assert _entry_hold_s(gate, lambda t: 200.0 + 2000.0 * t) == pytest.approx(0.01 + 0.5,
                                                                               abs=1e-9)


def test_air_cut_in_a_simulated_approach(tmp_path):
    # Park's fig8 lathe approaching for 1 s in air: the controller asks for 150 % (no force),
    # the bridge holds 100 % until the tool is in the part, then regulates.
    e = load_experiment(EXPERIMENTS / 'park1998_fig8.yaml').with_sets([
        'lathe_sim.depth_times_s=[0.0, 1.0]', 'lathe_sim.depth_mm=[0.0, 1.0]',
        'pmc_bridge.air_cut_override_pct=100.0', 'experiment.duration_s=3.0'])
    trace = simulate(e).trace
    t, applied = trace['t_s'], trace['applied_override_pct']
    assert np.all(applied[t < 1.0] == 100.0)
    assert np.all(trace['requested_override_pct'][(t > 0.1) & (t < 1.0)] == 150.0)
    assert np.max(applied[t > 1.0]) > 100.0          # regulating once in the cut
    assert trace['force_n'][-1] == pytest.approx(500.0, abs=25.0)


# --- overload reactions ----------------------------------------------------------------------


@pytest.mark.parametrize(('reaction', 'applied', 'reason', 'alarm', 'stop'), [
    ('alarm', 120.0, Reason.NORMAL, True, False),
    ('hold', 0.0, Reason.OVERLOAD_HOLD, True, False),
    ('stop', 120.0, Reason.NORMAL, True, True),
])
def test_an_overload_reaction_after_the_settable_time(reaction, applied, reason, alarm, stop):
    # Limit 0.8 x 2000 N = 1600 N for 0.1 s = ten blocks; the tenth block reacts.
    gate = gate_with(overload_reaction=reaction, reaction_delay_s=0.1)
    k = engage(gate)
    for j in range(9):
        d = block(gate, k + j, 1700.0)
        assert (d.applied_pct, d.alarm, d.stop_request) == (120.0, False, False)
    d = block(gate, k + 9, 1700.0)
    assert (d.applied_pct, d.reason, d.alarm, d.stop_request) == (applied, reason, alarm, stop)
    block(gate, k + 10, 500.0)                  # latched: the force falling does not end it
    assert gate.decide((k + 11) * PERIOD_S).alarm
    gate.arm((k + 11) * PERIOD_S)               # re-arming clears it
    d = block(gate, k + 11, 500.0)
    assert (d.applied_pct, d.alarm, d.stop_request) == (120.0, False, False)


def test_the_reaction_timer_restarts_when_the_force_dips_and_waits_while_stood_down():
    gate = gate_with(overload_reaction='hold', reaction_delay_s=0.1)
    k = engage(gate)
    for j in range(9):
        block(gate, k + j, 1700.0)
    block(gate, k + 9, 1500.0)                 # under the limit: the timer starts again
    for j in range(9):
        assert block(gate, k + 10 + j, 1700.0).reason == Reason.NORMAL
    k += 19
    for j in range(20):                        # threading: the option is off, no reaction
        assert block(gate, k + j, 1700.0, inputs=InputValues(threading=True)).reason == (
            Reason.OPERATOR)


# --- tool breakage ---------------------------------------------------------------------------


def breakage_experiment(*sets: str):
    return load_experiment(EXPERIMENTS / 'park1998_fig8.yaml').with_sets([
        'experiment.duration_s=4.0', 'pmc_bridge.breakage_spike_fraction=1.0',
        'pmc_bridge.breakage_drop_fraction=0.5', 'pmc_bridge.overload_force_n=4000.0',
        '/**.max_feed_force_n=5000.0', *sets])


def run_chain(e):
    plant = LathePlant(e.plant)
    chain = ControlChain(e.estimator, e.controller, e.bridge)
    applied, out = 100.0, []
    for _ in range(round(e.run.duration_s / PERIOD_S)):
        b = plant.step(applied)
        step = chain.step(b.currents, inputs=b.inputs)
        out.append((b, step))
        applied = step.decision.applied_pct
    return out, chain.close()


def test_a_force_spike_holds_the_feed_within_two_control_periods():
    # At 3 s the insert breaks and the holder digs in: the depth of cut jumps from 1 to 3 mm
    # at once (no chip-formation lag: tau_c = 0). The detector, with a level of 500 N, holds
    # the feed on the block whose estimate passes 1000 N; the PMC applies 0 % from the next.
    e = breakage_experiment('lathe_sim.depth_times_s=[0.0, 3.0]',
                            'lathe_sim.depth_mm=[1.0, 3.0]',
                            'lathe_sim.cutting_time_constant_s=0.0')
    out, cuts = run_chain(e)
    reasons = [s.decision.reason for _, s in out]
    first = reasons.index(Reason.TOOL_BREAKAGE)
    assert set(reasons[first:]) == {Reason.TOOL_BREAKAGE}
    # The depth steps at the start of the block ending at 3.01 s (index 300): the hold answers
    # that very block, and the PMC holds the feed from the next one (within two periods).
    assert first == 300
    assert out[first][1].decision.alarm
    assert 'above its recent level' in out[first][1].decision.detail
    assert cuts[0].breakage


def test_a_force_drop_holds_the_feed_while_the_program_says_the_tool_cuts():
    # At 3 s the insert breaks off: the depth falls from 2 to 0.4 mm (the holder rubs on).
    program = ['lathe_sim.program_enable_spans_s=[0.0, 3.5]']
    e = breakage_experiment('lathe_sim.depth_times_s=[0.0, 3.0]',
                            'lathe_sim.depth_mm=[2.0, 0.4]', *program)
    out, _ = run_chain(e)
    reasons = [s.decision.reason for _, s in out]
    first = reasons.index(Reason.TOOL_BREAKAGE)
    assert 300 <= first <= 310      # within the process lag (tau_c = 50 ms) of the drop
    assert 'below its recent level' in out[first][1].decision.detail


def test_a_tool_exit_is_no_breakage_when_the_program_cleared_the_input():
    # The same drop, to 0 mm (the tool leaves the part), after the program cleared the enable
    # input (M811 before the exit): a cut in the log, no hold.
    e = breakage_experiment('lathe_sim.depth_times_s=[0.0, 3.0]',
                            'lathe_sim.depth_mm=[2.0, 0.0]',
                            'lathe_sim.program_enable_spans_s=[0.0, 2.9]')
    out, cuts = run_chain(e)
    assert Reason.TOOL_BREAKAGE not in {s.decision.reason for _, s in out}
    assert len(cuts) == 1 and cuts[0].complete and not cuts[0].breakage
    # The force falls with the process lag (50 ms) from at most 880 N (2 mm at 100 %) to the
    # 50 N exit threshold: 0.05 ln(880 / 50) = 0.14 s, plus a block of detector and stamp.
    assert 3.0 < cuts[0].end_s <= 3.0 + 0.05 * math.log(880.0 / 50.0) + 0.02


# --- the cut log -------------------------------------------------------------------------------


def test_the_cut_log_of_a_known_cut():
    # 10 blocks in air, 100 blocks at 500 N (a 900 N peak) at 50 %, 10 blocks in air. The cut is
    # the 100 blocks: 1 s, at a fixed 100 % it would take 0.5 s.
    gate = gate_with(reaction_force_fraction=0.4)    # limit 800 N: the peak is one event
    k = 0
    for _ in range(10):
        block(gate, k, 0.0, 50.0)
        k += 1
    for j in range(100):
        block(gate, k, 900.0 if j == 50 else 500.0, 50.0, reachable=j < 75)
        k += 1
    for _ in range(10):
        block(gate, k, 0.0, 50.0)
        k += 1
    [cut] = gate.take_cuts()
    assert (cut.start_s, cut.end_s) == (pytest.approx(0.10), pytest.approx(1.10))
    assert cut.duration_s == pytest.approx(1.0)
    assert cut.programmed_feed_s == pytest.approx(0.5)
    assert (cut.max_force_n, cut.min_override_pct, cut.overload_events) == (900.0, 50.0, 1)
    assert cut.mean_force_n == pytest.approx(504.0)
    assert cut.reachable_fraction == pytest.approx(0.75)
    assert cut.complete and not cut.breakage and cut.index == 1


def test_an_open_cut_is_closed_incomplete():
    gate = gate_with()
    engage(gate, blocks=5)
    assert gate.take_cuts() == []
    record = gate.close()
    assert record is not None and not record.complete
    assert record.duration_s == pytest.approx(0.05)


def test_the_shopfloor_experiment_logs_its_two_cuts():
    e = load_experiment(EXPERIMENTS / 'shopfloor.yaml')
    out, cuts = run_chain(e)
    turning, threading = cuts
    # Engaged within a block or two of the depth steps (1.0 s in, 10.6 s out, 11.5-13.0 s).
    assert turning.start_s == pytest.approx(1.0, abs=0.03)
    assert turning.end_s == pytest.approx(10.6, abs=0.12)
    assert threading.start_s == pytest.approx(11.5, abs=0.04)
    # The threading pass runs at the programmed feed: its time is the programmed one.
    assert threading.min_override_pct == 100.0
    assert threading.programmed_feed_s == pytest.approx(threading.duration_s)
    # 0.5 mm at 0.2 mm/rev: K_s d f = 2200 * 0.5 * 0.2 = 220 N.
    assert threading.mean_force_n == pytest.approx(220.0, rel=0.05)
    reasons = {s.decision.reason for _, s in out}
    assert {Reason.AIR_CUT, Reason.RISE_LIMIT, Reason.OPERATOR, Reason.NORMAL} <= reasons
    dialled = [s.decision for b, s in out if 6.6 <= b.currents.t0_s < 7.4]
    assert all(d.applied_pct <= 40.0 for d in dialled)
    assert all(not s.decision.alarm for _, s in out)


# --- safety: never above the request -----------------------------------------------------------


def test_no_convenience_writes_more_than_the_request():
    # Every behaviour on (the feed floor, the one that raises, aside), random requests, forces
    # and dial, the program enabling: a regulating decision never exceeds the quantised request.
    rng = np.random.default_rng(7)
    table = get_table('fanuc_0t_4bit')
    gate = gate_with(program_enable_required=True, operator_dial='product',
                     rise_rate_pct_s=20.0, air_cut_override_pct=80.0,
                     overload_reaction='hold', reaction_delay_s=0.05,
                     breakage_spike_fraction=0.5)
    for k in range(3000):
        request = float(rng.uniform(0.0, 150.0))
        force = float(rng.choice([0.0, 60.0, 300.0, 500.0, 1700.0]))
        dial = float(rng.choice([0.0, 50.0, 100.0, 150.0]))
        d = block(gate, k, force, request, InputValues(True, False, dial))
        assert d.applied_pct <= table.quantise(request), (k, d)
        if d.reason in (Reason.OVERLOAD_HOLD, Reason.TOOL_BREAKAGE) and k % 50 == 0:
            gate.arm((k + 1) * PERIOD_S)


# --- teach-in ---------------------------------------------------------------------------------


def test_a_learning_cut_sets_the_reference():
    # 1 mm at the programmed 0.2 mm/rev: K_s d f = 2200 * 1 * 0.2 = 440 N. The learning cut
    # (0.5-3 s) runs at 100 %; its level, the mean over the settled part, sets the reference to
    # 0.9 of it, and the next cut (3.5-6 s) is regulated there.
    e = load_experiment(EXPERIMENTS / 'park1998_fig8.yaml').with_sets([
        'experiment.duration_s=6.0', 'lathe_sim.depth_times_s=[0.0, 0.5, 3.0, 3.5]',
        'lathe_sim.depth_mm=[0.0, 1.0, 0.0, 1.0]', 'pmc_bridge.teach_in=true',
        'pmc_bridge.tool=T0101', 'pmc_bridge.teach_file=unused.yaml'])
    out, cuts = run_chain(e)
    learning = [s for b, s in out if b.currents.t0_s < 3.0]
    assert {s.decision.applied_pct for s in learning} == {100.0}
    assert Reason.TEACH_IN in {s.decision.reason for s in learning}
    [learned] = [s.learned for _, s in out if s.learned is not None]
    assert learned.refused == '' and learned.tool == 'T0101'
    # The estimate's noise and its calibration leave the level within 1 % of 440 N.
    assert learned.taught.learned_force_n == pytest.approx(440.0, rel=0.01)
    reference = learned.taught.reference_force_n
    assert reference == pytest.approx(0.9 * learned.taught.learned_force_n)
    assert cuts[0].learned and not cuts[1].learned
    late = [b.force_n[-1] for b, s in out if b.currents.t0_s > 5.0]
    assert np.mean(late) == pytest.approx(reference, abs=10.0)


def test_a_learning_cut_that_did_not_run_at_the_programmed_feed_is_not_learned():
    gate = gate_with(teach_in=True, tool='T1', teach_file='t.yaml', cut_settle_s=0.0)
    gate.on_inputs(InputValues(operator_dial_pct=70.0))
    k = engage(gate, blocks=40)
    for j in range(3):
        block(gate, k + j, 0.0)
    learned = gate.take_learned()
    assert learned is not None and 'did not run at the programmed feed' in learned.refused
    # Still learning: the next cut is tried at the programmed feed.
    assert gate.decide((k + 3) * PERIOD_S).reason == Reason.TEACH_IN


def test_the_teach_file_round_trip_and_the_reference_it_gives(tmp_path):
    path = tmp_path / 'tools' / 'teach.yaml'
    assert load_teach_file(path) == {}
    save_teach_file(path, 'T0101', TaughtTool(440.0, 0.9, 396.0, 470.0, 2.5))
    save_teach_file(path, 'T0202', TaughtTool(800.0, 0.8, 640.0))
    tools = load_teach_file(path)
    assert tools['T0101'] == TaughtTool(440.0, 0.9, 396.0, 470.0, 2.5)
    assert tools['T0202'].reference_force_n == 640.0
    settings = BridgeSettings(tool='T0101', teach_file=str(path))
    assert taught_reference(settings) == 396.0
    assert taught_reference(settings.replace(tool='T9')) is None
    assert taught_reference(settings.replace(teach_in=True)) is None   # this session learns
    e = load_experiment(EXPERIMENTS / 'park1998_fig8.yaml').with_sets([
        'pmc_bridge.tool=T0101', f'pmc_bridge.teach_file={path}'])
    chain = ControlChain(e.estimator, e.controller, e.bridge)
    assert chain.controller.settings.reference_force_n == 396.0


@pytest.mark.parametrize(('text', 'message'), [
    ('tools: [', r'teach\.yaml: teach-in file is not valid YAML'),
    ('tools: 3', r'teach\.yaml: tools = 3: expected a mapping'),
    ('other: {}', r'teach\.yaml: expected a mapping with one key, tools'),
    ('tools: {T1: 5}', r'teach\.yaml: tools\.T1 = 5: expected a mapping'),
    ('tools: {T1: {learned_force_n: abc, teach_fraction: 0.9, reference_force_n: 1}}',
     r"teach\.yaml: tools\.T1\.learned_force_n = 'abc': expected a finite number above 0"),
    ('tools: {T1: {learned_force_n: 400, teach_fraction: 0.9, reference_force_n: -1}}',
     r'teach\.yaml: tools\.T1\.reference_force_n = -1: expected a finite number above 0'),
    ('tools: {T1: {learned_force_n: 400, teach_fraction: 0.9}}',
     r'teach\.yaml: tools\.T1\.reference_force_n = None: expected a finite number'),
    ('tools: {T1: {learned_force_n: 400, teach_fraction: 0.9, reference_force_n: 360, x: 1}}',
     r"teach\.yaml: tools\.T1: unknown keys \['x'\]"),
])
def test_a_malformed_teach_file_is_refused_in_one_line(tmp_path, text, message):
    path = tmp_path / 'teach.yaml'
    path.write_text(text)
    with pytest.raises(ConfigError, match=message) as info:
        load_teach_file(path)
    assert '\n' not in str(info.value)


def test_a_taught_reference_that_would_hold_the_feed_is_refused(tmp_path):
    path = tmp_path / 'teach.yaml'
    save_teach_file(path, 'T1', TaughtTool(2500.0, 0.9, 2250.0))
    e = load_experiment(EXPERIMENTS / 'park1998_fig8.yaml').with_sets([
        'pmc_bridge.tool=T1', f'pmc_bridge.teach_file={path}'])
    with pytest.raises(ConfigError, match=r'teach\.yaml: tools\.T1\.reference_force_n = 2250\.0'
                                          r': not below pmc_bridge\.overload_force_n'):
        ControlChain(e.estimator, e.controller, e.bridge)


# --- settings and simulated inputs -------------------------------------------------------------


@pytest.mark.parametrize(('changes', 'message'), [
    ({'exit_force_n': 100.0}, r'exit_force_n = 100\.0: not below engage_force_n'),
    ({'teach_file': 'x.yaml'}, r"pmc_bridge\.tool = '': empty, with teach_file"),
    ({'teach_in': True, 'tool': 'T1'}, r"pmc_bridge\.teach_file = '': empty, with teach_in"),
    ({'air_cut_override_pct': 160.0}, r'air_cut_override_pct = 160\.0: above the fanuc_0t'),
    ({'operator_dial': 'max'}, r'operator_dial = .max.: expected one of min, product, ignore'),
])
def test_bad_shopfloor_settings(changes, message):
    with pytest.raises(ConfigError, match=message):
        BridgeSettings(**changes)


def test_the_simulated_machines_inputs():
    s = PlantSettings(program_enable_spans_s=(0.5, 1.0, 2.0, 3.0),
                      threading_spans_s=(1.5, 1.7), operator_dial_wired=True,
                      operator_dial_times_s=(0.0, 2.5), operator_dial_pct=(150.0, 40.0))
    assert s.inputs_at(0.4) == InputValues(False, False, 150.0)
    assert s.inputs_at(0.5) == InputValues(True, False, 150.0)
    assert s.inputs_at(1.0) == InputValues(False, False, 150.0)   # [start, end)
    assert s.inputs_at(1.6) == InputValues(False, True, 150.0)
    assert s.inputs_at(2.5) == InputValues(True, False, 40.0)
    assert s.inputs_at(2.0 - 1e-12) == InputValues(True, False, 150.0)  # a sum of periods
    assert PlantSettings().inputs_at(1.0) == InputValues()         # none wired


@pytest.mark.parametrize(('changes', 'message'), [
    ({'program_enable_spans_s': (1.0,)}, r'program_enable_spans_s = \(1\.0,\): expected'),
    ({'threading_spans_s': (2.0, 1.0)}, r'threading_spans_s = \(2\.0, 1\.0\): expected'),
    ({'operator_dial_pct': (1.0, 2.0)}, r'operator_dial_pct = \(1\.0, 2\.0\): needs one value'),
])
def test_bad_simulated_inputs(changes, message):
    with pytest.raises(ConfigError, match=message):
        PlantSettings(**changes)


def test_a_binary_teach_file_is_a_config_error_naming_it(tmp_path):
    # The bridge node reads it at configure: one line, not a traceback (issue 17's poor list).
    from turning_force.core.errors import ConfigError
    from turning_force.core.pmc.shopfloor import load_teach_file

    teach = tmp_path / 'teach.yaml'
    teach.write_bytes(bytes(range(256)))
    with pytest.raises(ConfigError, match=r'teach\.yaml: pmc_bridge\.teach_file: not a text'):
        load_teach_file(teach)
