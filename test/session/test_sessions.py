"""Sessions: the graph run in lock-step to MCAP, read back by rosbags and by the mcap reader,
equal to the core loop, replayed, drawn (what a killed recorder leaves: test_session_repair)."""

from __future__ import annotations

import json
import struct
from pathlib import Path

import numpy as np
import pytest
import yaml
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from rosbags.highlevel import AnyReader

from bagfaults import rewrite
from turning_force.commands.run import run_lockstep
from turning_force.core.experiment import load_experiment
from turning_force.core.kernel.simulate import simulate
from turning_force.session.bag import (
    CUSTOM_EXPERIMENT,
    CUSTOM_PARAMETERS,
    CUSTOM_VERSIONS,
    BagError,
    SessionWriter,
    typestore,
)
from turning_force.session.reader import read_session, recorded_metrics
from turning_force.session.replay import replay
from turning_force.session.report import write_report

# force/measured: a dynamometer's, recorded where one is fitted (none here: no messages).
TOPICS = {'/servo/currents', '/servo/joint_state', '/sim/cutting_state', '/force/estimate',
          '/control/feed_command', '/pmc/feed_override', '/force/reference', '/diagnostics',
          '/force/measured', '/machine/inputs', '/machine/spindle_speed', '/pmc/cuts',
          '/session/settings'}


@pytest.fixture(scope='module')
def fig8_session(tmp_path_factory, fig8):
    experiment = load_experiment(fig8)
    bag = tmp_path_factory.mktemp('run') / 'fig8'
    outcome = run_lockstep(experiment, bag)
    return experiment, bag, outcome


def test_graph_run_equals_the_core_loop(fig8_session):
    # Same plant, estimator, controller and quantiser, the same one-period delay, float64 on
    # the wire: the graph must give the core loop's metrics. The tolerance (1e-9 relative) only
    # allows for summation order; in practice they agree to the last digit.
    experiment, bag, outcome = fig8_session
    graph = recorded_metrics(read_session(bag))
    core = simulate(experiment).metrics
    for name, value in graph.items():
        assert value == pytest.approx(core[name], rel=1e-9, abs=1e-12), name
    assert outcome.steps == 1200   # how fast: test/bench/bench_lockstep.py


def test_same_file_and_seed_give_identical_sessions(fig8_session, tmp_path):
    experiment, bag, _ = fig8_session
    again = tmp_path / 'again'
    run_lockstep(experiment, again)
    first, second = read_session(bag), read_session(again)
    assert recorded_metrics(first) == recorded_metrics(second)
    for name, values in first.signals.items():
        np.testing.assert_array_equal(values, second.signals[name], err_msg=name)


def test_rosbags_reads_every_topic_and_the_embedded_records(fig8_session, fig8):
    _, bag, _ = fig8_session
    with AnyReader([bag], default_typestore=typestore()) as reader:
        counts = {c.topic: c.msgcount for c in reader.connections}
        assert set(counts) == TOPICS
        for topic in ('/servo/currents', '/force/estimate', '/control/feed_command',
                      '/sim/cutting_state'):
            assert counts[topic] == 1200, topic
        connection = next(c for c in reader.connections if c.topic == '/servo/currents')
        _, _, raw = next(reader.messages(connections=[connection]))
        first = reader.deserialize(raw, connection.msgtype)
        assert len(first.phase_u_a) == 10 and first.sample_period_s == 1e-3
    session = read_session(bag)
    assert session.custom_data[CUSTOM_EXPERIMENT] == fig8.read_text()
    params = json.loads(session.custom_data[CUSTOM_PARAMETERS])
    assert params['force_controller']['smc_epsilon_n'] == 200.0
    assert params['pmc_bridge']['override_table'] == 'fanuc_0t_4bit'
    assert json.loads(session.custom_data[CUSTOM_VERSIONS])['turning_force']


