"""Issue 9's table, every row measured in one run: the old path beside the new where the old
path still exists, the ratio, the target, and whether it is met.

Rows (Park 1998 Fig. 8 throughout; min / median of ``--runs`` runs where a row repeats):

1. the core loop's realtime factor: issue 9's Python reference (gone: its measured figure)
   and the compiled kernel;
2. the lock-step graph's realtime factor (``run_lockstep``): the old path (``fast=False``: a
   ``/clock`` subscription per node, the recorder writing on the executor thread, its clock read
   per message) on the SingleThreadedExecutor and on the EventsExecutor, and today's graph;
3. replay of a one-hour session (written first by ``run --core --out``, 360,000 blocks):
   ``turning-force replay`` in a fresh process; old: the old reader (rosbags' CDR per message,
   a block object per block: ``bench_sessions.read_old``, measured) plus the Python chain per
   block (measured on the first ``OLD_REPLAY_BLOCKS`` blocks, scaled to the hour);
4. report of that session: ``turning-force report``; old: the old reader alone (measured; the
   old report read the session that way, and drew every point, so its time was more);
5. peak resident memory reading it back (the child's ``ru_maxrss``): old reader, new reader,
   report, replay;
6. reading a 10-minute session (issue 14): our reader (scan + codec) beside the libraries alone
   (mcap's reader, rosbags' CDR per message, the currents stacked): ours is kept where it is
   at least 10x faster;
7. start-up to the first period: a one-period ``turning-force run --core`` in a fresh process,
   and the import time of the command; Fig. 8 as a user types it (12 s) and 600 s of it, the
   whole command's wall and CPU (issue 14);
8. sweeps: 100 and 10,000 points of a fig8 grid through ``commands.sweep`` on all cores;
   old: ``turning-force run --core`` once per point (3 measured, scaled) and the Python API
   serially (``with_sets`` + ``simulate``, 200 measured, scaled);
9. the real-time graph's block-to-override latency as lathe_sim publishes it on
   ``/diagnostics`` (``bench_realtime.measure``): one process, five processes (as ``ros2 run``
   starts them), and both under SCHED_FIFO where the machine grants it; the old one-process
   path on the SingleThreadedExecutor beside them.

Measures; asserts nothing. ``--realtime-s`` sets each real-time graph's measured time (default
30 s after 10 s of warm-up; ``--realtime-s 600`` is the issue's 10-minute soak).
Run: ``make bench`` (this table) or ``.venv/bin/python test/bench/bench_table.py``.
"""

from __future__ import annotations

import argparse
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))

import bench_realtime
import bench_sessions

from turning_force.core import kernel
from turning_force.core.experiment import load_experiment
from turning_force.core.kernel import batch
from turning_force.core.kernel.simulate import simulate

ROOT = Path(__file__).resolve().parents[2]
FIG8 = ROOT / 'config' / 'experiments' / 'park1998_fig8.yaml'
COMMAND = str(Path(sys.executable).with_name('turning-force'))
OLD_REPLAY_BLOCKS = 12_000   # 2 minutes of the hour through the Python chain, scaled by 30
LAMBDA, EPSILON = 'force_controller.smc_lambda_per_s', 'force_controller.smc_epsilon_n'

Row = tuple[str, str, str, str, str]   # what, old, new, ratio, target (met?)
ROWS: list[Row] = []


def add(what: str, old: str, new: str, ratio: str, target: str) -> None:
    ROWS.append((what, old, new, ratio, target))
    print(f'  {what}: old {old}; new {new}; {ratio}; target {target}', flush=True)


def times(function: Callable[[], Any], runs: int) -> list[float]:
    out = []
    for _ in range(runs):
        start = time.perf_counter()
        function()
        out.append(time.perf_counter() - start)
    return out


def span(values: list[float], fmt: str = '.1f', scale: float = 1.0, unit: str = '') -> str:
    """'min / median' of ``values * scale``."""
    low, mid = min(values) * scale, statistics.median(values) * scale
    return f'{low:{fmt}} / {mid:{fmt}}{unit}' if len(values) > 1 else f'{low:{fmt}}{unit}'


def met(ok: bool) -> str:
    return 'met' if ok else 'NOT met'


def core_loop(runs: int) -> None:
    fig8 = load_experiment(FIG8)
    kernel.load()
    simulate(fig8)   # warm
    new = times(lambda: simulate(fig8), runs)
    sim_s = fig8.run.duration_s
    rf_new = [sim_s / t for t in new]
    # The Python reference is gone (one source, issue 14): its figure is issue 9's measurement.
    add('fig8 core loop (run --core), realtime factor [x] (min/median)',
        "22 / 23 (issue 9's Python reference)",
        f'{min(rf_new):.0f} / {statistics.median(rf_new):.0f}',
        f'{statistics.median(rf_new) / 23:.0f}x faster',
        f'>= 1000x: {met(statistics.median(rf_new) >= 1000)}')


