"""The shop-floor behaviours through the node graph: a part program on the simulator (air cut,
program enable, rise limit, the operator's dial, threading) decides block by block what the core
loop decides, records the inputs it saw and its cut log, replays exactly, and reports its cuts;
a learning cut's reference reaches the next session through the teach-in file."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest
import yaml

from turning_force.commands.run import run_lockstep
from turning_force.core.experiment import load_experiment
from turning_force.core.kernel.chain import ControlChain
from turning_force.core.plant.lathe import LathePlant
from turning_force.core.pmc.settings import Reason
from turning_force.session.reader import read_session, recorded_metrics
from turning_force.session.replay import replay
from turning_force.session.report import cut_table, write_html_report, write_report

EXPERIMENTS = Path(__file__).resolve().parents[2] / 'config' / 'experiments'


def core_run(experiment):
    """The core loop block by block: the decisions, the inputs each saw, the cut log."""
    plant = LathePlant(experiment.plant)
    chain = ControlChain(experiment.estimator, experiment.controller, experiment.bridge)
    applied, decisions, inputs, references = 100.0, [], [], []
    for _ in range(round(experiment.run.duration_s / experiment.run.control_period_s)):
        references.append(chain.controller.settings.reference_force_n)   # this block's
        b = plant.step(applied)
        step = chain.step(b.currents, inputs=b.inputs)
        decisions.append(step.decision)
        inputs.append(b.inputs)
        applied = step.decision.applied_pct
    return decisions, inputs, chain.close(), references


@pytest.fixture(scope='module')
def shopfloor(tmp_path_factory):
    experiment = load_experiment(EXPERIMENTS / 'shopfloor.yaml')
    bag = tmp_path_factory.mktemp('shopfloor') / 'session'
    run_lockstep(experiment, bag)
    return experiment, read_session(bag)


def test_the_graph_decides_as_the_core_loop_block_by_block(shopfloor):
    experiment, session = shopfloor
    decisions, inputs, _, _ = core_run(experiment)
    s = session.signals
    np.testing.assert_array_equal(s['answered_override_pct'],
                                  [d.applied_pct for d in decisions])
    np.testing.assert_array_equal(s['override_reason'], [int(d.reason) for d in decisions])
    np.testing.assert_array_equal(s['engaged'], [float(d.engaged) for d in decisions])
    # Every behaviour of the program showed up, on both sides.
    seen = {Reason(int(r)) for r in s['override_reason']}
    assert {Reason.AIR_CUT, Reason.RISE_LIMIT, Reason.OPERATOR, Reason.NORMAL} <= seen
    # The inputs the bridge recorded are the simulated machine's, block by block (FeedOverride
    # records the bridge's inputs: the spindle speed has a topic of its own).
    assert [session.inputs(k) for k in range(len(inputs))] == [
        dataclasses.replace(i, spindle_speed_rpm=None) for i in inputs]


def test_the_recorded_cut_log_is_the_core_loops(shopfloor):
    experiment, session = shopfloor
    _, _, core_cuts, _ = core_run(experiment)
    assert len(session.cuts) == len(core_cuts) == 2
    for recorded, core in zip(session.cuts, core_cuts, strict=True):
        # Times come through the bridge's clock (integer nanoseconds): equal to 1 ns.
        assert recorded.start_s == pytest.approx(core.start_s, abs=1e-9)
        assert recorded.end_s == pytest.approx(core.end_s, abs=1e-9)
        assert (recorded.programmed_feed_s, recorded.max_force_n, recorded.min_override_pct,
                recorded.overload_events, recorded.reachable_fraction) == (
            core.programmed_feed_s, core.max_force_n, core.min_override_pct,
            core.overload_events, core.reachable_fraction)
        assert recorded.tool == 'T0101' and recorded.complete


def test_replay_reproduces_decisions_that_depended_on_the_inputs(shopfloor):
    _, session = shopfloor
    result = replay(session)
    assert result.differing_overrides == 0 and result.differing_reasons == 0
    # Without the recorded inputs (a machine that wires none) the decisions differ: the
    # program's enable, the dial and the threading span are what made them.
    without = replay(session, ['pmc_bridge.program_enable_required=false',
                               'pmc_bridge.operator_dial=ignore',
                               'pmc_bridge.threading_stand_down=false'])
    assert without.differing_overrides > 50


def test_the_report_shows_the_cut_log(shopfloor, tmp_path):
    _, session = shopfloor
    assert cut_table(session) == session.cuts
    metrics = recorded_metrics(session)
    page = write_html_report(session, metrics, tmp_path / 'report.html').read_text()
    assert '<h2>Cut log</h2>' in page and page.count('<tr>') >= 2 + 1
    turning = session.cuts[0]
    assert f'{turning.duration_s:.2f}' in page and f'{turning.programmed_feed_s:.2f}' in page
    assert write_report(session, metrics, tmp_path / 'report.png').stat().st_size > 50_000


def test_a_session_ending_in_the_cut_reports_it_open(tmp_path):
    # Fig. 8 cuts to the end: the recording closes before the bridge does, so the open cut is
    # taken from the recorded blocks.
    experiment = load_experiment(EXPERIMENTS / 'park1998_fig8.yaml').with_sets(
        ['experiment.duration_s=1.0'])
    bag = tmp_path / 'fig8'
    run_lockstep(experiment, bag)
    session = read_session(bag)
    [cut] = cut_table(session)
    assert not cut.complete and session.cuts == []
    assert cut.start_s == pytest.approx(0.0, abs=0.02)   # the tool enters at 0 s
    assert cut.end_s == pytest.approx(1.0)


def test_teach_in_learns_in_one_session_and_the_next_session_cuts_to_it(tmp_path):
    # Session 1: a learning cut for T0101 (1 mm at the programmed feed: 440 N), then a cut
    # regulated at 0.9 of it. Session 2 starts from the file, regulating both cuts there.
    teach = tmp_path / 'teach.yaml'
    sets = ['experiment.duration_s=6.0', 'lathe_sim.depth_times_s=[0.0, 0.5, 3.0, 3.5]',
            'lathe_sim.depth_mm=[0.0, 1.0, 0.0, 1.0]', 'pmc_bridge.tool=T0101',
            f'pmc_bridge.teach_file={teach}']
    base = load_experiment(EXPERIMENTS / 'park1998_fig8.yaml')
    learning = base.with_sets([*sets, 'pmc_bridge.teach_in=true'])
    run_lockstep(learning, tmp_path / 'learn')
    taught = yaml.safe_load(teach.read_text())['tools']['T0101']
    assert taught['learned_force_n'] == pytest.approx(440.0, rel=0.01)
    reference = taught['reference_force_n']
    assert reference == pytest.approx(0.9 * taught['learned_force_n'])
    first = read_session(tmp_path / 'learn')
    assert Reason.TEACH_IN in set(first.signals['override_reason'].astype(int))
    assert first.cuts[0].learned
    # The graph's controller took the learned reference when the core loop's did.
    _, _, _, core_references = core_run(learning)
    np.testing.assert_array_equal(first.signals['reference_n'], core_references)
    assert replay(first).differing_overrides == 0

    run_lockstep(base.with_sets(sets), tmp_path / 'cut')
    second = read_session(tmp_path / 'cut')
    assert np.all(second.signals['reference_n'] == reference)
    late = second.t_s > 2.0
    assert np.mean(second.signals['force_n'][late & (second.t_s < 3.0)]) == pytest.approx(
        reference, abs=10.0)
    # Replay starts from the reference the session ran with, whatever the file says today.
    teach.write_text(teach.read_text().replace(f'reference_force_n: {reference}',
                                               'reference_force_n: 250.0'))
    assert replay(second).differing_overrides == 0
