"""The turning-force command: its outputs and its errors."""

from __future__ import annotations

import json
import threading
from pathlib import Path

import numpy as np
import pytest
from rclpy.node import Node
from turning_force_msgs.msg import ForceEstimate, ServoCurrents

from turning_force.cli import main
from turning_force.commands.play import play
from turning_force.core.experiment import load_experiment
from turning_force.core.kernel.simulate import simulate
from turning_force.core.metrics import METRIC_NAMES
from turning_force.nodes.convert import last_sample_ns, servo_currents_to_block, stamp_to_ns
from turning_force.nodes.force_estimator import ForceEstimatorNode
from turning_force.session.reader import read_session


def json_out(capfd, argv):
    assert main(argv) == 0
    return json.loads(capfd.readouterr().out)


def test_run_records_a_session_and_a_figure(capfd, tmp_path, fig8):
    out = json_out(capfd, ['run', str(fig8), '--out', str(tmp_path / 's'), '--json',
                            '--set', 'experiment.duration_s=2.0'])
    # The simulator's truth is recorded: the estimator's error beside the regulation's.
    assert set(out['metrics']) == {*METRIC_NAMES, 'estimate_error_rms_n', 'realtime_factor'}
    assert (tmp_path / 's' / 'metadata.yaml').is_file()
    assert Path(out['figure']).is_file() and out['executor'] == 'EventsExecutor'


def test_run_core_loop(capfd, fig8):
    # What the core loop computes, printed as it is (the paper's 8.9 N is checked on the core,
    # test/core/test_reproduction.py).
    out = json_out(capfd, ['run', str(fig8), '--core', '--json'])
    core = simulate(load_experiment(fig8)).metrics
    assert {k: v for k, v in out['metrics'].items() if k != 'realtime_factor'} == {
        k: v for k, v in core.items() if k != 'realtime_factor'}


def test_replay_json_of_the_reference_session(capfd, reference_bag):
    out = json_out(capfd, ['replay', str(reference_bag), '--json'])
    assert out['comparison']['differing_overrides'] == 0
    # To 1e-9, not the bit: see test/session/test_reference_bag.py.
    assert out['metrics'] == pytest.approx(out['recorded_metrics'], rel=1e-9)


def test_report_writes_the_figure(capfd, tmp_path, reference_bag):
    assert main(['report', str(reference_bag), '--out', str(tmp_path / 'r.png')]) == 0
    assert (tmp_path / 'r.png').stat().st_size > 50_000
    assert 'steady_mean_abs_error_n' in capfd.readouterr().out
    assert main(['report', str(reference_bag), '--out', str(tmp_path / 'r.html')]) == 0
    page = (tmp_path / 'r.html').read_text()
    assert 'data:image/png;base64,' in page and 'steady_mean_abs_error_n' in page
    assert sorted(p.name for p in tmp_path.iterdir()) == ['r.html', 'r.png']


@pytest.fixture
def bad_files(tmp_path, fig8):
    """Experiment files a shop will bring, in tmp_path, and a plain file to write under."""
    text = fig8.read_text()
    latin1 = text.replace('override, steel', 'override, Stahl \u00fc').encode('latin-1')
    (tmp_path / 'latin1.yaml').write_bytes(latin1)
    (tmp_path / 'twice.yaml').write_text(
        text + '/**/experiment:\n  ros__parameters:\n    duration_s: 1.0\n')
    (tmp_path / 'seed.yaml').write_text(text.replace('seed: 1\n', f'seed: {2**64}\n'))
    (tmp_path / 'name.yaml').write_text(text.replace('name: park1998_fig8', 'name: ../../x'))
    (tmp_path / 'recorder.yaml').write_text(
        text + '/**/session_recorder:\n  ros__parameters:\n    flush_periodd_s: 1.0\n')
    (tmp_path / 'afile').write_text('')
    return tmp_path


