"""turning_force.commands.sweep: grids, sweeps closed loop and on a session, their tables and
figures, the replay of several sessions, and the same results on local processes and on Dask."""

from __future__ import annotations

import csv
import math
import shutil
import sys

import pytest

from turning_force.commands import sweep as sweep_module
from turning_force.commands.sweep import (
    BETTER,
    REPLAY_COLUMNS,
    Axis,
    parse_axis,
    parse_grid,
    replay_sessions,
    replay_totals,
    sweep,
)
from turning_force.core.errors import ConfigError, TurningForceError
from turning_force.core.experiment import load_experiment, parse_set
from turning_force.core.kernel.simulate import simulate
from turning_force.core.metrics import METRIC_NAMES
from turning_force.session.reader import read_session
from turning_force.session.replay import replay

LAMBDA = 'force_controller.smc_lambda_per_s'
EPSILON = 'force_controller.smc_epsilon_n'
# 3 x 3 points of Fig. 8 cut to 1.5 s (150 periods: the first depth step's transient, enough
# for the metrics to differ from point to point).
GRID = [f'{LAMBDA}=5:20:3', f'{EPSILON}=100,200,300']
SHORT = ['experiment.duration_s=1.5']


@pytest.fixture(scope='module')
def short_fig8(fig8):
    return load_experiment(fig8).with_sets(SHORT)


@pytest.fixture(scope='module')
def swept(short_fig8):
    """The 3 x 3 sweep in this process."""
    return sweep(short_fig8, GRID, jobs=1, progress=False)


def metrics_of(row):
    return {name: row[name] for name in METRIC_NAMES}


def same(a, b):
    """Equal, NaN equal to NaN (a metric a point does not have)."""
    return a == b or (isinstance(a, float) and isinstance(b, float) and math.isnan(a)
                      and math.isnan(b))


# -- the grid ---------------------------------------------------------------------------------

def test_a_range_has_both_ends_and_n_points():
    assert parse_axis(f'{LAMBDA}=5:20:4').values == (5.0, 10.0, 15.0, 20.0)
    assert parse_axis(f'{LAMBDA}=7:7:1').values == (7.0,)


def test_a_log_range_is_evenly_spaced_in_the_logarithm():
    axis = parse_axis('force_controller.smc_eta=0.01:1:3log')
    assert axis.log
    assert axis.values[0] == 0.01 and axis.values[2] == 1.0
    assert axis.values[1] == pytest.approx(0.1, rel=1e-15)


def test_a_list_is_read_as_yaml_and_takes_the_settings_types():
    assert parse_axis('force_controller.controller=smc,adaptive').values == ('smc', 'adaptive')
    # An integer given for a float setting is the float Settings read it as.
    floats = parse_axis(f'{EPSILON}=100,200.5').values
    assert floats == (100.0, 200.5) and all(type(v) is float for v in floats)
    # An integer setting from a range: whole numbers, as integers.
    seeds = parse_axis('lathe_sim.seed=1:4:4').values
    assert seeds == (1, 2, 3, 4) and all(type(v) is int for v in seeds)
    assert parse_axis('lathe_sim.depth_mm=[1, 2, 3],[1.5, 2.5, 3.5]').values == (
        (1, 2, 3), (1.5, 2.5, 3.5))


def test_a_mapping_grid_takes_lists_and_range_texts():
    axes = parse_grid({LAMBDA: [5, 10], EPSILON: '100:300:3'})
    assert [a.values for a in axes] == [(5.0, 10.0), (100.0, 200.0, 300.0)]


