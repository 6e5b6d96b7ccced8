"""Run one path of the product with one compiled function replaced by a probe that raises, under
numba's own switch (``NUMBA_DISABLE_JIT=1``: the functions are the Python they are written in,
so a compiled caller looks the probe up as it would the function). Prints what reached it.

    python one_source_probe.py PATH FUNCTION[@LAW] ...   (test_one_source.py runs it)

One line per function: ``reached FUNCTION on PATH`` or ``not reached: FUNCTION on PATH``; with
``@LAW``, the run's control law is LAW.
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
FIG8 = ROOT / 'config' / 'experiments' / 'park1998_fig8.yaml'
REFERENCE = ROOT / 'bags' / 'reference' / 'park1998_fig8'
SHORT = 'experiment.duration_s=0.3'


class Reached(Exception):
    """The probe was called."""


def main() -> None:
    path, functions = sys.argv[1], sys.argv[2:]
    from turning_force.core import kernel

    jit = kernel.load()
    for spec in functions:
        function, _, law = spec.partition('@')
        original = getattr(jit, function)
        assert callable(original), function

        def probe(*args: object, name: str = function) -> None:
            raise Reached(name)

        setattr(jit, function, probe)
        try:
            run(path, function, law)
        except Reached:
            print(f'reached {spec} on {path}', flush=True)
        else:
            print(f'not reached: {spec} on {path}', flush=True)
        finally:
            setattr(jit, function, original)


def run(path: str, function: str, law: str) -> None:
    from turning_force import cli

    sets = ['--set', SHORT] + (['--set', f'force_controller.controller={law}'] if law else [])
    with tempfile.TemporaryDirectory() as tmp:
        if path == 'run':     # the node graph, lock-step on the simulator
            cli.main(['run', str(FIG8), *sets, '--out', f'{tmp}/session'])
        elif path == 'run-core':
            cli.main(['run', str(FIG8), '--core', *sets])
        elif path == 'replay':
            cli.main(['replay', str(REFERENCE), *sets[2:]])
        elif path == 'sweep':
            from turning_force.commands.sweep import sweep

            result = sweep(FIG8, ['force_controller.smc_lambda_per_s=5:10:2'],
                           sets=[s for s in sets if s != '--set'], jobs=1, progress=False)
            errors = ' '.join(map(str, getattr(result, 'errors', []) or []))
            if function in errors or 'Reached' in errors:
                raise Reached(function)
        else:
            raise SystemExit(f'unknown path {path!r}')


if __name__ == '__main__':
    main()