def lockstep(runs: int) -> None:
    from turning_force.commands.run import run_lockstep

    fig8 = load_experiment(FIG8)

    def best(**kwargs: Any) -> float:
        factors = []
        with tempfile.TemporaryDirectory() as tmp:
            for k in range(runs):
                outcome = run_lockstep(fig8, Path(tmp) / f'run{k}', **kwargs)
                factors.append(outcome.realtime_factor)
        return max(factors)

    single = best(fast=False, executor_kind='single')
    events_old = best(fast=False)
    now = best()
    add('fig8 lock-step graph (run), realtime factor [x] (best of runs)',
        f'{single:.1f} (SingleThreaded), {events_old:.1f} (Events)', f'{now:.1f}',
        f'{now / single:.1f}x / {now / events_old:.2f}x', f'>= 15x: {met(now >= 15)}')


def hour_session(folder: Path, runs: int) -> None:
    bag = folder / 'fig8_hour'
    wall, mb, _ = bench_sessions.timed([COMMAND, 'run', str(FIG8), '--core', '--out', str(bag),
                                        '--json', '--set', 'experiment.duration_s=3600'])
    print(f'  (one hour of fig8 recorded by run --core --out in {wall:.1f} s, peak {mb:.0f} MB)',
          flush=True)
    me = [sys.executable, str(Path(bench_sessions.__file__).resolve()), '--child']
    old_read = bench_sessions.timed([*me, 'old', str(bag)])
    new_read = bench_sessions.timed([*me, 'new', str(bag)])
    replays = [bench_sessions.timed([COMMAND, 'replay', str(bag), '--json'])
               for _ in range(runs)]
    reports = [bench_sessions.timed([COMMAND, 'report', str(bag), '--out',
                                     str(folder / 'hour.png')]) for _ in range(runs)]
    old_chain = old_chain_seconds(bag)
    replay_s = [r[0] for r in replays]
    report_s = [r[0] for r in reports]
    old_replay = old_read[0] + old_chain
    add('replay of a one-hour session [s] (min/median)',
        f'{old_replay:.0f} (read {old_read[0]:.0f} + Python chain {old_chain:.0f}, scaled from '
        f'{OLD_REPLAY_BLOCKS} blocks)', span(replay_s),
        f'{old_replay / statistics.median(replay_s):.0f}x faster',
        f'<= 10 s: {met(statistics.median(replay_s) <= 10)}')
    add('report of a one-hour session [s] (min/median)',
        f'> {old_read[0]:.0f} (the old reading alone)', span(report_s),
        f'> {old_read[0] / statistics.median(report_s):.0f}x faster',
        f'<= 10 s: {met(statistics.median(report_s) <= 10)}')
    add('peak memory reading back a one-hour session [MB]', f'{old_read[1]:.0f}',
        f'{new_read[1]:.0f} (read), {max(r[1] for r in reports):.0f} (report), '
        f'{max(r[1] for r in replays):.0f} (replay)',
        f'{old_read[1] / new_read[1]:.1f}x less',
        f'<= 400 MB reading back: {met(new_read[1] <= 400)}; report '
        f'{met(max(r[1] for r in reports) <= 400)}; replay '
        f'{met(max(r[1] for r in replays) <= 400)}')


def old_chain_seconds(bag: Path) -> float:
    """The Python chain (the reference, block by block, as replay ran before the kernel) on
    the session's first ``OLD_REPLAY_BLOCKS`` blocks, scaled to all of them."""
    from turning_force.session.reader import read_session

    session = read_session(bag)
    assert session.currents is not None and session.experiment is not None
    n = len(session.currents)
    first = batch.CurrentArrays(
        session.currents.t0_s[:OLD_REPLAY_BLOCKS], session.currents.sample_period_s,
        session.currents.phase_u_a[:OLD_REPLAY_BLOCKS],
        session.currents.phase_v_a[:OLD_REPLAY_BLOCKS],
        session.currents.rotor_angle_rad[:OLD_REPLAY_BLOCKS],
        session.currents.feed_rate_mm_min[:OLD_REPLAY_BLOCKS])
    start = time.perf_counter()
    batch._replay_blocks(session.experiment, first.block, len(first), session.arm_changes,
                         None, None)
    return (time.perf_counter() - start) * n / OLD_REPLAY_BLOCKS


