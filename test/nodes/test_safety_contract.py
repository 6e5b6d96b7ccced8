"""The safety contract (docs/safety.md) held where 3638a43 broke it (issue 17, U1-U5), on an
independent Modbus/TCP module (pyModbusTCP's server) behind a fault proxy: the hand-back
bounded whatever the dial reads (U1), no arming during a fault (U2), malformed answers as
faults, never exceptions (U3), one bridge per module (U4), and time that cannot jump (U5).
U6 is in test/core/test_machine.py and test/cli/test_pmc_check.py."""

from __future__ import annotations

import pytest
from turning_force_msgs.msg import FeedOverride

from bridge_harness import WallClock, rig
from faultproxy import Module

# Generous for a loaded 2-core machine: the tests are about what reaches the coils.
WATCHDOG_S = 0.3


def levels(the_rig) -> list[float]:
    return [pct for _, pct in the_rig.override_writes()]


@pytest.mark.parametrize('hand_back_pct', [100.0, 50.0])
def test_u1_the_hand_back_never_exceeds_its_level_whatever_the_dial_reads(
        context, executor, tmp_path, hand_back_pct):
    # The dial's four inputs all off: on the 0-T's table the code for 150 %, which an unwired
    # dial cannot be told from. 3638a43 wrote 150 % at stop, even never armed.
    with rig(tmp_path) as the_rig:
        driver = the_rig.driver(context, executor)
        the_rig.module.bank.set_discrete_inputs(2, [False] * 4)
        bridge = the_rig.bridge(context, executor, hand_back_pct=hand_back_pct)
        driver.run(0.3, pct=120.0)
        assert bridge.inputs.operator_dial_pct == 150.0
        bridge.stop()
        written = levels(the_rig)
        assert written and max(written) == hand_back_pct   # configure, then the stop
        # A dial below the level is the hand-back (never above the dial).
        bridge.start()
        the_rig.set_dial(40.0)
        driver.run(0.3, pct=120.0)
        bridge.stop()
        assert levels(the_rig)[-1] == 40.0


def test_u2_arm_is_refused_during_a_fault_and_the_bridge_stays_disarmed_after(
        context, executor, tmp_path):
    dead = {'on': False}
    with rig(tmp_path, plan=lambda i, fc: 'close' if dead['on'] else 'pass') as the_rig:
        driver = the_rig.driver(context, executor)
        the_rig.set_dial(100.0)
        bridge = the_rig.bridge(context, executor, armed=True, watchdog_period_s=WATCHDOG_S)
        assert driver.until(lambda: driver.overrides and
                            driver.last().reason == FeedOverride.REASON_NORMAL)
        dead['on'] = True
        assert driver.until(lambda: bool(bridge.io_fault))
        acts, message = bridge.arm()
        assert not acts and message.startswith('arm refused: the module is in fault: '
                                               'modbus_tcp 127.0.0.1:')
        assert not bridge.get_parameter('armed').value
        dead['on'] = False
        # Back: the hand-back, disarmed, whatever the controller asks, until armed again.
        assert driver.until(lambda: not bridge.io_fault and
                            driver.last().reason == FeedOverride.REASON_DISARMED)
        count = len(driver.overrides)
        driver.run(0.3, pct=60.0)
        assert {m.reason for m in driver.overrides[count:]} == {FeedOverride.REASON_DISARMED}
        assert levels(the_rig)[-1] == 100.0
        assert bridge.arm() == (True, 'armed')
        assert driver.until(lambda: levels(the_rig)[-1] == 60.0)


@pytest.mark.parametrize('fault', ['short', 'wrong_function', 'exception', 'out_of_range',
                                   'corrupt', 'empty', 'truncate'])
