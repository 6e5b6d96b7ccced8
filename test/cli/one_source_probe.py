"""Run one path of the product with one compiled function replaced by a probe that raises, under
numba's own switch (``NUMBA_DISABLE_JIT=1``: the functions are the Python they are written in,
so a compiled caller looks the probe up as it would the function). Prints what reached it.

    python one_source_probe.py PATH MODULE:FUNCTION[@LAW] ...   (test_one_source.py runs it)

One line per function: ``reached MODULE:FUNCTION on PATH`` or ``not reached: ...``; with
``@LAW``, the run's control law is LAW.
"""

from __future__ import annotations

import importlib
import sys
import tempfile
from pathlib import Path
from types import ModuleType

ROOT = Path(__file__).resolve().parents[2]
FIG8 = ROOT / 'config' / 'experiments' / 'park1998_fig8.yaml'
REFERENCE = ROOT / 'bags' / 'reference' / 'park1998_fig8'
SHORT = 'experiment.duration_s=0.3'


class Reached(Exception):
    """The probe was called."""


def bound(spec: str) -> list[tuple[ModuleType, str, object]]:
    """Every module that holds the compiled function ``MODULE:FUNCTION`` (its own, those that
    import it, the laws' generated dispatch), under whichever name: a compiled caller looks it
    up in its module."""
    from turning_force.core import kernel

    kernel.load()
    module_name, _, function = spec.partition(':')
    original = getattr(importlib.import_module(module_name), function)
    places = [(module, key, value) for name, module in list(sys.modules.items())
              if name.startswith('turning_force') and module is not None
              for key, value in list(vars(module).items()) if value is original]
    assert places, spec
    return places


def main() -> None:
    path, functions = sys.argv[1], sys.argv[2:]
    for spec in functions:
        function, _, law = spec.partition('@')
        places = bound(function)

        def probe(*args: object, name: str = function) -> None:
            raise Reached(name)

        for module, key, _ in places:
            setattr(module, key, probe)
        try:
            run(path, function, law)
        except Reached:
            print(f'reached {spec} on {path}', flush=True)
        else:
            print(f'not reached: {spec} on {path}', flush=True)
        finally:
            for module, key, original in places:
                setattr(module, key, original)


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
            if function.partition(':')[2] in errors or 'Reached' in errors:
                raise Reached(function)
        else:
            raise SystemExit(f'unknown path {path!r}')


if __name__ == '__main__':
    main()
