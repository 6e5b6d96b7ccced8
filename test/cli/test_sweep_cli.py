"""``turning-force sweep`` and ``turning-force replay BAG BAG ...``: outputs, errors, Dask."""

from __future__ import annotations

import csv
import json
import shutil

import pytest

from turning_force.cli import main
from turning_force.core.experiment import load_experiment
from turning_force.core.kernel.simulate import simulate
from turning_force.core.metrics import METRIC_NAMES
from turning_force.session.reader import read_session
from turning_force.session.replay import replay

LAMBDA = 'force_controller.smc_lambda_per_s'
EPSILON = 'force_controller.smc_epsilon_n'
SHORT = 'experiment.duration_s=1.5'


def sweep_argv(fig8, *extra):
    return ['sweep', str(fig8), '--grid', f'{LAMBDA}=5:20:3', '--grid', f'{EPSILON}=100,300',
            '--set', SHORT, *extra]


def json_out(capfd, argv, status=0):
    assert main(argv) == status
    return json.loads(capfd.readouterr().out)


@pytest.fixture(scope='module')
def two_bags(reference_bag, tmp_path_factory):
    copy = tmp_path_factory.mktemp('bags') / 'copy'
    shutil.copytree(reference_bag, copy)
    return [str(reference_bag), str(copy)]


def test_sweep_prints_the_best_and_writes_table_and_figure(capfd, tmp_path, fig8):
    table, figure = tmp_path / 'r.csv', tmp_path / 'r.png'
    out = json_out(capfd, sweep_argv(fig8, '--jobs', '1', '--top', '2', '--out', str(table),
                                     '--figure', str(figure), '--json'))
    assert (out['points'], out['errors'], out['metric'], out['better']) == (
        6, 0, 'steady_mean_abs_error_n', 'lower')
    with table.open(newline='') as f:
        rows = list(csv.DictReader(f))
    ranked = sorted(rows, key=lambda r: float(r['steady_mean_abs_error_n']))
    assert [b[LAMBDA] for b in out['best']] == [float(r[LAMBDA]) for r in ranked[:2]]
    best = out['best'][0]
    # The best point's --set line runs it again: simulate() on those settings agrees.
    direct = simulate(load_experiment(fig8).with_sets(best['sets']))
    assert best['sets'][0] == SHORT
    assert {m: best[m] for m in METRIC_NAMES} == {m: direct.metrics[m] for m in METRIC_NAMES}
    assert figure.read_bytes()[:4] == b'\x89PNG'


def test_sweep_text_output(capfd, fig8):
    assert main(sweep_argv(fig8, '--jobs', '2', '--metric', 'overshoot_n', '--top', '3')) == 0
    out = capfd.readouterr().out
    assert out.startswith('park1998_fig8: 6 points (3 force_controller.smc_lambda_per_s x 2 '
                          'force_controller.smc_epsilon_n), closed loop on the simulator, on '
                          '2 processes')
    assert 'best by overshoot_n (lower is better):' in out
    assert f"the best again: turning-force run {fig8} --set '{SHORT}' --set '{LAMBDA}=" in out
    ranks = [line.split()[0] for line in out.splitlines() if line.startswith('     ')]
    assert ranks == ['1', '2', '3']


def test_sweep_on_a_session(capfd, reference_bag):
    grid = 'force_estimator.kalman_force_noise_n=2.0,8.0'
    out = json_out(capfd, ['sweep', '--replay', str(reference_bag), '--grid', grid, '--jobs',
                           '1', '--metric', 'mean_abs_error_n', '--json'])
    direct = replay(read_session(reference_bag), out['best'][0]['sets'])
    assert out['replayed'] == str(reference_bag) and out['points'] == 2
    assert out['best'][0]['mean_abs_error_n'] == direct.rerun['mean_abs_error_n']
    assert out['best'][0]['differing_overrides'] == direct.differing_overrides


@pytest.mark.parametrize(('extra', 'message'), [
    (['--grid', 'lathe.seed=1,2'], "--grid 'lathe.seed=1,2': unknown node 'lathe'"),
    (['--grid', f'{LAMBDA}=5:20:0'], f"--grid '{LAMBDA}=5:20:0': N = 0: need at least 1"),
    (['--grid', f'{LAMBDA}=5:40:3'], f"--grid '{LAMBDA}=5:40:3': {LAMBDA} = 22.5: above"),
    (['--grid', 'force_controller.nope=1,2'], 'force_controller.nope = 1: unknown parameter'),
    (['--grid', f'{LAMBDA}=5', '--set', 'x.y=1'], "--set 'x.y=1': unknown node 'x'"),
    (['--grid', f'{LAMBDA}=5', '--out', 'r.xlsx'], '--out r.xlsx: write .csv or .parquet'),
    (['--grid', f'{LAMBDA}=5', '--figure', 'no/such/dir/f.png'],
     '--figure no/such/dir/f.png: no/such/dir does not exist'),
    (['--grid', f'{LAMBDA}=5', '--top', '0'], '--top 0: need at least 1'),
    (['--grid', f'{LAMBDA}=5', '--jobs', '0'], '--jobs 0: need at least 1'),
])
def test_a_bad_sweep_is_one_line_and_exit_2(capfd, fig8, extra, message):
    assert main(['sweep', str(fig8), '--set', SHORT, *extra]) == 2
    err = capfd.readouterr().err
    assert err.startswith('turning-force: ') and message in err and err.count('\n') == 1


