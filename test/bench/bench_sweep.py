"""Parameter sweeps of Park 1998 Fig. 8 (12 s simulated, 1200 periods a point): the sweep on
every local core beside the ways there were before it, in one run.

Prints:

- ``turning-force sweep``'s API on all cores: 10,000 points (100 x 100: the SMC's lambda and
  boundary layer; the first sweep of the process, so the start of the workers is in it), wall
  time, points per second and milliseconds per point; and 100 points (the issue's row: 87 s
  through the CLI, 18.5 s through the Python API on 2 processes before the kernel);
- the API in this process (``jobs=1``), on 500 points, extrapolated to 10,000;
- the old ways: ``Experiment.with_sets`` + ``simulate`` in a loop (the Python API serial) on
  200 points, and ``turning-force run --core --json`` once per point (a fresh process each)
  on 3 points, both extrapolated to 100 and 10,000;
- what a point costs in a worker: ``Experiment.with_sets`` against the field replacement the
  workers use, and ``simulate`` on the kernel.

Run: ``.venv/bin/python test/bench/bench_sweep.py`` (or ``make bench``). Measures; asserts
nothing (``test/core/test_sweep.py`` holds the sweep to ``simulate``).
"""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

from turning_force.commands import sweep as sweep_module
from turning_force.commands.sweep import parse_grid, sweep
from turning_force.core import kernel
from turning_force.core.experiment import load_experiment
from turning_force.core.kernel.simulate import simulate

ROOT = Path(__file__).resolve().parents[2]
FIG8 = ROOT / 'config' / 'experiments' / 'park1998_fig8.yaml'
COMMAND = Path(sys.executable).with_name('turning-force')
LAMBDA = 'force_controller.smc_lambda_per_s'
EPSILON = 'force_controller.smc_epsilon_n'


def grid(n: int) -> list[str]:
    """n x n points: lambda 2-20 1/s (the Eq. 24 bound at 100 Hz), epsilon 50-400 N."""
    return [f'{LAMBDA}=2:20:{n}', f'{EPSILON}=50:400:{n}']


def row(label: str, points: int, seconds: float, measured: int | None = None) -> str:
    note = '' if measured is None or measured == points else f'  (from {measured} points)'
    return (f'  {label:46s} {points:7d} {seconds:9.1f} {points / seconds:9.1f} '
            f'{seconds / points * 1e3:9.2f}{note}')


def main() -> int:
    fig8 = load_experiment(FIG8)
    cores = len(os.sched_getaffinity(0))
    print(f'Park 1998 Fig. 8 sweeps (12 s, 1200 periods a point) on {cores} cores; kernel '
          f'cache {"warm" if kernel.cache_is_warm() else "cold"}', flush=True)
    print(f'  {"":46s} {"points":>7s} {"wall [s]":>9s} {"points/s":>9s} {"ms/point":>9s}')

    start = time.perf_counter()
    big = sweep(fig8, grid(100), progress=False)
    wall = time.perf_counter() - start
    paths = {r['kernel'] for r in big.table}
    print(row(f'sweep API, {big.ran_on}, cold start', len(big.table), wall), flush=True)
    print(f'    errors {len(big.errors)}; kernel paths {sorted(paths)}; best '
          f'{big.best()[0]["steady_mean_abs_error_n"]:.3f} N at '
          f'{", ".join(big.point_sets(big.best()[0]))}', flush=True)
    start = time.perf_counter()
    hundred = sweep(fig8, grid(10), progress=False)
    print(row(f'sweep API, {hundred.ran_on}, forkserver running', 100,
              time.perf_counter() - start), flush=True)

    start = time.perf_counter()
    kernel.load()
    print(f'    (the kernel loaded in this process in {time.perf_counter() - start:.1f} s; the '
          'first sweep of a process starts the forkserver, which loads it once for its '
          'workers)')
    start = time.perf_counter()
    serial = sweep(fig8, [grid(20)[0], f'{EPSILON}=50:400:25'], jobs=1, progress=False)
    seconds = time.perf_counter() - start
    print(row('sweep API, this process (jobs=1)', 10_000, seconds / 500 * 10_000, 500))
    assert len(serial.table) == 500

    points = [[f'{LAMBDA}={2 + 18 * k / 199}', f'{EPSILON}=200.0'] for k in range(200)]
    start = time.perf_counter()
    for sets in points:
        simulate(fig8.with_sets(sets))
    seconds = time.perf_counter() - start
    print(row('old: with_sets + simulate, serial', 100, seconds / 200 * 100, 200))
    print(row('old: with_sets + simulate, serial', 10_000, seconds / 200 * 10_000, 200),
          flush=True)

    start = time.perf_counter()
    for k in range(3):
        subprocess.run([str(COMMAND), 'run', '--core', '--json', str(FIG8), '--set',
                        f'{LAMBDA}={5 + 5 * k}'], check=True, capture_output=True)
    seconds = time.perf_counter() - start
    print(row('old: turning-force run --core per point', 100, seconds / 3 * 100, 3))
    print(row('old: turning-force run --core per point', 10_000, seconds / 3 * 10_000, 3),
          flush=True)

    print('  a point in a worker [us]:')
    axes = parse_grid(grid(100))
    texts = tuple(tuple(a.set_text(v) for v in a.values) for a in axes)
    fast = tuple(('force_controller', a.name.split('.')[1], a.values) for a in axes)
    job = sweep_module._Job(fig8, (), texts, start=fig8, fast=fast)

    def per_point_us(what: str, run, count: int) -> None:
        start = time.perf_counter()
        for k in range(count):
            run(k)
        print(f'    {what:44s} {(time.perf_counter() - start) / count * 1e6:9.0f}')

    built: dict = {}
    per_point_us('Experiment.with_sets', lambda k: fig8.with_sets(job.point_sets(k)), 500)
    per_point_us('fields replaced (what the workers do)', lambda k: job.experiment(k, built),
                 500)
    experiments = [job.experiment(k, built) for k in range(200)]
    per_point_us('simulate on the kernel, metrics included', lambda k: simulate(experiments[k]),
                 200)
    return 0


if __name__ == '__main__':
    sys.exit(main())
