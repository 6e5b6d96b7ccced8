"""The compiled core loop, in one run:

- Park 1998 Fig. 8 (12 s, 1200 periods): realtime factor and microseconds per 10 ms period,
  min / median of several runs; and an hour of cutting (Fig. 8's cut, 360,000 periods);
- start-up of ``turning-force run --core --json`` to the first period (a one-period run, in a
  fresh process) with numba's cache warm (loading) and cold (compiling); and the import time of
  the command;
- every row of the robustness matrix (turning_force.commands.robustness).

Run: ``.venv/bin/python test/bench/bench_core.py`` (or ``make bench-all``). Measures; asserts
nothing.
"""

from __future__ import annotations

import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from turning_force.commands import robustness
from turning_force.core import kernel
from turning_force.core.experiment import load_experiment
from turning_force.core.kernel.simulate import simulate

ROOT = Path(__file__).resolve().parents[2]
EXPERIMENTS = ROOT / 'config' / 'experiments'
FIG8 = EXPERIMENTS / 'park1998_fig8.yaml'
COMMAND = Path(sys.executable).with_name('turning-force')


def timed_runs(experiment, runs: int) -> tuple[list[float], object]:
    times, result = [], None
    for _ in range(runs):
        start = time.perf_counter()
        result = simulate(experiment)
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
    simulate(e)   # first call: set-up caches
    k_times, _ = timed_runs(e, 7)
    hour = e.with_sets(['experiment.duration_s=3600.0'])
    h_times, _ = timed_runs(hour, 3)

    header = (f'{"core loop":34s} {"RTF min":>9s} {"RTF med":>9s} {"us/per":>9s} '
              f'{"us/p med":>9s} {"runs":>5s}')
    print(header)
    print('-' * len(header))
    print(row('fig8 12 s', 12.0, 1200, k_times))
    print(row('fig8 cut, 1 hour', 3600.0, 360000, h_times))
    print()

    warm = startup(dict(os.environ), 5)
    with tempfile.TemporaryDirectory() as cache:
        cold = startup({**os.environ, 'NUMBA_CACHE_DIR': cache}, 1)
    header = f'{"start-up, one-period run --core (s)":44s} {"min":>7s} {"median":>7s} {"runs":>5s}'
    print(header)
    print('-' * len(header))
    for label, times in (('numba cache warm (loads)', warm),
                         ('numba cache cold (compiles)', cold)):
        print(f'{label:44s} {min(times):7.3f} {statistics.median(times):7.3f} '
              f'{len(times):5d}')
    print(f'{"import turning_force.cli (-X importtime)":44s} {import_time_s():7.3f}\n')

    header = f'{"robustness matrix row":24s} {"law":9s} {"s":>9s}'
    print(header)
    print('-' * len(header))
    total = 0.0
    for scenario in robustness.MATRIX:
        for law in robustness.CONTROLLERS:
            x = robustness.scenario_experiment(EXPERIMENTS, scenario, law)
            (t_k,), _ = timed_runs(x, 1)
            total += t_k
            print(f'{scenario.name if law == "smc" else "":24s} {law:9s} {t_k:9.4f}',
                  flush=True)
    print(f'{"all rows":34s} {total:9.3f}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
