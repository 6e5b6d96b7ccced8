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

:func:`load` imports all of it before any block runs: the module compiled ahead of time
(:mod:`turning_force.core.aot`) where the cache folder has it, else numba's machine code
(``cache=True`` keeps it in :func:`cache_dir`), and with a cold cache it compiles both.
"""

from __future__ import annotations

import contextlib
import sys
import threading
import time
from types import ModuleType

from turning_force.core.codecache import STAMP, cache_dir, cache_is_warm, source_hash

__all__ = ['cache_dir', 'cache_is_warm', 'load', 'loaded', 'mode', 'prepare']

_lock = threading.Lock()
_module: ModuleType | None = None


def loaded() -> ModuleType | None:
    """The kernel's module if it is loaded in this process, else None (never waits)."""
    return _module


def mode() -> str:
    """How the kernel runs in this process: 'ahead of time', 'just in time', 'interpreted'
    (``NUMBA_DISABLE_JIT=1``), '' before :func:`load`."""
    from turning_force.core import compiled
    return compiled.mode()


def load() -> ModuleType:
    """The kernel's module, importing (or with a cold cache compiling) it now if need be.

    numba's machine code goes to :func:`cache_dir`, never into the installed package; a
    compilation (a new install or version) says so on stderr, and how long it took, and then
    compiles the kernel ahead of time as well (:func:`prepare`)."""
    global _module
    warm = True
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
    if not warm:
        _build_ahead()
    return _module


def prepare() -> None:
    """The kernel compiled both ways for the next runs (``make setup``): numba's cache
    (:func:`load`) and the module compiled ahead of time, where it is missing."""
    from turning_force.core import aot, compiled

    load()
    if compiled.mode() == compiled.JUST_IN_TIME and not aot.path().is_file():
        _build_ahead()


def _build_ahead() -> None:
    """Compile the kernel ahead of time into the cache folder (:mod:`turning_force.core.aot`),
    saying so; where it cannot be, say why (the runs load it just in time)."""
    from turning_force.core import aot, compiled

    if compiled.mode() != compiled.JUST_IN_TIME or aot.switched_off():
        return
    print(f'turning_force: compiling the kernel ahead of time into {aot.path()} (once per '
          'install and version: 30 to 90 s)', file=sys.stderr, flush=True)
    start = time.perf_counter()
    try:
        built = compiled.build_ahead()
    except Exception as exc:   # no C compiler, a numba without pycc: the runs load numba's
        print(f'turning_force: the kernel was not compiled ahead of time ({exc!r:.300}): '
              'runs load it just in time (0.6 s more each)', file=sys.stderr, flush=True)
        return
    if built is None:
        print('turning_force: another process is compiling it', file=sys.stderr, flush=True)
    else:
        print(f'turning_force: kernel compiled ahead of time in '
              f'{time.perf_counter() - start:.0f} s', file=sys.stderr, flush=True)
