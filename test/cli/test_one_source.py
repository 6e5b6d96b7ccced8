"""One source: every algorithm is one compiled function, and every path of the product runs it.

For each path (the node graph, the core loop, replay, a sweep), a probe replaces one function at
a time, wherever a module holds it, under ``NUMBA_DISABLE_JIT=1`` (where a compiled caller looks
it up as the Python it is) and the path is run: the probe must be reached, so no second copy of
the algorithm serves that path. The plant is not on replay's path (it replays recorded
currents). Each law's ``step`` is probed with that law chosen.

"""

import os
import subprocess
import sys
from pathlib import Path

import pytest

PROBE = Path(__file__).with_name('one_source_probe.py')
LAWS = [f'turning_force.core.control.laws.{law}:step@{law}'
        for law in ('smc', 'pi', 'adaptive', 'adaptive_smc', 'adaptive_pp', 'staircase', 'mpc')]
ALGORITHMS = ['turning_force.core.plant.lathe:plant_step',
              'turning_force.core.estimation.estimator:estimator_update',
              'turning_force.core.control.update:controller_update', *LAWS,
              'turning_force.core.pmc.gate:gate_on_estimate',
              'turning_force.core.pmc.gate:gate_answer',
              'turning_force.core.pmc.gate:_observe', 'turning_force.core.pmc.gate:_judge']


@pytest.mark.parametrize('path', ['run', 'run-core', 'replay', 'sweep'])
def test_every_path_reaches_each_algorithm_s_one_function(path):
    env = {**os.environ, 'NUMBA_DISABLE_JIT': '1'}
    probe = subprocess.run([sys.executable, str(PROBE), path, *ALGORITHMS], env=env,
                           capture_output=True, text=True, timeout=300, check=False)
    assert probe.returncode == 0, probe.stderr[-3000:]
    lines = [line for line in probe.stdout.splitlines() if 'reached' in line]
    expected = [f'not reached: {name} on {path}' if (path, name) == ('replay', ALGORITHMS[0])
                else f'reached {name} on {path}' for name in ALGORITHMS]
    assert lines == expected