def libraries_read_s(bag: Path) -> float:
    """Reading a session with the libraries alone (issue 14), as well as they allow:
    :func:`bench_sessions.read_libraries`."""
    from bench_sessions import read_libraries

    start = time.perf_counter()
    read_libraries(bag)
    return time.perf_counter() - start


def session_reading(folder: Path, runs: int) -> None:
    """Our session reader (scan + codec) beside mcap + rosbags on a 10-minute session: ours is
    kept where it is at least 10x faster (issue 14)."""
    from turning_force.session.reader import read_session

    bag = folder / 'ten_minutes'
    if not bag.exists():
        subprocess.run([COMMAND, 'run', str(FIG8), '--core', '--out', str(bag), '--set',
                        'experiment.duration_s=600'], check=True, capture_output=True)
    ours = times(lambda: read_session(bag), runs)
    libraries = [libraries_read_s(bag)]
    ratio = libraries[0] / statistics.median(ours)
    add('read a 10-minute session (60,000 blocks) [s]', f'{span(libraries, ".2f")} '
        '(mcap + rosbags)', f'{span(ours, ".2f")} (our scan + codec)', f'{ratio:.0f}x',
        f'>= 10x to keep ours: {met(ratio >= 10)}')


def command_runs(argv: list[str], runs: int) -> tuple[list[float], list[float]]:
    """Wall and CPU (user + system) seconds of ``argv``, run ``runs`` times as a user types it:
    the page cache warm, and no ``PYTHONDONTWRITEBYTECODE`` (which compiles every import from
    source, 0.1 s more)."""
    env = {k: v for k, v in os.environ.items() if k != 'PYTHONDONTWRITEBYTECODE'}
    subprocess.run(argv, check=True, capture_output=True, env=env)
    walls, cpus = [], []
    for _ in range(runs):
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        start = time.perf_counter()
        subprocess.run(argv, check=True, capture_output=True, env=env)
        walls.append(time.perf_counter() - start)
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
        cpus.append(after.ru_utime + after.ru_stime - before.ru_utime - before.ru_stime)
    return walls, cpus


def startup(runs: int) -> None:
    typed = [COMMAND, 'run', '--core', str(FIG8)]
    walls, cpus = command_runs([*typed, '--set', 'experiment.duration_s=0.01'], runs)
    out = subprocess.run([sys.executable, '-X', 'importtime', '-c', 'import turning_force.cli'],
                         check=True, capture_output=True, text=True).stderr
    line = next(x for x in out.splitlines() if x.rstrip().endswith('| turning_force.cli'))
    imports = int(line.split('|')[1]) / 1e6
    add('turning-force start-up to the first period [s] (min/median)',
        "1.1 (the issue's figure: the old imports are gone)",
        f'{span(walls, ".2f")} (process), {span(cpus, ".2f")} CPU, imports {imports:.2f}', '',
        f'<= 0.4 s: {met(min(walls) <= 0.4)} (min), {met(statistics.median(walls) <= 0.4)} '
        '(median)')
    # Issue 14: Fig. 8 as a user types it (12 s), and 600 s of it, the whole command's wall.
    walls, cpus = command_runs(typed, runs)
    add('fig8 run --core as typed (12 s), whole command [s] (min/median)',
        "0.81-0.84 (issue 14's figure, numba's dispatchers)",
        f'{span(walls, ".2f")} wall, {span(cpus, ".2f")} CPU', '',
        f'<= 0.5 s: {met(min(walls) <= 0.5)} (min), {met(statistics.median(walls) <= 0.5)} '
        '(median)')
    walls, cpus = command_runs([*typed, '--set', 'experiment.duration_s=600'], runs)
    factors = sorted(600.0 / w for w in walls)
    add('fig8 run --core, 600 s, whole command, realtime factor [x] (max/median)',
        "860-885 (issue 14's figure, numba's dispatchers)",
        f'{factors[-1]:.0f} / {statistics.median(factors):.0f} ({span(cpus, ".2f")} s CPU)', '',
        f'>= 1000x: {met(factors[-1] >= 1000)} (best), '
        f'{met(statistics.median(factors) >= 1000)} (median)')


