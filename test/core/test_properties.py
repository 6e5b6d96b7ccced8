"""Properties that must hold for any input (hypothesis): what reaches the PMC is always a level
of the table and never unsafe, and the estimator never calls a non-finite force OK.

Derandomized (the same examples every run), so that CI cannot flake; the example counts keep
the file to a few seconds.
"""

from __future__ import annotations

import math

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from turning_force.core.estimation.estimator import ForceEstimator
from turning_force.core.estimation.settings import EstimateStatus, EstimatorSettings
from turning_force.core.plant.drive import CurrentBlock
from turning_force.core.pmc.gate import OverrideGate
from turning_force.core.pmc.overrides import TABLES
from turning_force.core.pmc.settings import BridgeSettings, Reason

PROPERTY = settings(derandomize=True, max_examples=300, deadline=None,
                    suppress_health_check=[HealthCheck.too_slow])

ANY_FLOAT = st.floats(allow_nan=True, allow_infinity=True)
PMC_TABLES = [name for name, table in TABLES.items() if not table.continuous]


@PROPERTY
@given(table_name=st.sampled_from(sorted(TABLES)), request=ANY_FLOAT)
def test_the_quantiser_gives_a_level_or_refuses(table_name, request):
    table = TABLES[table_name]
    if not math.isfinite(request):
        try:
            table.quantise(request)
        except ValueError:
            return
        raise AssertionError(f'{request!r} was quantised')
    level = table.quantise(request)
    assert table.min_pct <= level <= table.max_pct
    if not table.continuous:
        assert level in table.levels_pct
        # The bits encode it and decode back to it.
        _, bits = table.encode(level)
        assert table.decode(bits) == level
        # Nearest: no level is closer to the (clipped) request.
        clipped = min(max(request, table.min_pct), table.max_pct)
        assert all(abs(clipped - level) <= abs(clipped - other) + 1e-12
                   for other in table.levels_pct)


# One step of the gate's world: a command, a force estimate, time moving on, or the operator.
STEPS = st.one_of(
    st.tuples(st.just('command'), ANY_FLOAT),
    st.tuples(st.just('estimate'), ANY_FLOAT, st.sampled_from(list(EstimateStatus))),
    st.tuples(st.just('time'), st.floats(min_value=0.0, max_value=1.0)),
    st.tuples(st.just('arm')),
    st.tuples(st.just('disarm')),
)


@PROPERTY
@given(table_name=st.sampled_from(PMC_TABLES), steps=st.lists(STEPS, max_size=40),
       safe_pct=st.sampled_from([0.0, 30.0, 50.0]), limit_n=st.floats(100.0, 4000.0))
def test_the_gate_writes_only_levels_and_nothing_unsafe(table_name, steps, safe_pct, limit_n):
    # Whatever arrives in whatever order, every decision is a level of the table, with its
    # bits; a hold is 0 %; above the force limit (or unreadable) the feed is held; a request
    # that is not a valid command never gets through as NORMAL; and NORMAL applies exactly
    # the quantised request.
    table = TABLES[table_name]
    gate = OverrideGate(BridgeSettings(override_table=table_name, armed=True,
                                       safe_override_pct=safe_pct, overload_force_n=limit_n),
                        t_s=0.0)
    t, last_request, over = 0.0, math.nan, False
    last_over = False   # whether the last judged estimate was over the limit or unreadable
    for step in steps:
        kind = step[0]
        if kind == 'command':
            last_request = step[1]
            gate.on_command(step[1], t)
        elif kind == 'estimate':
            gate.on_estimate(step[1], step[2])
            if step[2] in (EstimateStatus.OK, EstimateStatus.SATURATED):
                last_over = step[2] == EstimateStatus.SATURATED or not (
                    math.isfinite(step[1]) and step[1] <= limit_n)
                over = over or last_over
        elif kind == 'time':
            t += step[1]
        elif kind == 'arm':
            # Re-arming clears the hold only with the last force back under the limit.
            gate.arm(t)
            over = last_over
        else:
            gate.disarm()
        d = gate.answer(t)
        assert d.applied_pct in table.levels_pct
        assert table.encode(d.applied_pct) == (d.code, d.bits)
        if over:
            assert d.reason == Reason.OVERLOAD_HOLD and d.applied_pct == 0.0
        if d.reason == Reason.NORMAL:
            assert math.isfinite(last_request)
            assert table.min_pct <= last_request <= table.max_pct
            assert d.applied_pct == table.quantise(last_request)
        if d.reason in (Reason.WATCHDOG, Reason.INVALID_COMMAND) and d.applied_pct != 100.0:
            assert d.applied_pct == table.quantise(safe_pct) < 100.0


SAMPLES = st.floats(allow_nan=True, allow_infinity=True, width=64)


@PROPERTY
@given(blocks=st.lists(st.tuples(
    st.one_of(st.floats(-1e12, 1e12), st.sampled_from([math.nan, math.inf])),   # t0 [s]
    st.sampled_from([1e-3, 1e-3, 1e-3, 0.0, -1e-3, math.nan, 2e-3]),
    st.lists(SAMPLES, min_size=0, max_size=12),
    st.lists(st.floats(-40.0, 40.0), min_size=10, max_size=10),
), min_size=1, max_size=12), force_filter=st.sampled_from(['kalman', 'lowpass']))
def test_the_estimator_never_calls_a_non_finite_force_ok(blocks, force_filter):
    # Any block (non-finite or absurd samples, mismatched lengths, any stamp and period) gives
    # an estimate whose force and rate are finite; a non-finite one would be a status that
    # says so, and none is.
    estimator = ForceEstimator(EstimatorSettings(force_filter=force_filter))
    for t0, period, wild, sane in blocks:
        n = 10
        u = np.array((wild + sane)[:n] if len(wild) < n else wild[:n], dtype=float)
        v = np.array(sane, dtype=float)
        block = CurrentBlock(t0, period, u, v, np.zeros(n), np.full(n, 120.0))
        estimate = estimator.update(block)
        assert math.isfinite(estimate.force_n) and math.isfinite(estimate.force_rate_n_s)
        if estimate.status in (EstimateStatus.OK, EstimateStatus.SATURATED):
            assert np.all(np.isfinite(u)) and np.all(np.isfinite(v))
