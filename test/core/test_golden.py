"""Every experiment file against its golden trace (test/golden/, made by make_golden.py on a
CPU without AVX-512 dispatch): the true force, the estimate, the request and the applied override
of every block, and the metrics. The tolerances and why are in make_golden.py. The same runs
interpreted (numba's own switch, ``NUMBA_DISABLE_JIT=1``) and through numba's dispatchers where
the kernel compiled ahead of time is loaded (``TURNING_FORCE_AOT=0``) are held to the same
traces: the compiled and the readable code are one."""

import json
import os
import subprocess
import sys

import pytest

from golden.make_golden import EXPERIMENTS, HERE, golden_run, problems

FILES = sorted(EXPERIMENTS.glob('*.yaml'))


def test_every_experiment_file_has_a_golden_trace():
    assert {p.stem for p in FILES} == {p.stem for p in HERE.glob('*.npz')}
    assert set(json.loads((HERE / 'metrics.json').read_text())) == {p.stem for p in FILES}


@pytest.mark.parametrize('path', FILES, ids=[p.stem for p in FILES])
def test_the_run_is_its_golden_trace(path):
    traces, metrics = golden_run(path)
    assert problems(path.stem, traces, metrics) == []


def test_a_changed_behaviour_is_caught(tmp_path):
    # The comparison is not blind: a run of another setting against fig8's trace is refused,
    # by trace and by metric.
    from turning_force.core.experiment import load_experiment
    from turning_force.core.kernel.simulate import simulate

    result = simulate(load_experiment(EXPERIMENTS / 'park1998_fig8.yaml').with_sets(
        ['force_controller.smc_epsilon_n=9.0']))
    traces = {name: result.trace[name] for name in ('force_n', 'estimated_force_n',
                                                     'requested_override_pct',
                                                     'applied_override_pct')}
    found = problems('park1998_fig8', traces, result.metrics)
    assert any('applied override differs first at block' in p for p in found)
    assert any('metric steady_mean_abs_error_n' in p for p in found)


@pytest.mark.parametrize('how', [('NUMBA_DISABLE_JIT', '1', 'interpreted'),
                                 ('TURNING_FORCE_AOT', '0', 'just in time')],
                         ids=['interpreted', 'just-in-time'])
def test_the_other_ways_to_run_are_the_golden_traces_too(how):
    # Every file once more with numba off (the functions run as the Python they are written
    # in), and once through numba's dispatchers (where this process may run the kernel
    # compiled ahead of time, core/aot.py).
    variable, value, mode = how
    code = ('import json; from golden.make_golden import EXPERIMENTS, golden_run, problems; '
            'from turning_force.core import kernel; '
            'print(json.dumps([p for f in sorted(EXPERIMENTS.glob("*.yaml")) '
            'for p in problems(f.stem, *golden_run(f))] + [kernel.mode()]))')
    env = {**os.environ, variable: value,
           'PYTHONPATH': os.pathsep.join([str(HERE.parent), os.environ.get('PYTHONPATH', '')])}
    run = subprocess.run([sys.executable, '-c', code], env=env, capture_output=True, text=True,
                         timeout=600, check=False)
    assert run.returncode == 0, run.stderr[-2000:]
    assert json.loads(run.stdout) == [mode]