@pytest.mark.parametrize(('text', 'message'), [
    ('lathe.seed=1:2:2', "--grid 'lathe.seed=1:2:2': unknown node 'lathe'; known: /\\*\\*, "),
    (f'{LAMBDA}=5:20:0', 'N = 0: need at least 1 point'),
    (f'{LAMBDA}=5:20:-2', 'N = -2: need at least 1 point'),
    (f'{LAMBDA}=5:20:x', "N = 'x': expected a whole number of points, or Nlog"),
    (f'{LAMBDA}=5:20:2.5', "N = '2.5': expected a whole number"),
    (f'{LAMBDA}=a:20:3', "START and STOP must be numbers, got 'a' and '20'"),
    (f'{LAMBDA}=5:nan:3', 'START and STOP must be finite'),
    (f'{LAMBDA}=5:20', "expected START:STOP:N \\(or Nlog\\), got '5:20'"),
    (f'{LAMBDA}=0:20:3log', 'a log-spaced range needs START and STOP above 0'),
    (f'{LAMBDA}=', 'expected node.param=START:STOP:N'),
    ('smc_lambda_per_s=5', 'expected node.param=START:STOP:N'),
    (f'{LAMBDA}=5,,6', r'not a list of YAML values .*: line 1, column \d+: '),
    (f'{LAMBDA}=5,null', 'an empty value'),
    (f'{LAMBDA}=5,[6', 'not a list of YAML values'),
    (f'{LAMBDA}=5,5.0', '5.0 is given twice'),
    (f'{LAMBDA}=5:5:2', '5.0 is given twice'),
    ('lathe_sim.seed=1:2:3', 'lathe_sim.seed takes whole numbers; the range gives 1.5'),
    ('force_controller.controller=1:2:3', 'force_controller.controller is a str: give its '
     'values as v1,v2'),
    ('lathe_sim.depth_mm=1:2:3', 'lathe_sim.depth_mm is a list: give its values as'),
])
def test_a_bad_axis_is_one_error_naming_it(text, message):
    with pytest.raises(ConfigError, match=message) as caught:
        parse_grid([text])
    assert '\n' not in str(caught.value)


def test_an_axis_given_twice_and_no_axis_are_errors():
    with pytest.raises(ConfigError, match=f'{LAMBDA} is swept by .* already'):
        parse_grid([f'{LAMBDA}=5,10', f'{LAMBDA}=15'])
    with pytest.raises(ConfigError, match='no axes'):
        parse_grid([])


@pytest.mark.parametrize(('text', 'message'), [
    # The settings' specs, checked before any point runs.
    (f'{LAMBDA}=10:30:3', f"--grid '{LAMBDA}=10:30:3': {LAMBDA} = 30.0: above the Eq. 24"),
    (f'{EPSILON}=-1,100', f'{EPSILON} = -1.0: outside'),
    ('force_controller.controller=smc,fuzzy', "controller = 'fuzzy': expected one of"),
    ('force_controller.smc_typo=1,2', 'force_controller.smc_typo = 1: unknown parameter'),
])
def test_a_value_the_settings_refuse_stops_the_sweep_before_it_runs(short_fig8, text, message):
    with pytest.raises(ConfigError, match=message):
        sweep(short_fig8, [text], jobs=2, progress=False)


@pytest.mark.parametrize('value', [1e-05, 0.1, 1e20, -3.5, 7, True, 'smc', (1.0, 2.0), 'a b'])
def test_a_value_reads_back_from_its_set_text(value):
    node, param, read = parse_set(Axis('force_controller.x', (value,)).set_text(value))
    assert (node, param) == ('force_controller', 'x')
    assert read == (list(value) if isinstance(value, tuple) else value)
    assert type(read) is (list if isinstance(value, tuple) else type(value))


def test_every_metric_says_which_way_is_better():
    assert set(BETTER) == set(METRIC_NAMES)
    assert BETTER['steady_mean_abs_error_n'] == 'lower'
    assert BETTER['reachable_fraction'] == 'higher'


# -- closed loop ------------------------------------------------------------------------------

def test_every_point_is_what_simulate_gives_on_its_settings(swept, short_fig8):
    assert len(swept.table) == 9 and not swept.errors
    assert [(r[LAMBDA], r[EPSILON]) for r in swept.table[:4]] == [
        (5.0, 100.0), (5.0, 200.0), (5.0, 300.0), (12.5, 100.0)]   # the last axis fastest
    for row in swept.table:
        direct = simulate(short_fig8.with_sets(swept.point_sets(row)))
        assert metrics_of(row) == {k: direct.metrics[k] for k in METRIC_NAMES}
    values = [r['steady_mean_abs_error_n'] for r in swept.table]
    assert len(set(values)) == 9   # the grid does change the run


def test_the_best_are_the_lowest_error_first(swept):
    best = swept.best(k=3)
    ordered = sorted(swept.table, key=lambda r: r['steady_mean_abs_error_n'])
    assert best == ordered[:3]
    # Higher is better for the reachable fraction: ties (all 1.0 here) in grid order.
    assert swept.best('reachable_fraction', 2) == sorted(
        swept.table, key=lambda r: -r['reachable_fraction'])[:2]
    with pytest.raises(ConfigError, match="--metric 'speed': not a metric"):
        swept.best('speed')


def test_a_sweep_is_deterministic_and_the_same_on_one_or_two_processes(swept, short_fig8):
    again = sweep(short_fig8, GRID, jobs=1, progress=False)
    two = sweep(short_fig8, GRID, jobs=2, progress=False)
    assert again.table == swept.table
    assert two.table == swept.table and two.ran_on == '2 processes'


