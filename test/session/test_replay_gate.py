"""Replay reproduces every recorded session exactly, the PMC gate's decisions included: a
session where the gate held the feed (overload), one where the bridge stayed disarmed (an air
cut), one where the watchdog tripped (the current sensor failed for a while), and one where the
tool-breakage detector held it."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from turning_force.commands.run import run_lockstep
from turning_force.core.experiment import load_experiment
from turning_force.core.pmc.settings import Reason
from turning_force.session.reader import read_session
from turning_force.session.replay import replay

EXPERIMENTS = Path(__file__).resolve().parents[2] / 'config' / 'experiments'

CASES = {
    # Fig. 8 with a 700 N limit: the first depth step (4 s) passes it and the feed is held.
    'held': ('park1998_fig8.yaml', ['pmc_bridge.overload_force_n=700.0',
                                    'experiment.duration_s=5.0'], Reason.OVERLOAD_HOLD),
    # The air cut: disarmed, the programmed feed throughout (replay refused it before).
    'disarmed': ('air_cut.yaml', ['experiment.duration_s=1.0'], Reason.DISARMED),
    # The sensor reads NaN for 0.3 s: no command, the watchdog holds the feed.
    'watchdog': ('park1998_fig8.yaml', ['lathe_sim.sensor_fault_start_s=1.0',
                                        'lathe_sim.sensor_fault_duration_s=0.3',
                                        'experiment.duration_s=2.0'], Reason.WATCHDOG),
    # The insert breaks at 3 s (the depth jumps to 3 mm at once): the breakage detector holds.
    'breakage': ('park1998_fig8.yaml', ['experiment.duration_s=3.5',
                                        'lathe_sim.depth_times_s=[0.0, 3.0]',
                                        'lathe_sim.depth_mm=[1.0, 3.0]',
                                        'lathe_sim.cutting_time_constant_s=0.0',
                                        'pmc_bridge.breakage_spike_fraction=1.0'],
                 Reason.TOOL_BREAKAGE),
}


@pytest.fixture(scope='module', params=sorted(CASES))
def recorded(request, tmp_path_factory):
    name, sets, reason = CASES[request.param]
    experiment = load_experiment(EXPERIMENTS / name).with_sets(sets)
    bag = tmp_path_factory.mktemp(request.param) / 'session'
    run_lockstep(experiment, bag)
    return read_session(bag), reason


def test_replay_reproduces_the_gates_decisions(recorded):
    session, reason = recorded
    recorded_reasons = session.signals['override_reason']
    # The session shows the case it is meant to: the gate's reason is there, and every block
    # has an answer (the bridge answers a block the controller is silent on).
    assert np.count_nonzero(recorded_reasons == int(reason)) >= 5
    assert np.all(np.isfinite(session.signals['answered_override_pct']))
    result = replay(session)
    assert result.differing_overrides == 0
    assert result.differing_reasons == 0
    np.testing.assert_array_equal(result.answered_override_pct,
                                  session.signals['answered_override_pct'])
    assert result.max_force_difference_n == 0.0


def test_replay_with_new_settings_changes_the_gates_decisions(recorded):
    # The replay is not a copy of the recording: a different limit or safe override gives
    # different decisions where the gate acted.
    session, reason = recorded
    if reason == Reason.DISARMED:
        result = replay(session, ['pmc_bridge.armed=true', 'experiment.arm_bridge=true'])
        assert np.all(result.reasons != int(Reason.DISARMED))
    elif reason == Reason.OVERLOAD_HOLD:
        result = replay(session, ['pmc_bridge.overload_force_n=1500.0'])
        assert int(Reason.OVERLOAD_HOLD) not in result.reasons
    elif reason == Reason.TOOL_BREAKAGE:
        result = replay(session, ['pmc_bridge.breakage_spike_fraction=0.0'])
        assert int(Reason.TOOL_BREAKAGE) not in result.reasons
    else:
        result = replay(session, ['pmc_bridge.safe_override_pct=50.0'])
        watchdog = result.reasons == int(Reason.WATCHDOG)
        assert np.all(result.answered_override_pct[watchdog] == 50.0)
    assert result.differing_overrides > 0


def test_the_graph_runs_the_predictor_and_the_quantiser_as_the_core_loop(tmp_path):
    # The regulation the product ships (Smith predictor on an 80 ms dead time, error-feedback
    # quantiser, automatic boundary layer) through the node graph: the controller node's law
    # keeps its model of the levels it sent, as the core loop's does, so both give the same
    # metrics (1e-9 relative: summation order only), and replay reproduces the session.
    from turning_force.commands.robustness import MATRIX, scenario_experiment
    from turning_force.core.kernel.simulate import simulate
    from turning_force.session.reader import recorded_metrics

    scenario = next(s for s in MATRIX if s.name == 'dead time 80 ms')
    experiment = scenario_experiment(EXPERIMENTS, scenario, 'smc').with_sets(
        ['experiment.duration_s=6.0'])
    assert experiment.controller.model_dead_time_s == pytest.approx(0.08, abs=0.01)  # identified
    run_lockstep(experiment, tmp_path / 'session')
    session = read_session(tmp_path / 'session')
    graph, core = recorded_metrics(session), simulate(experiment).metrics
    for name, value in graph.items():
        assert value == pytest.approx(core[name], rel=1e-9, abs=1e-12), name
    result = replay(session)
    assert result.differing_overrides == 0 and result.max_request_difference_pct == 0.0


def test_an_unreachable_reference_is_recorded_and_drawn(tmp_path):
    # K_s x 0.7 at 1 mm: 150 % gives 462 N < 500 N. The controller's flag goes into the
    # session (FeedCommand.reference_reachable), the metrics leave that span out and say how
    # much, and the report shades it.
    from turning_force.session.reader import recorded_metrics
    from turning_force.session.report import _spans, write_report

    experiment = load_experiment(EXPERIMENTS / 'park1998_fig8.yaml').with_sets([
        'lathe_sim.specific_cutting_force_n_mm2=1540.0', 'experiment.duration_s=5.0',
        'force_controller.quantiser=error_feedback'])
    run_lockstep(experiment, tmp_path / 'session')
    session = read_session(tmp_path / 'session')
    out_of_reach = session.signals['reference_reachable'] == 0.0
    spans = _spans(out_of_reach)
    assert len(spans) == 1
    first, last = spans[0]
    assert 1.0 <= session.t_s[first] <= 2.0 and 3.99 <= session.t_s[last] <= 4.05
    metrics = recorded_metrics(session)
    assert metrics['reachable_fraction'] == pytest.approx(1.0 - out_of_reach.mean(), abs=1e-9)
    assert write_report(session, metrics, tmp_path / 'report.png').stat().st_size > 10_000
