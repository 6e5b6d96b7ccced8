"""The compiled kernel's loader and loops.

Each algorithm is written once, compiled, in the module of its stage of the signal chain: the plant
(:mod:`turning_force.core.plant.lathe`), the estimator
(:mod:`turning_force.core.estimation.estimator`), the control laws
(:mod:`turning_force.core.control.laws`), the PMC gate with the shop floor's behaviours
(:mod:`turning_force.core.pmc.gate`). They run compiled on every path: the nodes one block at a
time (:class:`~turning_force.core.plant.lathe.LathePlant`,
:class:`~turning_force.core.estimation.estimator.ForceEstimator`,
:class:`~turning_force.core.control.base.Controller`,
:class:`~turning_force.core.pmc.gate.OverrideGate`), the loops here (:mod:`.loops`: the core loop,
replay, sweeps) many blocks at once. The same functions run as plain Python under numba's own
switch (``NUMBA_DISABLE_JIT=1``), for debugging and coverage.

:func:`load` imports (and, with a cold cache, compiles: ``cache=True`` keeps the machine code in
:func:`cache_dir`) all of it, before any block runs.
"""

from __future__ import annotations

import contextlib
import sys
import threading
from types import ModuleType

from turning_force.core.codecache import STAMP, cache_dir, cache_is_warm, source_hash

__all__ = ['cache_dir', 'cache_is_warm', 'load', 'loaded']

_lock = threading.Lock()
_module: ModuleType | None = None


def loaded() -> ModuleType | None:
    """The kernel's module if it is loaded in this process, else None (never waits)."""
    return _module


def load() -> ModuleType:
    """The kernel's module, importing (or with a cold cache compiling) it now if need be.

    numba's machine code goes to :func:`cache_dir`, never into the installed package; a
    compilation (a new install or version) says so on stderr, and how long it took."""
    global _module
    with _lock:
        if _module is None:
            where = cache_dir()
            warm = cache_is_warm()
            try:
                from turning_force.core import compiled
                from turning_force.core.kernel import loops as jit
                took = compiled.activate()
            except Exception as exc:   # a broken numba install: say so
                raise RuntimeError(f'the compiled kernel did not load: {exc!r}') from exc
            if not warm:
                print(f'turning_force: kernel compiled in {took:.0f} s', file=sys.stderr,
                      flush=True)
                with contextlib.suppress(OSError):
                    (where / STAMP).write_text(source_hash() + '\n')
            _module = jit
    return _module