def test_u3_a_malformed_answer_is_a_fault_never_an_exception(context, executor, tmp_path,
                                                             fault):
    # From the 40th answer on, three answers in a row faulted: the bridge goes safe, says why in
    # FeedOverride and /diagnostics, stays alive (an exception would leave spin_once), and
    # comes back disarmed.
    with rig(tmp_path, plan=lambda i, fc: fault if 40 <= i < 43 else 'pass') as the_rig:
        driver = the_rig.driver(context, executor)
        the_rig.set_dial(100.0)
        bridge = the_rig.bridge(context, executor, armed=True, watchdog_period_s=WATCHDOG_S)
        assert driver.until(lambda: any(m.reason == FeedOverride.REASON_IO_FAULT
                                        for m in driver.overrides))
        faulted = next(m for m in driver.overrides if m.reason == FeedOverride.REASON_IO_FAULT)
        assert not faulted.armed and 'disarmed, reconnecting' in faulted.detail
        assert any(word in faulted.detail for word in (
            'malformed answer', 'refused, exception code 4', 'read back', 'no answer within',
            'operator dial'))
        assert driver.until(lambda: any('IO_FAULT' in d for d in driver.diagnostics))
        if fault in ('empty', 'truncate'):   # no whole answer in time: misses, then the fault
            assert driver.until(lambda: any(d.startswith('io_misses=') for d in
                                            driver.diagnostics))
        assert driver.until(lambda: not bridge.io_fault and
                            driver.last().reason == FeedOverride.REASON_DISARMED)
        assert max(levels(the_rig)[-3:]) <= 100.0


@pytest.mark.parametrize(('owner_register', 'found'), [
    (10, 'another bridge on the module'),      # the owner token: CONFLICT for the other
    (None, 'another writer on the module'),    # the coils changed: 0 % for the other
], ids=['owner register', 'coils only'])
def test_u4_two_bridges_on_one_module_both_refuse(context, executor, tmp_path, owner_register,
                                                  found):
    with rig(tmp_path, owner_register=owner_register) as the_rig:
        first_driver = the_rig.driver(context, executor, '/first')
        the_rig.set_dial(100.0)
        first = the_rig.bridge(context, executor, '/first', armed=True,
                               watchdog_period_s=WATCHDOG_S)
        assert first_driver.until(lambda: 60.0 in levels(the_rig))
        second = the_rig.bridge(context, executor, '/second')
        assert first_driver.until(lambda: bool(first.io_fault and second.io_fault))
        for bridge in (first, second):
            assert found in bridge.io_fault
            assert 'both refuse' in bridge.io_fault
            assert bridge.backend.refused   # and it stays so: no reconnect
        count = len(levels(the_rig))
        first_driver.run(0.3, pct=120.0)
        assert len(levels(the_rig)) == count   # neither writes any more
        # 3638a43: the coils alternated 150 % / 0 %. Here: the first's level, then the
        # second's hand-back, nothing above either; without a token, the 0 % the first wrote
        # for the second to find is the last (feed hold, below every hand-back level).
        assert max(levels(the_rig)) <= 100.0
        if owner_register is None:
            assert levels(the_rig)[-1] == 0.0


@pytest.mark.parametrize('step_s', [-30.0, 30.0])
def test_u5_the_watchdog_does_not_read_the_wall_clock(context, executor, tmp_path,
                                                      monkeypatch, step_s):
    wall = WallClock(monkeypatch)
    with rig(tmp_path) as the_rig:
        driver = the_rig.driver(context, executor)
        the_rig.set_dial(100.0)
        bridge = the_rig.bridge(context, executor, armed=True, watchdog_period_s=WATCHDOG_S)
        assert driver.until(lambda: driver.overrides and
                            driver.last().reason == FeedOverride.REASON_NORMAL)
        count = len(driver.overrides)
        wall.step(step_s)
        # Commands keep coming: a forward step must not trip the watchdog (3638a43: 0 % at
        # once), a backward one must not blind it.
        driver.run(0.5, pct=60.0)
        assert {m.reason for m in driver.overrides[count:]} == {FeedOverride.REASON_NORMAL}
        # The controller stops: the safe override (0 %) within the watchdog period.
        assert driver.until(lambda: levels(the_rig)[-1] == 0.0 and
                            driver.last().reason == FeedOverride.REASON_WATCHDOG,
                            pct=None, timeout_s=5.0)
        assert bridge.get_parameter('armed').value
        stale = next(m for m in reversed(driver.overrides)
                     if m.reason == FeedOverride.REASON_WATCHDOG)
        # Its age measured on the steady clock: the watchdog's, not the 30 s step (a loaded
        # machine may add a second).
        assert stale.detail.startswith('feed command ') and stale.detail.endswith(
            's old (watchdog 0.3 s)')
        assert WATCHDOG_S <= float(stale.detail.split()[2]) < WATCHDOG_S + 1.0


def test_the_independent_module_is_not_ours():
    # The suite's module is pyModbusTCP's server, not pymodbus (the client under test).
    assert Module().server.__class__.__module__ == 'pyModbusTCP.server'