def test_a_sweep_needs_an_experiment_or_a_session(capfd):
    assert main(['sweep', '--grid', f'{LAMBDA}=5']) == 2
    assert 'give EXPERIMENT, or --replay BAG' in capfd.readouterr().err


def test_a_sweep_where_every_point_fails_says_so(capfd, fig8):
    grid = ['--grid', 'force_controller.smc_ksd_min_n_mm=5000', '--grid',
            'force_controller.smc_ksd_max_n_mm=3000']
    # Each value alone is valid against the file (2000-7000); together they are not.
    assert main(['sweep', str(fig8), '--set', SHORT, '--jobs', '1', *grid]) == 2
    captured = capfd.readouterr()
    assert '1 of 1 points failed' in captured.out
    assert 'sweep: no point has a number for steady_mean_abs_error_n (1 of 1 points failed; ' \
           'the first: force_controller.smc_ksd_max_n_mm = 3000.0: must exceed' in captured.err


def test_replay_of_several_sessions_prints_a_row_each_and_the_totals(capfd, two_bags):
    sets = ['--set', f'{LAMBDA}=15']
    assert main(['replay', *two_bags, *sets, '--jobs', '2']) == 0
    out = capfd.readouterr().out.splitlines()
    direct = replay(read_session(two_bags[0]), [f'{LAMBDA}=15'])
    assert out[0].startswith(f'2 sessions replayed open loop with {LAMBDA}=15')
    rows = [line.split() for line in out if line.strip().startswith((*two_bags, 'total'))]
    assert [r[0] for r in rows] == [*two_bags, 'total']
    assert [int(r[-1]) for r in rows] == [direct.differing_overrides] * 2 + [
        2 * direct.differing_overrides]
    assert rows[2][:5] == ['total', '(2', 'of', '2)', '2400']
    js = json_out(capfd, ['replay', *two_bags, *sets, '--jobs', '1', '--json'])
    assert [s['session'] for s in js['sessions']] == two_bags
    assert js['sessions'][0]['metrics'] == direct.rerun
    assert js['totals']['comparison']['differing_overrides'] == 2 * direct.differing_overrides


def test_replay_of_several_sessions_with_a_bad_one(capfd, two_bags, tmp_path):
    missing = str(tmp_path / 'gone')
    assert main(['replay', two_bags[0], missing, '--jobs', '1']) == 2
    captured = capfd.readouterr()
    assert f'{missing} failed: {missing}: not a rosbag2 folder' in captured.out
    assert 'total (1 of 2)' in captured.out
    assert captured.err.strip() == f'turning-force: {missing}: not a rosbag2 folder (no ' \
                                   'metadata.yaml)'


def test_publish_plays_one_session(capfd, two_bags):
    assert main(['replay', *two_bags, '--publish']) == 2
    assert '--publish plays one session' in capfd.readouterr().err


def test_sweep_and_replay_on_dask_are_the_local_ones(capfd, dask_cluster, fig8, reference_bag,
                                                    two_bags):
    address = dask_cluster.scheduler_address
    local = json_out(capfd, sweep_argv(fig8, '--jobs', '1', '--json'))
    on_dask = json_out(capfd, sweep_argv(fig8, '--dask', address, '--json'))
    assert on_dask['ran_on'] == f'dask {address}'
    for name in ('best', 'points', 'errors'):
        assert on_dask[name] == local[name]
    sets = ['--set', 'force_estimator.kalman_force_noise_n=4.0']
    one = json_out(capfd, ['replay', str(reference_bag), *sets, '--json'])
    # One session on Dask prints what the one-session replay prints.
    assert json_out(capfd, ['replay', str(reference_bag), *sets, '--dask', address,
                            '--json']) == one
    many = json_out(capfd, ['replay', *two_bags, *sets, '--dask', address, '--json'])
    for session in many['sessions']:
        assert {k: session[k] for k in one} == {**one, 'session': session['session']}