def test_points_built_by_replacing_fields_are_the_experiments_with_sets_builds(short_fig8):
    # The workers build a point's settings by replacing fields of the sections it changes;
    # that must be exactly Experiment.with_sets, sections and all (here: four sections, an
    # integer and a list-valued setting).
    grid = ['lathe_sim.seed=1,2', 'force_estimator.kalman_force_noise_n=2.0,8.0',
            'experiment.settle_window_s=0.5,1.0',
            'lathe_sim.depth_mm=[1.0, 2.0, 3.0],[1.5, 2.0, 2.5]']
    result = sweep(short_fig8, grid, jobs=1, progress=False)
    axes = parse_grid(grid)
    job = sweep_module._Job(
        short_fig8, (), tuple(tuple(a.set_text(v) for v in a.values) for a in axes),
        start=short_fig8, fast=tuple((a.name.rsplit('.', 1)[0], a.name.rsplit('.', 1)[1],
                                      a.values) for a in axes))
    built: dict = {}
    for k, row in enumerate(result.table):
        assert job.experiment(k, built) == short_fig8.with_sets(job.point_sets(k))
        direct = simulate(short_fig8.with_sets(result.point_sets(row)))
        assert metrics_of(row) == {m: direct.metrics[m] for m in METRIC_NAMES}


@pytest.mark.parametrize('grid', [
    # Same section, refused by its check: K_s d max not above min.
    ['force_controller.smc_ksd_min_n_mm=2000,5000', 'force_controller.smc_ksd_max_n_mm=3000,7000'],
    # Two sections, refused by the experiment: the reference not below the overload hold.
    ['force_controller.reference_force_n=400,600', 'pmc_bridge.overload_force_n=550,2000'],
])
def test_a_combination_the_settings_refuse_is_that_points_error(short_fig8, grid):
    result = sweep(short_fig8, grid, jobs=1, progress=False)
    failed = [k for k, r in enumerate(result.table) if r['error']]
    assert failed == [2]   # (5000, 3000) and (600, 550): the third point of four
    row = result.table[2]
    assert 'must exceed' in row['error'] or 'not below' in row['error']
    assert all(math.isnan(row[m]) for m in METRIC_NAMES)
    for k in (0, 1, 3):
        direct = simulate(short_fig8.with_sets(result.point_sets(result.table[k])))
        assert metrics_of(result.table[k]) == {m: direct.metrics[m] for m in METRIC_NAMES}


def test_a_shop_floor_setting_sweeps_like_any_other(short_fig8):
    # The rise limit (the gate's, compiled with the rest) slows the override's rise: fewer
    # changes of override a second with it than without.
    result = sweep(short_fig8.with_sets(['experiment.duration_s=1.5']),
                   ['pmc_bridge.rise_rate_pct_s=0,20'], jobs=1, progress=False)
    assert [row['error'] for row in result.table] == ['', '']
    free, limited = result.table
    assert limited['override_changes_per_s'] < free['override_changes_per_s']


# -- the table and the figure -----------------------------------------------------------------

def test_the_table_reads_back_from_csv_and_parquet(swept, tmp_path):
    import pyarrow.parquet as pq

    swept.write(tmp_path / 't.csv')
    with (tmp_path / 't.csv').open(newline='') as f:
        rows = list(csv.DictReader(f))
    assert list(rows[0]) == [LAMBDA, EPSILON, *METRIC_NAMES, 'error']
    assert len(rows) == 9
    for read, row in zip(rows, swept.table, strict=True):
        for name in (LAMBDA, EPSILON, *METRIC_NAMES):
            assert float(read[name]) == row[name]   # floats written to round-trip
        assert read['error'] == ''
    swept.write(tmp_path / 't.parquet')
    assert pq.read_table(tmp_path / 't.parquet').to_pylist() == swept.table
    with pytest.raises(TurningForceError, match=r'write \.csv or \.parquet'):
        swept.write(tmp_path / 't.xlsx')


def test_figures_of_one_two_and_three_axes(swept, short_fig8, tmp_path):
    two = swept.figure(tmp_path / 'two.png')
    quick = short_fig8.with_sets(['experiment.duration_s=0.5'])
    one = sweep(quick, [f'{LAMBDA}=5:20:4'], jobs=1, progress=False).figure(tmp_path / '1.png')
    three = sweep(quick, [*GRID[:1], 'force_controller.smc_eta=0.05:0.2:2log', GRID[1]],
                  jobs=1, progress=False).figure(tmp_path / '3.png', 'overshoot_n')
    for path in (one, two, three):
        data = path.read_bytes()
        assert data[:8] == b'\x89PNG\r\n\x1a\n' and len(data) > 20_000


