"""The turning-force command: its outputs and its errors."""

from __future__ import annotations

import json
import threading
from pathlib import Path

import pytest
from turning_force_msgs.msg import ForceEstimate

from turning_force.cli import main
from turning_force.core.metrics import METRIC_NAMES
from turning_force.nodes.force_estimator import ForceEstimatorNode
from turning_force.session.play import play

ROOT = Path(__file__).resolve().parents[2]
FIG8 = ROOT / 'config' / 'experiments' / 'park1998_fig8.yaml'
REFERENCE = ROOT / 'bags' / 'reference' / 'park1998_fig8'


def json_out(capfd, argv):
    assert main(argv) == 0
    return json.loads(capfd.readouterr().out)


def test_run_records_a_session_and_a_figure(capfd, tmp_path):
    out = json_out(capfd, ['run', str(FIG8), '--out', str(tmp_path / 's'), '--json',
                            '--set', 'experiment.duration_s=2.0'])
    assert set(out['metrics']) == {*METRIC_NAMES, 'realtime_factor'}
    assert (tmp_path / 's' / 'metadata.yaml').is_file()
    assert Path(out['figure']).is_file() and out['executor'] == 'EventsExecutor'


def test_run_core_loop(capfd):
    out = json_out(capfd, ['run', str(FIG8), '--core', '--json'])
    assert out['metrics']['steady_mean_abs_error_n'] <= 8.9


def test_replay_json_of_the_reference_session(capfd):
    out = json_out(capfd, ['replay', str(REFERENCE), '--json'])
    assert out['comparison']['differing_overrides'] == 0
    assert out['metrics'] == out['recorded_metrics']


def test_report_writes_the_figure(capfd, tmp_path):
    assert main(['report', str(REFERENCE), '--out', str(tmp_path / 'r.png')]) == 0
    assert (tmp_path / 'r.png').stat().st_size > 50_000
    assert 'steady_mean_abs_error_n' in capfd.readouterr().out
    assert main(['report', str(REFERENCE), '--out', str(tmp_path / 'r.html')]) == 0
    page = (tmp_path / 'r.html').read_text()
    assert 'data:image/png;base64,' in page and 'steady_mean_abs_error_n' in page
    assert sorted(p.name for p in tmp_path.iterdir()) == ['r.html', 'r.png']


@pytest.mark.parametrize(('argv', 'message'), [
    (['run', 'nope.yaml'], 'nope.yaml: cannot read'),
    (['run', str(FIG8), '--set', 'force_controller.smc_lambda_per_s=40.0'],
     'force_controller.smc_lambda_per_s = 40.0'),
    (['run', str(FIG8), '--set', 'lambda=3'], "--set 'lambda=3': expected node.param=value"),
    (['replay', 'bags/none'], 'bags/none: not a rosbag2 folder'),
    (['replay', str(REFERENCE), '--publish', '--rate', '0'], '--rate 0.0: must be positive'),
    (['report', str(REFERENCE), '--out', 'x.svg'], '--out x.svg: write .png or .html'),
])
def test_bad_input_exits_2_naming_it(capfd, argv, message):
    assert main(argv) == 2
    assert message in capfd.readouterr().err


def test_replay_publish_feeds_a_live_graph(context, executor, spin_until):
    # The recorded currents, played at twice their speed into a live estimator here.
    estimator = ForceEstimatorNode(context=context)
    executor.add_node(estimator)
    estimates: list[ForceEstimate] = []
    estimator.create_subscription(ForceEstimate, 'force/estimate', estimates.append, 100)
    sent: list[int] = []
    player = threading.Thread(target=lambda: sent.append(
        play(REFERENCE, rate=2.0, context=context, show_progress=False)))
    player.start()
    try:
        assert spin_until(lambda: not player.is_alive() and len(estimates) >= 1140, 60.0)
    finally:
        player.join(timeout=60)
    assert sent[0] == 1200 + 1200 + 0   # currents and joint states; no reference was recorded
    ok = [e for e in estimates if e.status == ForceEstimate.STATUS_OK]
    # A few may go before discovery or when this busy test process falls behind, as with
    # ros2 bag play; 95 % must arrive.
    assert len(ok) >= 1140
