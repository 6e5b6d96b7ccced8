"""The fault suite (issue 17 item 9): pmc_bridge on an independent Modbus/TCP module
(pyModbusTCP's server) behind a proxy that drops, delays, truncates, shortens, corrupts,
reorders and refuses answers and closes connections, with the wall clock stepped either way
and arming tried during faults; each case generated from its seed, and the module's whole coil
history checked against the safety contract (docs/safety.md):

- only legal levels: every pattern written decodes to a level of the table;
- never above what is allowed: armed, at most the controller's highest request and the
  operator's dial (operator_dial min); disarmed, at configure, after a fault and at stop, at
  most the hand-back level and the dial;
- a fault is the safe state: disarmed, said in FeedOverride, arming refused while it lasts,
  no exception out of the node;
- a clock step trips nothing: no watchdog while the commands flow.

``make test`` runs a sample of 40 cases; ``make test-all`` all 300.
"""

from __future__ import annotations

import math
import random
import re
import time
from dataclasses import dataclass

import pytest
from turning_force_msgs.msg import FeedOverride

from bridge_harness import WallClock, rig
from faultproxy import FAULTS, random_plan
from turning_force.nodes.pmc_bridge import BridgeStartError

CASES = 300
SAMPLE = list(range(0, CASES, 7))[:40]
MAX_REQUEST_PCT = 120.0
RUN_S = 0.5           # per case: 50 control periods
CONFIGURE_ANSWERS = 12   # connect, claim, inputs and the first hand-back, with room
WATCHDOG_S = 0.3      # long against a loaded machine's scheduling, short against a 1 s step
STEP_MIN_S = 1.0      # the smallest step of the wall clock a case makes


@dataclass(frozen=True)
class Case:
    seed: int
    rate: float                  # share of answers faulted
    faults: tuple[str, ...]
    dial_pct: float              # 150: every dial input off (an unwired dial reads so)
    hand_back_pct: float
    owner_register: int | None
    step_s: float                # the wall clock's step, either way
    step_at_s: float


def case(seed: int) -> Case:
    draw = random.Random(seed)
    faults = tuple(draw.sample(FAULTS[1:], draw.randint(1, 4)))
    return Case(seed, draw.choice((0.02, 0.05, 0.1, 0.2)), faults,
                draw.choice((150.0, 100.0, 70.0, 40.0)), draw.choice((100.0, 50.0, 0.0)),
                draw.choice((None, 10)),
                draw.choice((-1.0, 1.0)) * draw.uniform(STEP_MIN_S, 3600.0),
                draw.uniform(0.05, RUN_S))


def run_case(context, executor, tmp_path, monkeypatch, c: Case) -> None:
    wall = WallClock(monkeypatch)
    draw = random.Random(c.seed + 10**6)
    # The faults start once the bridge is configured (a configure that fails is refused with
    # its reason: test_pmc_lifecycle.py).
    with rig(tmp_path, random_plan(c.seed, c.rate, c.faults, first=CONFIGURE_ANSWERS),
             owner_register=c.owner_register) as the_rig:
        driver = the_rig.driver(context, executor)
        the_rig.set_dial(c.dial_pct)
        try:
            bridge = the_rig.bridge(context, executor, armed=True,
                                    watchdog_period_s=WATCHDOG_S, hand_back_pct=c.hand_back_pct)
        except BridgeStartError as exc:   # a module too slow to configure (a loaded machine):
            text = str(exc)               # refused with the reason, nothing above the hand-back
            assert 'configure failed' in text and '\n' not in text
            assert all(pct <= min(c.hand_back_pct, c.dial_pct)
                       for _, pct in the_rig.override_writes())
            return
        first_fault_s: list[float] = []
        refused: list[str] = []
        stepped = [False]
        start = time.monotonic()
        request = [60.0]

        def each() -> None:
            now = time.monotonic()
            if bridge.io_fault and not first_fault_s:
                first_fault_s.append(now)
            if bridge.io_fault and draw.random() < 0.05:   # the operator tries to arm
                acts, message = bridge.arm()
                assert not acts and message.startswith('arm refused: the module is in fault')
                refused.append(message)
            if not stepped[0] and now - start >= c.step_at_s:
                wall.step(c.step_s)
                stepped[0] = True

        def walk() -> float:
            request[0] = min(max(request[0] + draw.uniform(-15.0, 15.0), 0.0), MAX_REQUEST_PCT)
            return request[0]

        driver.run(RUN_S, pct=walk, each=each)
        stop_s = time.monotonic()
        bridge.stop()
        writes = the_rig.override_writes()   # decoding raises on a pattern that is no level
    # The dial as the bridge read it: a module that answers a wrong dial the same way twice
    # in a row (a deterministic corruption) is read as the operator turning it; every
    # FeedOverride records the dial its decision saw, and never goes above it.
    read = [m.operator_dial_pct for m in driver.overrides if math.isfinite(m.operator_dial_pct)]
    dial = max([c.dial_pct, *read])
    handed_back = min(c.hand_back_pct, dial)
    armed_bound = min(MAX_REQUEST_PCT, dial)
    for msg in driver.overrides:
        if math.isfinite(msg.operator_dial_pct) and msg.reason != FeedOverride.REASON_IO_FAULT:
            assert msg.applied_pct <= msg.operator_dial_pct, (msg.applied_pct, msg.detail)
    assert writes, 'nothing reached the module'
    assert writes[0][1] <= handed_back, f'configure wrote {writes[0][1]} %'
    for t_s, pct in writes:
        assert pct <= armed_bound, f'{pct} % above what is allowed ({armed_bound} %)'
        if first_fault_s and t_s > first_fault_s[0]:
            assert pct <= handed_back, f'{pct} % after a fault (hand-back {handed_back} %)'
        if t_s >= stop_s:
            assert pct <= handed_back, f'{pct} % at stop (hand-back {handed_back} %)'
    for msg in driver.overrides:
        if msg.reason == FeedOverride.REASON_IO_FAULT:
            assert not msg.armed and 'disarmed' in msg.detail and msg.detail
        # The watchdog in its waiting state, just after arming, or on a command that really
        # waited: the executor held up by an answer the proxy dropped (the rig's 0.1 s timeout)
        # on a loaded machine (seed 238 under make test: 0.333 s). A clock step that tripped it
        # would make the command look at least the smallest step old (STEP_MIN_S).
        if msg.reason == FeedOverride.REASON_WATCHDOG and not msg.detail.startswith(
                'armed, waiting for the first feed command'):
            age = re.match(r'feed command ([0-9.]+) s old', msg.detail)
            assert age is not None and float(age.group(1)) < STEP_MIN_S, msg.detail


@pytest.mark.parametrize('seed', SAMPLE)
def test_a_sample_of_the_fault_cases(context, executor, tmp_path, monkeypatch, seed):
    run_case(context, executor, tmp_path, monkeypatch, case(seed))


@pytest.mark.slow
@pytest.mark.parametrize('seed', [s for s in range(CASES) if s not in SAMPLE])
def test_every_fault_case(context, executor, tmp_path, monkeypatch, seed):
    run_case(context, executor, tmp_path, monkeypatch, case(seed))


def test_the_suite_covers_every_fault_and_both_clock_steps():
    cases = [case(seed) for seed in range(CASES)]
    assert {f for c in cases for f in c.faults} == set(FAULTS[1:])
    assert {c.step_s > 0 for c in cases} == {True, False}
    assert {c.owner_register for c in cases} == {None, 10}
    sample = [case(seed) for seed in SAMPLE]
    assert len(sample) == 40 and {f for c in sample for f in c.faults} == set(FAULTS[1:])