# -- open loop on a session -------------------------------------------------------------------

def test_a_sweep_on_a_session_is_what_replay_gives(reference_bag):
    session = read_session(reference_bag)
    grid = ['force_estimator.kalman_force_noise_n=2.0,8.0', f'{LAMBDA}=10,20']
    result = sweep(None, grid, replay=reference_bag, jobs=1, progress=False)
    assert result.replayed and len(result.table) == 4 and not result.errors
    assert list(result.table[0])[-5:] == [*REPLAY_COLUMNS, 'error']
    for row in result.table:
        direct = replay(session, result.point_sets(row))
        assert metrics_of(row) == {m: direct.rerun.get(m, math.nan) for m in METRIC_NAMES}
        assert row['differing_overrides'] == direct.differing_overrides
        assert row['max_force_difference_n'] == direct.max_force_difference_n
    # The estimator's noise changes the estimate (and so every metric); lambda only the
    # commands, which an open-loop replay does not feed back to the force.
    first, third = result.table[0], result.table[2]
    assert first['mean_abs_error_n'] != third['mean_abs_error_n']
    assert first['mean_abs_error_n'] == result.table[1]['mean_abs_error_n']


# -- several sessions -------------------------------------------------------------------------

@pytest.fixture(scope='module')
def two_bags(reference_bag, tmp_path_factory):
    copy = tmp_path_factory.mktemp('bags') / 'copy'
    shutil.copytree(reference_bag, copy)
    return [str(reference_bag), str(copy)]


def test_several_sessions_replay_as_each_does_alone(two_bags, tmp_path):
    sets = [f'{LAMBDA}=15']
    results = replay_sessions([*two_bags, str(tmp_path / 'none')], sets, jobs=2)
    direct = replay(read_session(two_bags[0]), sets)
    for r, bag in zip(results[:2], two_bags, strict=True):
        assert r.session == bag and not r.error and r.blocks == 1200
        assert r.metrics == direct.rerun and r.recorded_metrics == direct.recorded
        assert r.comparison['differing_overrides'] == direct.differing_overrides
    assert results[2].error.endswith('not a rosbag2 folder (no metadata.yaml)')
    totals = replay_totals(results)
    assert (totals['sessions'], totals['failed'], totals['blocks']) == (3, 1, 2400)
    assert totals['comparison']['differing_overrides'] == 2 * direct.differing_overrides
    # Two equal sessions: the block-weighted means and the maxima are each one's.
    assert totals['metrics'] == pytest.approx(direct.rerun, rel=1e-12)


# -- Dask -------------------------------------------------------------------------------------

def test_a_sweep_on_dask_is_the_local_one(dask_cluster, swept, short_fig8, reference_bag):
    on_dask = sweep(short_fig8, GRID, dask=dask_cluster.scheduler_address, progress=False)
    assert on_dask.table == swept.table
    assert on_dask.ran_on == f'dask {dask_cluster.scheduler_address}'
    grid = ['force_estimator.kalman_force_noise_n=2.0,8.0']
    local = sweep(None, grid, replay=reference_bag, jobs=1, progress=False)
    assert sweep(None, grid, replay=reference_bag, dask=dask_cluster.scheduler_address,
                 progress=False).table == local.table


def test_several_sessions_on_dask_are_the_local_replays(dask_cluster, two_bags):
    from distributed import Client

    sets = ['force_estimator.kalman_force_noise_n=4.0']
    with Client(dask_cluster) as client:
        on_dask = replay_sessions(two_bags, sets, dask=client)
    assert on_dask == replay_sessions(two_bags, sets, jobs=1)


def test_dask_not_installed_is_one_error_naming_the_extra(short_fig8, monkeypatch):
    monkeypatch.setitem(sys.modules, 'distributed', None)   # what an install without it gives
    with pytest.raises(TurningForceError, match=r"--dask: dask.distributed is not installed; "
                                                r"pip install 'turning_force\[dask\]'"):
        sweep(short_fig8, GRID, dask='tcp://127.0.0.1:8786', progress=False)


def test_pyarrow_not_installed_is_one_error_naming_the_extra(swept, tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, 'pyarrow', None)
    with pytest.raises(TurningForceError, match=r"writing Parquet needs pyarrow; pip install "
                                                r"'turning_force\[parquet\]', or write \.csv"):
        swept.write(tmp_path / 't.parquet')
