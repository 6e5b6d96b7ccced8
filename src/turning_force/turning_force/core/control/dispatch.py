"""The compiled dispatch to the laws installed: a module written for them, into the compiled
code's cache folder, and imported.

numba calls a function it knows when it compiles the caller; it cannot keep a caller that takes
a function as an argument in its cache. So the choice of law is a chain of ``if kind == ...``
over every law's ``step``, ``reset``, ``finite``, ``sent`` and ``adopt``, written here as
source: one file per set of laws (the cache folder is named for them,
:mod:`turning_force.core.codecache`), so that a law another package installs runs compiled
like ours, and is cached like ours.
"""

from __future__ import annotations

import importlib.util
import os
import sys
import tempfile
from pathlib import Path
from types import ModuleType

from turning_force.core.codecache import cache_dir
from turning_force.core.control.registry import CONTROLLERS, names

__all__ = ['MODULE', 'load', 'source']

MODULE = 'turning_force_law_dispatch'
_HOOKS = {
    'step': ('cp, cs, force, rate, out', None),
    'reset': ('cp, cs', None),
    'finite': ('cp, cs', 'True'),
    'sent': ('cp, cs, level', None),
    'adopt': ('cp, cs, cause, size', 'False'),
}


def source() -> str:
    """The dispatch module's source for the laws installed (their order is their number)."""
    laws = [(kind, CONTROLLERS[name]) for kind, name in enumerate(names())]
    lines = ['"""The control laws\' compiled dispatch, written by '
             'turning_force.core.control.dispatch', 'for the laws installed:', '']
    lines += [f'{kind}: {law.name} ({law.module.__name__})' for kind, law in laws]
    lines += ['"""', '', 'from turning_force.core.compiled import compiled']
    for kind, law in laws:
        for hook in _HOOKS:
            if callable(getattr(law.module, hook, None)):
                lines.append(f'from {law.module.__name__} import {hook} as {hook}_{kind}')
    for hook, (args, otherwise) in _HOOKS.items():
        lines += ['', '', '@compiled', f'def {hook}(kind, {args}):']
        branches = [kind for kind, law in laws if callable(getattr(law.module, hook, None))]
        for i, kind in enumerate(branches):
            call = f'{hook}_{kind}({args})'
            lines += [f'    {"if" if i == 0 else "elif"} kind == {kind}:',
                      f'        return {call}' if otherwise else f'        {call}']
        lines.append(f'    return {otherwise}' if otherwise else '    return None')
    return '\n'.join(lines) + '\n'


def load() -> ModuleType:
    """The dispatch module, written into the cache folder if it is not there yet (a file that
    stays as it is keeps numba's cache of it valid)."""
    if MODULE in sys.modules:
        return sys.modules[MODULE]
    text = source()
    folder = cache_dir()
    path = folder / 'law_dispatch.py'
    if not path.is_file() or path.read_text() != text:
        folder.mkdir(parents=True, exist_ok=True)
        _write_atomically(path, text)
    spec = importlib.util.spec_from_file_location(MODULE, path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[MODULE] = module
    spec.loader.exec_module(module)
    return module


def _write_atomically(path: Path, text: str) -> None:
    """Another process may be reading it: write beside it, then rename."""
    handle, temporary = tempfile.mkstemp(dir=path.parent, suffix='.tmp')
    try:
        with os.fdopen(handle, 'w') as out:
            out.write(text)
        os.replace(temporary, path)
    except BaseException:
        Path(temporary).unlink(missing_ok=True)
        raise
