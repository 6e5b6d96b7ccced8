"""Per-tool settings through the node graph (issue 16, item 5): the two-tool program on the
simulator (lathe_sim publishes the tool on machine/tool; force_controller and pmc_bridge each
take their section of the tools file) decides block by block what the compiled core loop
decides, each cut on its own tool's reference, and the recorded cut log and the report say which
tool made each cut."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from turning_force.commands.run import run_lockstep
from turning_force.core.experiment import parse_experiment
from turning_force.core.kernel.batch import run_core
from turning_force.session.reader import read_session, recorded_metrics
from turning_force.session.replay import replay
from turning_force.session.report import cut_table, write_html_report

ROOT = Path(__file__).resolve().parents[2]
TWO_TOOLS = ROOT / 'config' / 'experiments' / 'two_tools.yaml'
TOOLS = ROOT / 'config' / 'tools' / 'two_tools.yaml'


@pytest.fixture(scope='module')
def two_tools(tmp_path_factory):
    text = TWO_TOOLS.read_text().replace('config/tools/two_tools.yaml', str(TOOLS))
    experiment = parse_experiment(text, str(TWO_TOOLS))
    bag = tmp_path_factory.mktemp('two_tools') / 'session'
    run_lockstep(experiment, bag)
    return experiment, read_session(bag)


def test_the_graph_switches_tools_as_the_core_loop_block_by_block(two_tools):
    experiment, session = two_tools
    core = run_core(experiment)
    s = session.signals
    np.testing.assert_array_equal(s['answered_override_pct'], core.chain.applied_pct)
    np.testing.assert_array_equal(s['override_reason'], core.chain.reason)
    # The commands' references are each tool's, where the controller acted, on both sides.
    acted = np.isfinite(core.chain.reference_n)
    np.testing.assert_array_equal(s['reference_n'][acted], core.chain.reference_n[acted])
    assert set(core.chain.reference_n[acted]) == {500.0, 300.0}


def test_the_recorded_cut_log_and_the_report_say_which_tool_cut(two_tools, tmp_path):
    experiment, session = two_tools
    core = run_core(experiment)
    assert [c.tool for c in session.cuts] == [c.tool for c in core.cuts] == ['T1', 'T2']
    for recorded, expected in zip(session.cuts, core.cuts, strict=True):
        assert recorded.start_s == pytest.approx(expected.start_s, abs=1e-9)
        assert recorded.mean_force_n == expected.mean_force_n
    assert [c.tool for c in cut_table(session)] == ['T1', 'T2']
    page = write_html_report(session, recorded_metrics(session),
                             tmp_path / 'report.html').read_text()
    table = page[page.index('<h2>Cut log</h2>'):]
    assert '>T1</td>' in table and '>T2</td>' in table


def test_replay_takes_the_recorded_tool(two_tools):
    # FeedOverride records the tool each decision saw: replay switches where the run did.
    _, session = two_tools
    ends = session.t_s
    assert [session.inputs(k).tool_number for k in (10, len(ends) - 10)] == [1, 2]
    result = replay(session)
    assert result.differing_overrides == 0 and result.differing_reasons == 0
