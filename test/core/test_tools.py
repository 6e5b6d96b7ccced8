"""Per-tool settings (issue 16, item 5): the machine's tool input selects its section of the
tools file (core/tools.py) in the compiled core loop, as the per-block chain does; two tools
with different materials in one program each cut on their own settings and the cut log says
which; a tool without a section is refused at configure and handed back when it appears while
running; the sections are validated as the nodes validate their own settings."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

from turning_force.core.control import ControllerSettings, drift, make_controller
from turning_force.core.control.predictor import model_matrices
from turning_force.core.errors import ConfigError
from turning_force.core.experiment import load_experiment, parse_experiment
from turning_force.core.kernel.batch import InputArrays, replay_chain, run_core
from turning_force.core.kernel.chain import ControlChain
from turning_force.core.kernel.simulate import simulate
from turning_force.core.pmc.gate import cut_record
from turning_force.core.pmc.settings import Reason
from turning_force.core.pmc.shopfloor import InputValues
from turning_force.core.tools import load_tools_file, save_tool_section

ROOT = Path(__file__).resolve().parents[2]
TWO_TOOLS = ROOT / 'config' / 'experiments' / 'two_tools.yaml'
TOOLS = ROOT / 'config' / 'tools' / 'two_tools.yaml'
BAND_N = 25.0   # the experiment's allowed_error_n: 5 % of T1's reference (Park Sec. 2.3)


def two_tools(tools_file: Path = TOOLS, *sets: str):
    """The two-tool program with ``tools_file`` (absolute: the tests run from anywhere)."""
    text = TWO_TOOLS.read_text().replace('config/tools/two_tools.yaml', str(tools_file))
    return parse_experiment(text, str(TWO_TOOLS)).with_sets(list(sets))


def cut_means(result, experiment):
    """Per cut of the cut log: its tool, the reference in force and the true force's mean in
    its steady part (1.5 s after the entry, which the entry feed and the SMC's reaching phase
    take, to 0.2 s before the exit)."""
    t = result.trace
    out = []
    for row in result.cut_rows:
        cut = cut_record(row, experiment.bridge.tool)
        steady = (t['t_s'] > cut.start_s + 1.5) & (t['t_s'] < cut.end_s - 0.2)
        out.append((cut.tool, float(np.mean(t['reference_n'][steady])),
                    float(np.mean(t['force_n'][steady]))))
    return out


def test_two_tools_each_cut_on_their_own_settings_in_the_core_loop():
    e = two_tools()
    run = run_core(e)   # simulate's result, bit for bit, and the chain's decisions
    cuts = cut_means(run.result, e)
    # The cut log says which tool made each cut (the tool input while it cut).
    assert [tool for tool, _, _ in cuts] == ['T1', 'T2']
    # Each regulated to its own section's reference, inside the band: T1's 500 N in steel,
    # T2's 300 N in cast iron (another k and exponent g; its own SMC bounds).
    (_, ref1, force1), (_, ref2, force2) = cuts
    assert (ref1, ref2) == (500.0, 300.0)
    assert abs(force1 - 500.0) < BAND_N and abs(force2 - 300.0) < BAND_N
    # The entry level is the tool's: 30 % for T1's entry, 40 % for T2's (the air-cut override
    # holds the request down until the force is established).
    air, t = run.chain.reason == Reason.AIR_CUT, run.currents.t_end_s
    assert set(run.chain.applied_pct[air & (t < 5.5)]) == {30.0}
    assert set(run.chain.applied_pct[air & (t > 5.5)]) == {40.0}


def test_without_the_tools_file_the_second_tool_cuts_on_the_first_ones_settings():
    # The counterfactual: the same program with one set of settings regulates T2's cut to
    # 500 N, not its 300; the tools file is what made the difference above.
    e = two_tools(TOOLS, "/**.tools_file=''", 'force_controller.smc_ksd_min_n_mm=2900.0',
                  'force_controller.smc_ksd_max_n_mm=4840.0')
    cuts = cut_means(simulate(e), e)
    assert [ref for _, ref, _ in cuts] == [500.0, 500.0]
    assert cuts[1][2] > 400.0


def test_the_compiled_loop_switches_as_the_per_block_chain_does():
    # run_core (the compiled loop, run --core) against ControlChain block by block (as the
    # nodes run it): the same decisions and the same cut log, tool change included.
    e = two_tools()
    run = run_core(e)
    chain = ControlChain(e.estimator, e.controller, e.bridge)
    from turning_force.core.plant.lathe import LathePlant

    applied = e.plant.approach_override_pct
    plant = LathePlant(e.plant, initial_override_pct=applied)
    decided = []
    for _ in range(len(run.chain)):
        block = plant.step(applied)
        applied = chain.step(block.currents, inputs=block.inputs).decision.applied_pct
        decided.append(applied)
    np.testing.assert_array_equal(run.chain.applied_pct, decided)
    assert [c.tool for c in chain.close()] == [c.tool for c in run.cuts] == ['T1', 'T2']


def test_a_tool_without_a_section_is_refused_at_configure(tmp_path):
    with pytest.raises(ConfigError, match=r'tool 3 has no section in the tools file .*two_tools'
                                          r'\.yaml \(sections: \[1, 2\]\).*identify --tool'):
        two_tools(TOOLS, 'lathe_sim.tool_numbers=[1, 3]')


def test_a_tool_without_a_section_while_running_hands_the_feed_back():
    # The compiled replay over a recorded run whose tool input says 7 from 5.5 s on: no
    # section, so never T1's or T2's settings: the feed goes back (at most hand_back_pct) with
    # the reason, the alarm output set, until a tool with a section comes (T2 from 8 s).
    e = two_tools()
    run = run_core(e)
    ends = run.currents.t_end_s
    tools = np.where(ends < 5.5, 1.0, np.where(ends < 8.0, 7.0, 2.0))
    inputs = InputArrays(np.ones(ends.size, dtype=np.bool_), np.full(ends.size, -1, np.int8),
                         np.full(ends.size, -1, np.int8), np.full(ends.size, np.nan),
                         tool_number=tools)
    trace = replay_chain(e, run.currents, [(0.0, True)], inputs)
    unknown = tools == 7.0
    assert set(trace.reason[unknown]) == {Reason.OPERATOR}
    assert set(trace.applied_pct[unknown]) == {e.bridge.hand_back_pct}
    assert trace.alarm[unknown].all() and not trace.alarm[~unknown].any()
    assert Reason.NORMAL in set(trace.reason[ends > 9.0])
    # The per-block chain says why, in words.
    chain = ControlChain(e.estimator, e.controller, e.bridge, t_s=0.0)
    chain.gate.on_inputs(InputValues(tool_number=7))
    detail = chain.gate.decide(0.01).detail
    assert 'tool 7 has no section in the tools file' in detail and 'handed back' in detail


@pytest.mark.parametrize(('section', 'message'), [
    ({'force_controller': {'control_period_s': 0.02}},
     r'tools\.2\.force_controller\.control_period_s = 0\.02: not a per-tool setting'),
    ({'force_controller': {'controller': 'mpc'}},
     r"tools\.2\.force_controller\.controller = 'mpc': the law is the machine's, one for "
     r"every tool \(force_controller\.controller = 'smc'\)"),
    ({'pmc_bridge': {'cut_settle_s': 0.5}},
     r'tools\.2\.pmc_bridge\.cut_settle_s = 0\.5: not a per-tool setting \(per tool: '
     r'air_cut_override_pct'),
    ({'force_controller': {'reference_force_n': -5.0}},
     r'tools\.2\.force_controller: force_controller\.reference_force_n = -5\.0: outside'),
    ({'force_controller': {'reference_force_n': 1500.0},
      'pmc_bridge': {'overload_force_n': 1200.0}},
     r'tools\.2: reference_force_n 1500\.0 N not below overload_force_n 1200\.0 N'),
    ({'spindle': {}}, r'tools\.2 = .*expected a mapping with force_controller and/or pmc_bridge'),
])
def test_a_section_is_validated_as_the_nodes_validate_their_settings(tmp_path, section,
                                                                       message):
    path = tmp_path / 'tools.yaml'
    data = yaml.safe_load(TOOLS.read_text())
    data['tools'][2] = section
    path.write_text(yaml.safe_dump(data))
    with pytest.raises(ConfigError, match=message):
        two_tools(path)


def regulate(law, periods: int = 800) -> np.ndarray:
    """The levels ``law`` sends on a noise-free plant of 9.68 N/% through a 0.4 s dead time,
    the first-order 0.17 s servo and the 0.05 s process lag (test_mpc's plant)."""
    phi, gamma = model_matrices('first_order', 0.17, 60.0, 0.7, 0.05, step_s=0.01)
    x, queue, levels = np.array([50.0, 50.0]), [50.0] * 40, np.empty(periods)
    for k in range(periods):
        levels[k] = law.update(9.68 * float(x[-1]), 0.0).override_pct
        queue.append(levels[k])
        x = phi @ x + gamma * queue.pop(0)
    return levels


@pytest.mark.parametrize('law', ['mpc', 'smc'])
def test_a_tool_with_a_longer_dead_time_than_the_machines_runs_as_if_it_were_the_machines(
        tmp_path, law):
    # The dead time's queue lives in the law's state: a tool's section that lengthens it
    # (0 s for the machine, 0.4 s for tool 2) must find room for it, or the compiled law
    # writes past its state (it did: a segmentation fault, or the heap corrupted). With room,
    # tool 2 regulates exactly as a controller commissioned at 0.4 s for every tool does.
    path = tmp_path / 'tools.yaml'
    path.write_text(yaml.safe_dump({'tools': {2: {'force_controller': {
        'model_dead_time_s': 0.4}}}}))
    base = ControllerSettings(controller=law, initial_override_pct=50.0, quantiser='nearest',
                              smc_predictor=True, reference_force_n=500.0)
    tooled = make_controller(base.replace(tools_file=str(path)))
    assert tooled.select_tool(2)
    direct = make_controller(base.replace(model_dead_time_s=0.4))
    np.testing.assert_array_equal(regulate(tooled), regulate(direct))


def test_a_live_change_that_needs_a_longer_queue_is_refused(tmp_path):
    law = make_controller(ControllerSettings(controller='mpc'))
    longer = law.settings.replace(model_dead_time_s=0.4)
    with pytest.raises(ConfigError, match=r'mpc: the new settings need a larger state .*'
                                          r'model_dead_time_s.*restart the node'):
        law.retune(longer)
    assert law.settings.model_dead_time_s == 0.0   # nothing of it taken


def test_the_drift_alarm_speaks_of_the_tools_model(tmp_path):
    # The drift text and the adopted model's text read the settings the law runs on: the
    # tool's section where the tool input selected one (tool 2's 100 ms dead time, not the
    # machine's 0 ms), the machine's before a tool input and for a tool without a section.
    path = tmp_path / 'tools.yaml'
    path.write_text(yaml.safe_dump({'tools': {2: {'force_controller': {
        'model_dead_time_s': 0.1}}}}))
    law = make_controller(ControllerSettings(controller='mpc', tools_file=str(path)))
    assert law.in_use.model_dead_time_s == 0.0
    assert law.select_tool(2)
    text = drift.drift_text(law.in_use, drift.DEAD_TIME, 0.05, 0.005, adopted=(drift.DEAD_TIME,
                                                                                0.05))
    assert 'identified 100 ms, now 150 +- 5 ms' in text and 'predicts with 150 ms' in text
    assert not law.select_tool(7)
    assert law.in_use.model_dead_time_s == 0.0


def test_a_missing_tools_file_is_refused_naming_it(tmp_path):
    with pytest.raises(ConfigError, match=r'nowhere\.yaml: cannot read tools file'):
        two_tools(tmp_path / 'nowhere.yaml')


def test_writing_one_tools_section_keeps_the_others(tmp_path):
    path = tmp_path / 'tools.yaml'
    path.write_text(TOOLS.read_text())
    save_tool_section(path, 2, {'force_controller': {'reference_force_n': 280.0}}, 'from a test')
    save_tool_section(path, 5, {'force_controller': {'smc_ksd_min_n_mm': 1000.0}})
    tools = load_tools_file(path)
    assert sorted(tools) == [1, 2, 5]
    assert tools[1] == load_tools_file(TOOLS)[1]
    assert tools[2] == {'force_controller': {'reference_force_n': 280.0}}
    assert tools[5]['force_controller']['smc_ksd_min_n_mm'] == 1000.0


def test_the_shipped_experiment_loads_from_the_repository_root(monkeypatch):
    monkeypatch.chdir(ROOT)
    assert load_experiment(TWO_TOOLS).controller.tools_file == 'config/tools/two_tools.yaml'
