"""The kernel compiled ahead of time: the entry points as a CPython extension module in the
compiled code's cache folder, loaded without importing numba.

numba's own start-up (its import, 0.3 s, and its CPU target's set-up, 0.2-0.35 s) is more than
a short run's whole budget. So the entry points (:func:`turning_force.core.compiled.entry`,
with their signatures) are compiled once more, by numba's ahead-of-time compiler
(``numba.pycc``, pending deprecation since numba 0.57 and still shipped by 0.68), from the same
decorated functions, into one extension module. It needs numpy, not numba, to run: the module
and numba's runtime it carries in C (the reference counts of arrays, numba's helpers) load in a
millisecond.

It lives beside numba's cache (:func:`turning_force.core.codecache.cache_dir`, a folder named
for the hash of every compiled source and every installed law), so a change of any of them
never meets an old module; its name says the CPU it was compiled for (``NUMBA_CPU_NAME``, else
this host's), numba's bounds checks and numpy's version. :func:`turning_force.core.kernel.load`
builds it where it compiled numba's cache (a new install or version), ``make setup``
(:func:`turning_force.core.kernel.prepare`) where it is missing; where it is missing or cannot
be built, the kernel is loaded just in time as before, never run as interpreted Python.
"""

from __future__ import annotations

import contextlib
import fcntl
import hashlib
import importlib
import importlib.machinery
import importlib.util
import os
import re
import sys
import tempfile
import warnings
from collections.abc import Callable, Sequence
from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np

from turning_force.core.codecache import cache_dir

__all__ = ['Checked', 'build', 'cpu_name', 'load', 'module_name', 'path', 'switched_off']


def cpu_name() -> str:
    """The CPU the module is compiled for: ``NUMBA_CPU_NAME`` as numba reads it, else 'host'."""
    return os.environ.get('NUMBA_CPU_NAME', '').strip() or 'host'


def _host_features() -> str:
    """What 'host' compiles for, where the cache folder is shared by machines (a home folder on
    the network): the processor's model and instruction set extensions as Linux lists them
    (empty where it does not). A module compiled for one processor's extensions never loads on
    another's, where it could stop on an illegal instruction."""
    try:
        text = Path('/proc/cpuinfo').read_text(errors='replace')
    except OSError:
        return ''
    keep = ('model name', 'flags')
    lines = [line for line in text.splitlines() if line.split(':')[0].strip() in keep]
    return '|'.join(dict.fromkeys(lines))   # the first processor's, once


def module_name() -> str:
    """The extension module's name: what it was compiled for (the CPU, and for 'host' this
    processor's model and extensions; bounds checks; numpy)."""
    host = _host_features() if cpu_name() == 'host' else ''
    key = f'{cpu_name()}|{host}|{os.environ.get("NUMBA_BOUNDSCHECK", "")}|{np.__version__}'
    cpu = re.sub(r'\W', '_', cpu_name())
    return f'turning_force_aot_{cpu}_{hashlib.sha256(key.encode()).hexdigest()[:10]}'


def path() -> Path:
    """Where the module is (or goes): the compiled code's cache folder."""
    suffix = importlib.machinery.EXTENSION_SUFFIXES[0]
    return cache_dir() / f'{module_name()}{suffix}'


def switched_off() -> bool:
    """Whether ``TURNING_FORCE_AOT=0`` asks for numba's dispatchers: no module is loaded,
    and none is built."""
    return os.environ.get('TURNING_FORCE_AOT', '').strip() == '0'


def load() -> ModuleType | None:
    """The module compiled ahead of time for today's sources, or None where there is none, it
    does not load (it is built again the next time numba's cache is) or ``TURNING_FORCE_AOT=0``
    asks for numba's dispatchers (to compare the two, or debug numba's side)."""
    where = path()
    if switched_off() or not where.is_file():
        return None
    name = module_name()
    if name in sys.modules:
        return sys.modules[name]
    loader = importlib.machinery.ExtensionFileLoader(name, str(where))
    spec = importlib.util.spec_from_file_location(name, where, loader=loader)
    if spec is None:
        return None
    try:
        module = importlib.util.module_from_spec(spec)
        loader.exec_module(module)
    except ImportError:
        return None
    sys.modules[name] = module
    return module


def build(entries: Sequence[tuple[Callable[..., Any], str]]) -> Path | None:
    """Compile ``entries`` (each a function and its signature, under numba's hand: every
    function they call a dispatcher) into the module at :func:`path`; None where another
    process is building it now. Raises where numba or the C compiler cannot build it.

    An entry's own body is compiled under numba's default error model (the functions it calls
    keep theirs, numpy's): entry points only pass their arguments on, they divide nothing."""
    where = path()
    where.parent.mkdir(parents=True, exist_ok=True)
    with open(where.parent / f'{module_name()}.lock', 'w') as lock:
        try:
            fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            return None
        with warnings.catch_warnings():
            warnings.simplefilter('ignore')   # pycc's pending deprecation (see the module's text)
            pycc: Any = importlib.import_module('numba.pycc')
        with tempfile.TemporaryDirectory(dir=where.parent) as folder:
            cc = pycc.CC(module_name(), source_module=__name__)
            cc.output_dir = folder
            cc.target_cpu = cpu_name()
            names = [function.__name__ for function, _ in entries]
            if len(set(names)) < len(names):
                raise ValueError(f'entry points share a name: {sorted(names)}')
            for function, signature in entries:
                cc.export(function.__name__, signature)(function)
            with contextlib.redirect_stdout(sys.stderr):   # the C compiler's chatter, if any
                cc.compile()
            os.replace(Path(folder) / cc.output_file, where)
    return where


_ARRAY = re.compile(r'(\w+)(?:\[([^\]]*)\])?')


class Checked:
    """An entry point of the module compiled ahead of time, its arrays checked against its
    signature: the module reads an array's memory as the signature says, so an array of
    another type, shape or layout is a TypeError here, as it is from numba's dispatcher."""

    def __init__(self, compiled: Callable[..., Any], function: Callable[..., Any],
                 signature: str) -> None:
        self._compiled, self.py_func, self.signature = compiled, function, signature
        self.__doc__, self.__name__ = function.__doc__, function.__name__
        arguments = signature[signature.index('(') + 1:signature.rindex(')')]
        self._arrays = tuple((i, np.dtype(m[1]), m[2].count(':') - m[2].count('::'))
                             for i, m in enumerate(_ARRAY.finditer(arguments)) if m[2])
        self._count = sum(1 for _ in _ARRAY.finditer(arguments))

    def __call__(self, *args: Any) -> Any:
        if len(args) != self._count:
            raise TypeError(f'{self.__name__}: {len(args)} arguments, its signature has '
                            f'{self._count}: {self.signature}')
        for i, dtype, ndim in self._arrays:
            a = args[i]
            if not (isinstance(a, np.ndarray) and a.dtype == dtype and a.ndim == ndim
                    and a.flags.c_contiguous and a.flags.writeable):
                raise TypeError(f'{self.__name__}: argument {i} is not {dtype}, {ndim}-d, '
                                f'C-contiguous and writeable: {self.signature}')
        return self._compiled(*args)