@pytest.mark.parametrize(('argv', 'message'), [
    (['run', 'nope.yaml'], 'nope.yaml: cannot read'),
    (['run', '{fig8}', '--set', 'force_controller.smc_lambda_per_s=40.0'],
     'force_controller.smc_lambda_per_s = 40.0'),
    (['run', '{fig8}', '--set', 'lambda=3'], "--set 'lambda=3': expected node.param=value"),
    (['replay', 'bags/none'], 'bags/none: not a rosbag2 folder'),
    (['replay', '{reference}', '--publish', '--rate', '0'], '--rate 0.0: must be positive'),
    (['report', '{reference}', '--out', 'x.svg'], '--out x.svg: write .png or .html'),
    (['run', '{tmp}/latin1.yaml'], '{tmp}/latin1.yaml: not UTF-8 text: byte 0xfc on line 31'),
    (['run', '{tmp}/twice.yaml'], "{tmp}/twice.yaml: not valid YAML: line {end}, column 1: "
     "duplicate key '/**/experiment' (first on line {first})"),
    (['run', '{tmp}/seed.yaml'], f'{{tmp}}/seed.yaml: lathe_sim.seed = {2**64}: outside the '
     '64-bit range of a ROS integer parameter'),
    (['run', '{tmp}/name.yaml'], "experiment.name = '../../x': must be a plain file name"),
    (['run', '{tmp}/recorder.yaml'], 'session_recorder.flush_periodd_s = 1.0: unknown '
     'parameter'),
    (['run', '{fig8}', '--out', '{tmp}/missing/s'],
     '--out {tmp}/missing/s: {tmp}/missing does not exist'),
    (['run', '{fig8}', '--out', '{tmp}/afile/s'],
     '--out {tmp}/afile/s: {tmp}/afile is not a folder'),
    (['run', '{fig8}', '--out', '{tmp}/afile'],
     '--out {tmp}/afile: exists already; a session is never overwritten'),
    (['run', '{fig8}', '--out', '/proc/self/s'], '--out /proc/self/s: cannot write in /proc/self'),
    (['report', '{reference}', '--out', '{tmp}/missing/r.png'],
     '--out {tmp}/missing/r.png: {tmp}/missing does not exist'),
    (['calibrate', '{reference}', '{reference}', '--settle-s', '-1'],
     '--settle-s -1.0: expected a finite time >= 0 s'),
    (['calibrate', '{reference}', '{reference}', '--settle-s', 'nan'],
     '--settle-s nan: expected a finite time >= 0 s'),
])
def test_bad_input_exits_2_naming_it(capfd, bad_files, fig8, reference_bag, argv, message):
    lines = fig8.read_text().splitlines()
    names = {'fig8': fig8, 'reference': reference_bag, 'tmp': bad_files,
             'end': len(lines) + 1, 'first': lines.index('/**/experiment:') + 1}
    assert main([a.format(**names) for a in argv]) == 2
    err = capfd.readouterr().err
    assert message.format(**names) in err
    assert err.count('\n') == 1 and err.startswith('turning-force: '), err   # one line
    assert not (bad_files / 'missing').exists()          # nothing made on the way


def test_a_bad_ros_domain_is_one_line_and_the_old_variable_is_gone(capfd, monkeypatch, fig8,
                                                                     tmp_path):
    # The run isolates itself (session/run.py): TURNING_FORCE_DOMAIN_ID no longer exists.
    monkeypatch.setenv('TURNING_FORCE_DOMAIN_ID', 'abc')
    assert main(['run', str(fig8), '--out', str(tmp_path / 's'), '--json',
                 '--set', 'experiment.duration_s=0.1']) == 0
    capfd.readouterr()
    monkeypatch.setenv('ROS_DOMAIN_ID', 'abc')
    assert main(['run', str(fig8), '--out', str(tmp_path / 't')]) == 2
    assert capfd.readouterr().err == ("turning-force: ROS_DOMAIN_ID='abc': expected an integer "
                                      'from 0 to 232\n')
    assert not (tmp_path / 't').exists()


def test_replay_publish_feeds_a_live_graph(context, executor, spin_until, reference_bag):
    # The recorded sensor topics, played at twice their speed into this process. A listener
    # with room for the whole session gets every block, as recorded, in order (reliable QoS,
    # matched before the first one goes out): nothing here depends on how busy the machine is.
    # The estimator beside it answers what its 10-deep queue keeps up with.
    estimator = ForceEstimatorNode(context=context)
    listener = Node('listener', context=context)
    for node in (estimator, listener):
        executor.add_node(node)
    heard: list[ServoCurrents] = []
    estimates: list[ForceEstimate] = []
    listener.create_subscription(ServoCurrents, 'servo/currents', heard.append, 1200)
    listener.create_subscription(ForceEstimate, 'force/estimate', estimates.append, 1200)
    sent: list[int] = []
    player = threading.Thread(target=lambda: sent.append(
        play(reference_bag, rate=2.0, context=context, show_progress=False)))
    player.start()
    try:
        assert spin_until(lambda: not player.is_alive() and len(heard) == 1200, 60.0)
    finally:
        player.join(timeout=60)
    assert sent[0] == 1200 + 1200 + 0   # currents and joint states; no reference was recorded
    recorded = read_session(reference_bag).blocks
    for block, msg in zip(recorded, heard, strict=True):
        played = servo_currents_to_block(msg)
        assert stamp_to_ns(msg.header.stamp) == round(block.t0_s * 1e9)
        np.testing.assert_array_equal(played.phase_u_a, block.phase_u_a)
        np.testing.assert_array_equal(played.feed_rate_mm_min, block.feed_rate_mm_min)
    # Each estimate answers a played block (its last sample's stamp), but for the STALE ones
    # the estimator's watchdog sends, on its clock, when playback stalls on a busy machine.
    answers = {last_sample_ns(msg) for msg in heard}
    assert spin_until(lambda: any(e.status == ForceEstimate.STATUS_OK for e in estimates))
    assert all(stamp_to_ns(e.header.stamp) in answers for e in estimates
               if e.status != ForceEstimate.STATUS_STALE)