def test_mcap_reader_decodes_the_session(fig8_session):
    _, bag, _ = fig8_session
    with (bag / f'{bag.name}.mcap').open('rb') as stream:
        reader = make_reader(stream, validate_crcs=True, decoder_factories=[DecoderFactory()])
        summary = reader.get_summary()
        assert {c.topic for c in summary.channels.values()} == TOPICS
        assert {s.encoding for s in summary.schemas.values()} == {'ros2msg'}
        overrides = [m for _, _, _, m in reader.iter_decoded_messages(
            topics=['/pmc/feed_override'])]
    levels = {o.applied_pct for o in overrides}
    assert levels <= {10.0 * k for k in range(16)}   # only FANUC 0-T levels reached the PMC
    assert all(len(o.pmc_bits) == 4 for o in overrides)


def test_replay_with_other_settings_changes_the_commands_not_the_currents(fig8_session):
    _, bag, _ = fig8_session
    result = replay(read_session(bag), ['force_controller.controller=pi'])
    assert result.max_force_difference_n == 0.0     # open loop: same currents, same estimates
    assert result.differing_overrides > 100
    assert result.experiment.controller.controller == 'pi'


def test_report_is_a_png(fig8_session, tmp_path):
    _, bag, _ = fig8_session
    session = read_session(bag)
    out = write_report(session, recorded_metrics(session), tmp_path / 'fig8.png')
    header = out.read_bytes()[:24]
    assert header[:8] == b'\x89PNG\r\n\x1a\n'
    width, height = struct.unpack('>II', header[16:24])
    assert (width, height) == (1440, 1020)


def test_a_session_from_the_machine_replays_with_its_experiment_file(fig8_session, tmp_path):
    # A recorder started with ros2 run embeds the experiment file, not resolved parameters.
    _, bag, _ = fig8_session
    copy = tmp_path / 'fig8'   # without the settings topic, which holds the parameters too
    rewrite(bag, copy, keep=lambda topic: topic != '/session/settings')
    metadata = yaml.safe_load((copy / 'metadata.yaml').read_text())
    del metadata['rosbag2_bagfile_information']['custom_data'][CUSTOM_PARAMETERS]
    (copy / 'metadata.yaml').write_text(yaml.safe_dump(metadata))
    session = read_session(copy)
    assert session.experiment is not None
    assert 'recorded experiment' in session.experiment.source
    assert replay(session).differing_overrides == 0


def copy_without(bag: Path, out: Path, dropped: str) -> None:
    """A copy of a session without one topic (here: what a machine does not have)."""
    custom = yaml.safe_load((bag / 'metadata.yaml').read_text())[
        'rosbag2_bagfile_information']['custom_data']
    writer = SessionWriter(out)
    for key, value in custom.items():
        writer.set_custom_data(key, value)
    with AnyReader([bag], default_typestore=typestore()) as reader:
        kept = [c for c in reader.connections if c.topic != dropped]
        for connection in kept:
            writer.add_topic(connection.topic, connection.msgtype)
        for connection, timestamp, raw in reader.messages(connections=kept):
            writer.write(connection.topic, timestamp, bytes(raw))
    writer.close()


def test_a_machine_session_is_measured_on_the_estimated_force(fig8_session, tmp_path):
    # No simulator truth on a lathe: metrics and figure come from the estimated force. Over
    # fig8 the estimate is within a few newtons of the truth, so the metrics are close to it.
    _, bag, _ = fig8_session
    machine = tmp_path / 'machine'
    copy_without(bag, machine, '/sim/cutting_state')
    session = read_session(machine)
    assert not session.has_truth
    truth = recorded_metrics(read_session(bag))
    estimated = recorded_metrics(session)
    assert estimated['steady_mean_abs_error_n'] == pytest.approx(
        truth['steady_mean_abs_error_n'], abs=1.0)
    assert estimated['override_changes_per_s'] == pytest.approx(
        truth['override_changes_per_s'], rel=0.01)
    assert write_report(session, estimated, tmp_path / 'machine.png').stat().st_size > 50_000


def test_a_broken_session_is_named(tmp_path):
    with pytest.raises(BagError, match=f'{tmp_path}: not a rosbag2 folder'):
        read_session(tmp_path)
    (tmp_path / 'metadata.yaml').write_text('rosbag2_bagfile_information: [')
    with pytest.raises(BagError, match=r'metadata\.yaml: not rosbag2 metadata'):
        read_session(tmp_path)