def sweeps() -> None:
    from turning_force.commands.sweep import sweep

    fig8 = load_experiment(FIG8)
    grid_100 = [f'{LAMBDA}=2:20:10', f'{EPSILON}=50:400:10']
    grid_10k = [f'{LAMBDA}=2:20:100', f'{EPSILON}=50:400:100']
    start = time.perf_counter()
    big = sweep(fig8, grid_10k, progress=False)
    big_s = time.perf_counter() - start
    start = time.perf_counter()
    sweep(fig8, grid_100, progress=False)
    small_s = time.perf_counter() - start
    points = [[f'{LAMBDA}={2 + 18 * k / 199}', f'{EPSILON}=200.0'] for k in range(200)]
    start = time.perf_counter()
    for sets in points:
        simulate(fig8.with_sets(sets))
    serial_point = (time.perf_counter() - start) / 200
    start = time.perf_counter()
    for k in range(3):
        subprocess.run([COMMAND, 'run', '--core', '--json', str(FIG8), '--set',
                        f'{LAMBDA}={5 + 5 * k}'], check=True, capture_output=True)
    cli_point = (time.perf_counter() - start) / 3
    add('100-point parameter sweep of fig8 [s]',
        f'{cli_point * 100:.0f} (CLI per point), {serial_point * 100:.0f} (API serial, Python)',
        f'{small_s:.1f} (sweep, {big.ran_on}, pool warm)', f'{cli_point * 100 / small_s:.0f}x',
        '')
    add('10,000-point parameter sweep of fig8 [s]',
        f'{cli_point * 10_000:.0f} (CLI per point), {serial_point * 10_000:.0f} (API serial)',
        f'{big_s:.1f} (sweep, cold start, {len(big.errors)} errors)',
        f'{serial_point * 10_000 / big_s:.0f}x', f'<= 60 s: {met(big_s <= 60)}')


def realtime(seconds: float, warmup: float) -> None:
    graphs = [('one process, EventsExecutor', ['turning_force_graph'], 'events'),
              ('one process, SingleThreaded (old)', ['turning_force_graph'], 'single'),
              ('five processes, EventsExecutor', list(bench_realtime.SPLIT), 'events')]
    if bench_realtime.fifo_granted():
        graphs += [('one process, SCHED_FIFO 50', ['turning_force_graph'], 'events'),
                   ('five processes, SCHED_FIFO 50', list(bench_realtime.SPLIT), 'events')]
    results = {label: bench_realtime.measure(label, exes, seconds, warmup, executor)
               for label, exes, executor in graphs}

    def shown(label: str) -> str:
        r = results.get(label)
        return ('not granted here' if r is None else
                f'p50 {r["p50"]:.2f}, p99 {r["p99"]:.2f}, max {r["max"]:.1f} ms, missed '
                f'{r["missed"]}/{r["blocks"]}')

    old = results['one process, SingleThreaded (old)']
    for label, limit in (('one process, EventsExecutor', 1.5),
                         ('one process, SCHED_FIFO 50', 1.5),
                         ('five processes, EventsExecutor', 3.0),
                         ('five processes, SCHED_FIFO 50', 3.0)):
        r = results.get(label)
        add(f'real-time graph {label}, block -> override, {seconds:g} s at 100 Hz',
            shown('one process, SingleThreaded (old)') if label.startswith('one') else '',
            shown(label), '' if r is None else f'p99 {old["p99"] / r["p99"]:.1f}x lower',
            '' if r is None else f'p99 <= {limit} ms: {met(r["p99"] <= limit)}; 0 missed: '
            f'{met(r["missed"] == 0)}')


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--runs', type=int, default=3)
    parser.add_argument('--realtime-s', type=float, default=30.0)
    parser.add_argument('--warmup-s', type=float, default=10.0)
    parser.add_argument('--keep', help='folder for the one-hour session (kept)')
    args = parser.parse_args()
    print(f'issue 9 table: {os.cpu_count()} cores, load {os.getloadavg()[0]:.1f}; kernel '
          f'cache {"warm" if kernel.cache_is_warm() else "cold"}', flush=True)
    core_loop(args.runs)
    lockstep(max(args.runs - 1, 1))
    folder = Path(args.keep or tempfile.mkdtemp(prefix='bench_table_'))
    folder.mkdir(parents=True, exist_ok=True)
    hour_session(folder, args.runs)
    session_reading(folder, args.runs)
    startup(max(args.runs, 5))
    sweeps()
    realtime(args.realtime_s, args.warmup_s)
    widths = [max(len(r[i]) for r in [('what', 'old', 'new', 'ratio', 'target'), *ROWS])
              for i in range(5)]
    print()
    print(' | '.join(h.ljust(w) for h, w in zip(('what', 'old', 'new', 'ratio', 'target'),
                                                 widths, strict=True)))
    print('-|-'.join('-' * w for w in widths))
    for row in ROWS:
        print(' | '.join(c.ljust(w) for c, w in zip(row, widths, strict=True)))
    print(f'load average at the end {os.getloadavg()[0]:.1f}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
