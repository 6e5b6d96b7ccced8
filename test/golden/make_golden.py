"""Write the golden traces: every experiment file in config/experiments run through the core loop
(compiled), its true force, force estimate, requested and applied override per block, and its
metrics, into test/golden/ (``<experiment>.npz`` and ``metrics.json``).

They are made on a CPU without AVX-512 dispatch, as the issue asks: this script runs itself again
with numpy's AVX-512 kernels off (``NPY_DISABLE_CPU_FEATURES``) and numba compiling for a generic
x86-64 (``NUMBA_CPU_NAME=generic``), whatever machine it is on. ``test/core/test_golden.py`` holds
every later run to them. Run it when a change alters behaviour on purpose, and say in the commit
which metrics moved and by how much (it prints them, old beside new)::

    .venv/bin/python test/golden/make_golden.py
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
EXPERIMENTS = HERE.parents[1] / 'config' / 'experiments'
# What is stored per block (the core loop's trace names).
COLUMNS = ('force_n', 'estimated_force_n', 'requested_override_pct', 'applied_override_pct')
PORTABLE = {'NPY_DISABLE_CPU_FEATURES': 'X86_V4 AVX512_ICL AVX512_SPR',
            'NUMBA_CPU_NAME': 'generic'}


def golden_run(path: Path) -> tuple[dict[str, np.ndarray], dict[str, float]]:
    """The experiment's traces (COLUMNS) and metrics (without the wall-clock one)."""
    from turning_force.core.experiment import load_experiment
    from turning_force.core.kernel.simulate import simulate

    result = simulate(load_experiment(path))
    metrics = {k: v for k, v in result.metrics.items() if k != 'realtime_factor'}
    return {name: result.trace[name] for name in COLUMNS}, metrics


# Tolerances, argued. Every path runs the same compiled functions, so a run on another CPU
# differs from these traces only where the arithmetic itself does: a transcendental function of
# another libm or SIMD kernel (numpy's AVX-512 power differed from libm's in the last bit,
# 2.2e-16 relative). A last-bit difference in a continuous value grows through the loop, most of
# all through an adaptive law's estimates (hwang1990_example1's force rate moved by 4e-8
# relative after 1.5 s when the plant alone differed); 1e-9 relative (of the trace's own scale,
# so that values near zero are held alike) leaves that a hundred-fold margin over the ulp and
# would still catch any change of behaviour, which moves these values by far more. Override
# levels are held equal: a level that differs is a different decision, and the message says how
# far the request was from the quantiser's nearest boundary, the one case where a last-bit
# difference could flip it.
RTOL = 1e-9


def problems(stem: str, traces: dict[str, np.ndarray], metrics: dict[str, float]) -> list[str]:
    """What differs between a run of experiment ``stem`` and its golden trace ('' where none)."""
    golden = np.load(HERE / f'{stem}.npz')
    found = []
    for name in COLUMNS:
        want, got = golden[name], traces[name]
        if want.shape != got.shape:
            found.append(f'{stem}: {name}: {got.shape} blocks, golden {want.shape}')
            continue
        if name == 'applied_override_pct':
            bad = np.flatnonzero(got != want)
            if bad.size:
                k = int(bad[0])
                request = traces['requested_override_pct'][max(k - 1, 0)]
                found.append(f'{stem}: applied override differs first at block {k}: {got[k]!r} '
                             f'against {want[k]!r} (the request before it: {request!r} %)')
            continue
        scale = float(np.max(np.abs(want))) if want.size else 0.0
        off = np.abs(got - want) > RTOL * np.maximum(np.abs(want), scale)
        if np.any(off):
            k = int(np.flatnonzero(off)[0])
            found.append(f'{stem}: {name} differs first at block {k}: {got[k]!r} against '
                         f'{want[k]!r} ({int(off.sum())} blocks past {RTOL:g} relative)')
    stored = json.loads((HERE / 'metrics.json').read_text())[stem]
    if set(stored) != set(metrics):
        found.append(f'{stem}: metrics {sorted(metrics)} against {sorted(stored)}')
    for name, want_value in stored.items():
        value = metrics.get(name, float('nan'))
        if not abs(value - want_value) <= RTOL * max(abs(want_value), 1.0):
            found.append(f'{stem}: metric {name} = {value!r} against {want_value!r}')
    return found


def main() -> None:
    if any(os.environ.get(k) != v for k, v in PORTABLE.items()):
        env = {**os.environ, **PORTABLE}
        sys.exit(subprocess.run([sys.executable, __file__], env=env, check=False).returncode)
    old_file = HERE / 'metrics.json'
    old = json.loads(old_file.read_text()) if old_file.exists() else {}
    metrics = {}
    for path in sorted(EXPERIMENTS.glob('*.yaml')):
        traces, metrics[path.stem] = golden_run(path)
        np.savez_compressed(HERE / f'{path.stem}.npz', **traces)
        for name, value in metrics[path.stem].items():
            before = old.get(path.stem, {}).get(name)
            if before != value:
                print(f'{path.stem:22} {name:28} {before!s:>22} -> {value!r}')
    old_file.write_text(json.dumps(metrics, indent=1, sort_keys=True) + '\n')
    print(f'{len(metrics)} experiments written to {HERE}')


if __name__ == '__main__':
    main()
