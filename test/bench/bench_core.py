"""The core loop on the compiled kernel beside the plain Python reference, in one run.

Prints, side by side so that the ratios hold on a noisy machine:

- Park 1998 Fig. 8 (12 s, 1200 periods) through the core loop, the reference and the kernel:
  realtime factor and microseconds per 10 ms period, min / median of several runs, and the
  largest difference between their traces (the kernel is bit for bit the reference);
- the kernel alone on an hour of cutting (Fig. 8's cut, 360,000 periods);
- start-up of ``turning-force run --core --json`` to the first period (a one-period run, in a
  fresh process): the default (a short run stays in Python, numba is not imported), and the
  kernel forced from the first period (``TURNING_FORCE_KERNEL=on``) with numba's cache cold
  (compiling) and warm (loading); and the import time of the command;
- every row of the robustness matrix (turning_force.commands.robustness) both ways.

Run: ``.venv/bin/python test/bench/bench_core.py`` (or ``make bench``). Measures; asserts
nothing (``test/core/test_kernel.py`` holds the kernel to the reference).
"""

from __future__ import annotations

import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from turning_force.commands import robustness
from turning_force.core import kernel
from turning_force.core.experiment import load_experiment
from turning_force.core.simulate import simulate

ROOT = Path(__file__).resolve().parents[2]
EXPERIMENTS = ROOT / 'config' / 'experiments'
FIG8 = EXPERIMENTS / 'park1998_fig8.yaml'
COMMAND = Path(sys.executable).with_name('turning-force')


def timed_runs(experiment, compiled: bool, runs: int) -> tuple[list[float], object]:
    times, result = [], None
    for _ in range(runs):
        start = time.perf_counter()
        result = simulate(experiment, compiled=compiled)
        times.append(time.perf_counter() - start)
    return times, result


def row(label: str, simulated_s: float, periods: int, times: list[float]) -> str:
    best, median = min(times), statistics.median(times)
    return (f'{label:34s} {simulated_s / best:9.0f} {simulated_s / median:9.0f} '
            f'{best / periods * 1e6:9.2f} {median / periods * 1e6:9.2f} {len(times):5d}')


def startup(env: dict[str, str], runs: int) -> list[float]:
    """Wall seconds of a one-period ``run --core --json`` in a fresh process."""
    argv = [str(COMMAND), 'run', '--core', '--json', str(FIG8), '--set',
            'experiment.duration_s=0.01']
    times = []
    for _ in range(runs):
        start = time.perf_counter()
        subprocess.run(argv, env=env, check=True, capture_output=True)
        times.append(time.perf_counter() - start)
    return times


def import_time_s() -> float:
    """``python -X importtime``'s cumulative time of importing the command's module."""
    out = subprocess.run([sys.executable, '-X', 'importtime', '-c', 'import turning_force.cli'],
                         check=True, capture_output=True, text=True).stderr
    line = next(x for x in out.splitlines() if x.rstrip().endswith('| turning_force.cli'))
    return int(line.split('|')[1]) / 1e6


def main() -> int:
    print(f'kernel: numba, cache {"warm" if kernel.cache_is_warm() else "cold"}; loading ...',
          flush=True)
    start = time.perf_counter()
    kernel.load()
    print(f'kernel loaded in {time.perf_counter() - start:.2f} s (in this process)\n')

    e = load_experiment(FIG8)
    simulate(e, compiled=True)   # first call: set-up caches
    py_times, reference = timed_runs(e, False, 3)
    k_times, compiled = timed_runs(e, True, 7)
    worst = max(float(np.max(np.abs(compiled.trace[n] - reference.trace[n])))
                for n in reference.trace)
    hour = e.with_sets(['experiment.duration_s=3600.0'])
    h_times, _ = timed_runs(hour, True, 3)

    header = (f'{"core loop":34s} {"RTF min":>9s} {"RTF med":>9s} {"us/per":>9s} '
              f'{"us/p med":>9s} {"runs":>5s}')
    print(header)
    print('-' * len(header))
    print(row('fig8 12 s, Python reference', 12.0, 1200, py_times))
    print(row('fig8 12 s, compiled kernel', 12.0, 1200, k_times))
    print(row('fig8 cut, 1 hour, compiled kernel', 3600.0, 360000, h_times))
    ratio = statistics.median(py_times) / statistics.median(k_times)
    print(f'kernel / reference (median): {ratio:.0f}x; largest trace difference: {worst:g}\n')

    env = dict(os.environ)
    env.pop(kernel.ENV, None)
    default = startup(env, 5)
    with tempfile.TemporaryDirectory() as cache:
        forced = {**env, kernel.ENV: 'on', 'NUMBA_CACHE_DIR': cache}
        cold = startup(forced, 1)
        warm = startup(forced, 5)
    header = f'{"start-up, one-period run --core (s)":44s} {"min":>7s} {"median":>7s} {"runs":>5s}'
    print(header)
    print('-' * len(header))
    for label, times in (('default (short run: Python, no numba)', default),
                         ('kernel forced, numba cache cold (compiles)', cold),
                         ('kernel forced, numba cache warm (loads)', warm)):
        print(f'{label:44s} {min(times):7.3f} {statistics.median(times):7.3f} '
              f'{len(times):5d}')
    print(f'{"import turning_force.cli (-X importtime)":44s} {import_time_s():7.3f}\n')

    header = (f'{"robustness matrix row":24s} {"law":9s} {"Python s":>9s} {"kernel s":>9s} '
              f'{"ratio":>7s} {"same":>5s}')
    print(header)
    print('-' * len(header))
    total_py = total_k = 0.0
    for scenario in robustness.MATRIX:
        for law in robustness.CONTROLLERS:
            x = robustness.scenario_experiment(EXPERIMENTS, scenario, law)
            (t_py,), slow = timed_runs(x, False, 1)
            (t_k,), fast = timed_runs(x, True, 1)
            same = all(np.array_equal(slow.trace[n], fast.trace[n], equal_nan=True)
                       for n in slow.trace)
            total_py, total_k = total_py + t_py, total_k + t_k
            print(f'{scenario.name if law == "smc" else "":24s} {law:9s} {t_py:9.3f} '
                  f'{t_k:9.4f} {t_py / t_k:7.0f} {"yes" if same else "NO":>5s}', flush=True)
    print(f'{"all rows":34s} {total_py:9.2f} {total_k:9.3f} {total_py / total_k:7.0f}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
