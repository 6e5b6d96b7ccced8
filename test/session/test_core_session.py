"""``run --core --out``: the core loop's session against the lock-step graph's, for one experiment
file: the same signals read back (estimates, requests, overrides, reasons: equal), the same
messages on every topic but /diagnostics (which only nodes publish), the cut log among them,
and both read by the mcap library's own ROS 2 decoder, reported and replayed."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from turning_force.cli import main
from turning_force.commands.core_session import NOT_RECORDED, RECORDER, TOPICS, record_core
from turning_force.commands.run import run_lockstep
from turning_force.core.experiment import load_experiment
from turning_force.core.kernel.simulate import simulate
from turning_force.nodes.session_recorder import GRAPH_TOPICS, msgtype
from turning_force.session.bag import CUSTOM_EXPERIMENT, CUSTOM_PARAMETERS
from turning_force.session.reader import read_session, recorded_metrics

# Three seconds of fig8: the first depth, settled, and the tool out of the cut from 2 s (a cut
# that ends: the cut log).
SETS = ['experiment.duration_s=3.0', 'lathe_sim.depth_times_s=[0.0, 2.0]',
        'lathe_sim.depth_mm=[1.0, 0.0]']
BLOCKS = 300


@pytest.fixture(scope='module')
def sessions(tmp_path_factory, fig8):
    experiment = load_experiment(fig8).with_sets(SETS)
    folder = tmp_path_factory.mktemp('core_session')
    graph = run_lockstep(experiment, folder / 'graph')
    core = record_core(experiment, folder / 'core')
    return graph.bag, core.bag


def decoded(bag):
    """Every message as the mcap library decodes it: (topic, log time, message), by topic."""
    out: dict[str, list[tuple[int, str]]] = {}
    with next(bag.glob('*.mcap')).open('rb') as stream:
        reader = make_reader(stream, validate_crcs=True, decoder_factories=[DecoderFactory()])
        for _, channel, message, value in reader.iter_decoded_messages(log_time_order=False):
            out.setdefault(channel.topic, []).append((message.log_time, repr(value)))
    return out


def test_the_core_session_has_the_graphs_topics():
    assert {f'/{t.lstrip("/")}': msgtype(c) for t, c in GRAPH_TOPICS.items()} == TOPICS


def test_both_read_back_to_the_same_signals(sessions):
    graph, core = (read_session(bag) for bag in sessions)
    assert graph.signals.keys() == core.signals.keys()
    for name, values in graph.signals.items():
        np.testing.assert_array_equal(core.signals[name], values, err_msg=name)
    for name in ('t0_s', 'phase_u_a', 'phase_v_a', 'rotor_angle_rad', 'feed_rate_mm_min'):
        np.testing.assert_array_equal(getattr(core.currents, name),
                                      getattr(graph.currents, name), err_msg=name)
    np.testing.assert_array_equal(core.t_s, graph.t_s)
    np.testing.assert_array_equal(core.answer_stamps_ns, graph.answer_stamps_ns)
    assert core.arm_changes == graph.arm_changes
    assert core.cuts == graph.cuts and len(core.cuts) == 1
    assert core.cuts[0].complete and 2.0 <= core.cuts[0].end_s <= 2.15
    assert recorded_metrics(core) == recorded_metrics(graph)
    assert core.custom_data[CUSTOM_PARAMETERS] == graph.custom_data[CUSTOM_PARAMETERS]
    assert core.custom_data[CUSTOM_EXPERIMENT] == graph.custom_data[CUSTOM_EXPERIMENT]
    assert RECORDER in core.custom_data and RECORDER not in graph.custom_data
    # What differs: /diagnostics, published once a second by each of the graph's nodes; and
    # the bridge's timer may write an override of its own before the first command reaches it
    # (a race of the graph's start: WATCHDOG, stamped with no block's stamp).
    counts = {t: n for t, n in graph.message_counts.items() if t not in NOT_RECORDED}
    overrides = counts.pop('/pmc/feed_override')
    core_counts = {t: n for t, n in core.message_counts.items() if t not in NOT_RECORDED}
    assert core_counts.pop('/pmc/feed_override') == BLOCKS + 1 <= overrides   # + the configured
    assert counts == core_counts
    assert graph.message_counts['/diagnostics'] >= 5 * 2   # five nodes, once a second
    assert core.message_counts['/diagnostics'] == 0


def test_the_mcap_library_decodes_the_same_messages_at_the_same_times(sessions):
    graph, core = (decoded(bag) for bag in sessions)
    assert set(graph) - set(NOT_RECORDED) == set(core)
    first_block_end_ns = 10_000_000
    for topic, messages in core.items():
        if topic == '/pmc/feed_override':   # those answering blocks, and the configured one
            graph[topic] = [(t, m) for t, m in graph[topic]
                            if 'frame_id=z_axis' in m or 'DISARMED' in m or 'inactive' in m]
        if topic == '/session/settings':   # the same keys but the recorder's and the versions'
            assert len(messages) == len(graph[topic]) == 2
            continue
        assert [m for _, m in messages] == [m for _, m in graph[topic]], topic
        # Logged at the end of their block, as the recorder's sim clock says (the first
        # block's messages too, when they reach the graph's recorder before its first /clock).
        assert [t for t, _ in messages] == [t for t, _ in graph[topic]], topic
        assert messages[0][0] >= first_block_end_ns


@pytest.mark.parametrize('which', [0, 1], ids=['graph', 'core'])
def test_report_and_replay_work_on_both(sessions, which, tmp_path, capsys):
    bag = sessions[which]
    assert main(['report', str(bag), '--out', str(tmp_path / 'figure.png')]) == 0
    assert (tmp_path / 'figure.png').read_bytes()[:8] == b'\x89PNG\r\n\x1a\n'
    capsys.readouterr()
    assert main(['replay', str(bag), '--json']) == 0
    comparison = json.loads(capsys.readouterr().out)['comparison']
    assert comparison['differing_overrides'] == 0
    assert comparison['differing_reasons'] == 0
    assert comparison['max_force_difference_n'] == 0.0
    assert comparison['blocks'] == BLOCKS
    assert not math.isnan(comparison['max_request_difference_pct'])


def test_run_core_out_writes_a_session(fig8, tmp_path, capsys):
    bag = tmp_path / 'fig8'
    assert main(['run', str(fig8), '--core', '--out', str(bag), '--json', '--set',
                 SETS[0]]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out['session'] == str(bag)
    session = read_session(bag)
    assert len(session.blocks) == BLOCKS
    assert recorded_metrics(session)['mean_abs_error_n'] == pytest.approx(
        out['metrics']['mean_abs_error_n'], rel=1e-12)


def test_a_tapers_recorded_metrics_are_the_runs(fig8, tmp_path):
    # A taper's depth changes in every block of its ramp: read back, the ramp is the one change
    # the run measured from, not a change per block that leaves no steady sample (0 N).
    experiment = load_experiment(fig8).with_sets([
        'experiment.duration_s=3.0', 'lathe_sim.depth_times_s=[0.0, 3.0]',
        'lathe_sim.depth_mm=[1.0, 2.0]', 'lathe_sim.depth_interpolation=linear'])
    record_core(experiment, tmp_path / 'taper')
    recorded = recorded_metrics(read_session(tmp_path / 'taper'))
    run = simulate(experiment).metrics
    assert recorded['steady_mean_abs_error_n'] > 0.0
    for name in ('steady_mean_abs_error_n', 'ripple_p2p_n', 'mean_abs_error_n'):
        assert recorded[name] == pytest.approx(run[name], rel=1e-9), name
