"""The one switchboard of compiled code: numba's options, where its machine code is cached,
and the scalar rules every compiled algorithm shares.

Each algorithm is written once, in the module of its stage of the signal chain (the plant in
:mod:`.plant.lathe`, the estimator in :mod:`.estimation.estimator`, each control law in its
module of :mod:`.control.laws`, the PMC gate in :mod:`.pmc.gate`), as functions decorated here:
:func:`compiled` for the algorithm's own functions, :func:`entry` for the few that Python calls,
with their signatures. Under ``NUMBA_DISABLE_JIT=1`` they run as the Python they are written in.

Decorating imports no numba: a module of compiled code costs what its Python costs to import,
so that reading settings (which live beside the code that reads them) stays cheap.
:func:`activate` (called by :func:`turning_force.core.kernel.load`) makes every entry point
the function of the module compiled ahead of time (:mod:`.aot`: numba is not imported) where
the cache folder has one, else imports numba and makes every function decorated so far a numba
dispatcher, in its module and in every module that imported it by name; what is decorated after
it is compiled as it is defined (or where Python calls it). An entry point is compiled
for its signature (or loaded from the cache) at its first call, so that a run loads the machine
code of the entry points it calls and no other; with a warm cache the other functions'
dispatchers wait until Python calls one or a compilation needs them. numba's machine code goes to
:func:`turning_force.core.codecache.cache_dir`, never into the installed package.
"""

from __future__ import annotations

import math
import os
import sys
import threading
import time
import types
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any, TypeVar, cast

import numpy as np

from turning_force.core import aot
from turning_force.core.codecache import cache_dir, cache_is_warm, installed_laws

__all__ = ['AHEAD', 'INTERPRETED', 'JUST_IN_TIME', 'Arr', 'activate', 'active', 'build_ahead',
           'compiled', 'delayed', 'entry', 'in_one_chunk', 'isclose', 'mode', 'npsign',
           'pairwise_sum', 'pymax', 'pymin', 'pymod', 'quantise', 'requeue']

_F = TypeVar('_F', bound=Callable[..., Any])
_T = TypeVar('_T')
Arr = np.ndarray   # float64, C-contiguous: what the entry points' signatures say

# What is decorated before activate(): each function with its entry signature ('' if none).
_pending: list[tuple[Callable[..., Any], str]] = []
_entries: list[tuple[Callable[..., Any], str]] = []   # every entry point, in their order
_active = False
AHEAD, JUST_IN_TIME, INTERPRETED = 'ahead of time', 'just in time', 'interpreted'
_mode = ''
_lock = threading.RLock()
_OPTIONS: dict[str, Any] = {'cache': True, 'error_model': 'numpy', 'nogil': True}


def compiled(function: _F) -> _F:
    """numba's options for every compiled function: cached on disk, numpy's error model (a
    division by zero gives IEEE infinities), the GIL released. Compiled at its first call."""
    with _lock:
        if _active:
            if _mode == AHEAD:   # numba's, where Python calls it (:class:`_Deferred`)
                return cast(_F, _Deferred(function))
            _materialize()
            return cast(_F, _jit(function, ''))
        _pending.append((function, ''))
        return function


def entry(signature: str) -> Callable[[_F], _F]:
    """An entry point from Python: compiled for ``signature`` (or loaded from the cache) at its
    first call and closed to other types, so that no call from Python compiles on its way.
    Compiled ahead of time as well (:mod:`.aot`): its own body only passes its arguments on."""
    def decorate(function: _F) -> _F:
        with _lock:
            _entries.append((function, signature))
            if _active:
                if _mode != AHEAD:
                    _materialize()
                return cast(_F, _jit(function, signature))
            _pending.append((function, signature))
            return function
    return decorate


def active() -> bool:
    """Whether :func:`activate` has run in this process."""
    return _active


def mode() -> str:
    """How the compiled functions run in this process: :data:`AHEAD` (the module compiled
    ahead of time, :mod:`.aot`), :data:`JUST_IN_TIME` (numba's dispatchers),
    :data:`INTERPRETED` (``NUMBA_DISABLE_JIT=1``), '' before :func:`activate`."""
    return _mode


def activate() -> float:
    """Compile every function decorated so far (see the module's text); the seconds it took.

    Where the module compiled ahead of time for today's sources is in the cache folder
    (:mod:`.aot`), the entry points are its functions and numba is not imported: the other
    compiled functions become numba's only if Python calls one. Else numba's dispatchers,
    loaded from its cache (numba checks a cached function's own file only, not the files of
    what it calls: the cache folder is named for every source's hash, :mod:`.codecache`)."""
    global _active, _mode
    with _lock:
        if _active:
            return 0.0
        start = time.perf_counter()
        ahead = None if _jit_disabled() else aot.load()
        warm = True
        if ahead is not None:
            made = {id(function): (function, _Deferred(function) if not signature
                                   else aot.Checked(getattr(ahead, function.__name__),
                                                    function, signature)
                                   if hasattr(ahead, function.__name__)
                                   else _jit(function, signature))
                    for function, signature in _pending}
            _mode = AHEAD
        else:
            numba = _numba()
            warm = cache_is_warm()
            if not warm:
                print(f'turning_force: compiling the kernel into {cache_dir()} (once per '
                      'install and version: 15 to 60 s)', file=sys.stderr, flush=True)
            # With a warm cache an entry point's machine code is read whole: nothing else is
            # compiled, and the other functions' dispatchers (a millisecond each) wait until
            # Python calls one or a compilation needs them (_materialize).
            disabled = numba.config.DISABLE_JIT
            made = {id(function): (function, _Deferred(function) if warm and not disabled
                                   and not signature else _jit(function, signature))
                    for function, signature in _pending}
            _mode = INTERPRETED if disabled else JUST_IN_TIME
        _rebind(made, {function.__module__ for function, _ in _pending})
        if not warm:   # compile them all now, and say how long it took
            for _, compiled_function in made.values():
                if isinstance(compiled_function, _Entry):
                    compiled_function.load()
        _pending.clear()
        _active = True
        return time.perf_counter() - start


def build_ahead() -> Path | None:
    """Compile every entry point ahead of time (:func:`.aot.build`) from numba's dispatchers
    (this process's kernel loaded just in time); None where another process is at it."""
    with _lock:
        if _mode != JUST_IN_TIME:
            raise RuntimeError(f'the kernel is loaded {_mode or "nowhere"}, not just in time')
        _materialize()
        return in_one_chunk(lambda: aot.build(list(_entries)))


def _roomy(call: Callable[[], _T]) -> _T:
    return call()


# CPython 3.11 and 3.12 keep the frames' data in 16 KiB chunks, each mapped when a call
# crosses into it and unmapped when the call returns (gh-142183, fixed in 3.13 and 3.14 in
# 2026). numba's compiler recurses back and forth over such a boundary where the stack's
# depth happens to put one: compiling the kernel under `turning-force run` mapped and unmapped
# a chunk 1.2 million times, 8 s of the system's time in 44 s (36 s in one chunk). A frame of
# ROOMY_SLOTS local slots (528 kB) is given a chunk of 1 MiB of its own, and what it calls
# runs in the half that it leaves free (test_compiled.py).
ROOMY_SLOTS = 66_000
_in_chunk = cast(Callable[[Callable[[], Any]], Any], types.FunctionType(_roomy.__code__.replace(
    co_varnames=(*_roomy.__code__.co_varnames, *(f'_{i}' for i in range(ROOMY_SLOTS))),
    co_nlocals=_roomy.__code__.co_nlocals + ROOMY_SLOTS), globals()))


def in_one_chunk(call: Callable[[], _T]) -> _T:
    """``call()``, its frames and those of all it calls in one chunk of Python's frame stack
    (see ROOMY_SLOTS): what compiles numba's machine code runs through this."""
    return cast(_T, _in_chunk(call))


def _jit_disabled() -> bool:
    """numba's own switch (``NUMBA_DISABLE_JIT``), read without importing numba."""
    return os.environ.get('NUMBA_DISABLE_JIT', '').strip() not in ('', '0')


def _rebind(made: Mapping[int, tuple[Any, Any]], owners: set[str]) -> None:
    """Every module that holds one of the functions by name gets what it was made into
    (numba resolves a compiled function's globals when it compiles it)."""
    for name, module in list(sys.modules.items()):
        if module is None or not (name in owners or name.startswith('turning_force')):
            continue
        namespace = vars(module)
        for key, value in list(namespace.items()):
            found = made.get(id(value))
            if found is not None and found[0] is value:
                namespace[key] = found[1]


_deferred: list[_Deferred] = []


def _materialize() -> bool:
    """The deferred functions' dispatchers, made and bound in every module that holds them;
    False where there were none."""
    with _lock:
        if not _deferred:
            return False
        made = {id(d): (d, _dispatcher(d.py_func)) for d in _deferred}
        _rebind(made, {d.py_func.__module__ for d in _deferred})
        for d in _deferred:
            d.dispatcher = made[id(d)][1]
        _deferred.clear()
        return True


class _Deferred:
    """A compiled function whose dispatcher is not made yet (:func:`activate`): a call from
    Python makes every deferred one's, then runs."""

    def __init__(self, function: Callable[..., Any]) -> None:
        self.py_func = function
        self.__doc__, self.__name__ = function.__doc__, function.__name__
        self.dispatcher: Any = None
        _deferred.append(self)

    def __call__(self, *args: Any) -> Any:
        _materialize()
        return self.dispatcher(*args)


class _Entry:
    """An entry point: numba's dispatcher, compiled for its signature at the first call and
    then closed to any other (a call with other types is an error, not a compilation on the
    way)."""

    def __init__(self, function: Callable[..., Any], signature: str) -> None:
        self.py_func, self._signature = function, signature
        self._dispatcher: Any = None
        self._call: Callable[..., Any] = self._first
        self.__doc__, self.__name__ = function.__doc__, function.__name__

    def __call__(self, *args: Any) -> Any:
        return self._call(*args)

    def load(self) -> None:
        """Compile it for its signature now, or load it from the cache (where the cache
        misses, numba compiles it, and the functions it calls need their dispatchers)."""
        with _lock:
            if self._dispatcher is None or self._call is not self._dispatcher:
                in_one_chunk(self._compile)
                self._call = self._dispatcher

    def _compile(self) -> None:
        self._dispatcher = _dispatcher(self.py_func)
        try:
            self._dispatcher.compile(self._signature)
        except Exception:
            if not _materialize():
                raise
            # numba keeps a failed compilation's error: a fresh dispatcher tries again.
            self._dispatcher = _dispatcher(self.py_func)
            self._dispatcher.compile(self._signature)
        self._dispatcher.disable_compile()

    def _first(self, *args: Any) -> Any:
        self.load()
        return self._call(*args)

    def __getattr__(self, name: str) -> Any:   # signatures, ...
        if name.startswith('_'):
            raise AttributeError(name)
        if self._dispatcher is None:
            self.load()
        return getattr(self._dispatcher, name)


_numba_ready = False


def _numba() -> Any:
    """numba, imported, its cache in :func:`cache_dir` (and, with a warm cache and only our
    laws, its CPU target set up without its check for a BLAS)."""
    global _numba_ready
    import numba
    with _lock:
        if not _numba_ready:
            numba.config.CACHE_DIR = str(cache_dir())   # type: ignore[attr-defined]
            if cache_is_warm() and not installed_laws():
                _target_without_blas()
            _numba_ready = True
    return numba


def _target_without_blas() -> None:
    """numba's CPU target, set up without its check for a BLAS.

    numba looks for a BLAS (for ``np.dot`` and ``np.linalg``) by importing ``scipy.linalg``,
    a fifth of a short run's start-up (0.14 s of 0.65). Our compiled code calls no BLAS
    (``test_kernel`` reads its sources for it), and with a warm cache nothing is compiled:
    so where only our laws are installed the check finds none. A law another package installs
    may use one: then numba checks as it always does."""
    from numba.core.registry import cpu_target

    hidden = 'scipy.linalg.cython_blas'
    if 'scipy.linalg' in sys.modules:   # already paid for: nothing to save
        cpu_target.target_context.refresh()
        return
    sys.modules[hidden] = None   # type: ignore[assignment]
    try:
        cpu_target.target_context.refresh()
    finally:
        del sys.modules[hidden]


def _dispatcher(function: _F) -> Any:
    """numba's dispatcher of ``function`` (the function itself under ``NUMBA_DISABLE_JIT``)."""
    return _numba().njit(**_OPTIONS)(function)


def _jit(function: _F, signature: str) -> Any:
    """numba's dispatcher of ``function``, an entry point's behind :class:`_Entry` (made at
    its first call)."""
    if signature and not _jit_disabled():
        return _Entry(function, signature)
    return _dispatcher(function)


# --- Python's and numpy's scalar rules, as the golden traces have them ----------------------

@compiled
def pymax(a: float, b: float) -> float:
    """Python's ``max(a, b)``: the first of equals."""
    return b if b > a else a


@compiled
def pymin(a: float, b: float) -> float:
    """Python's ``min(a, b)``."""
    return b if b < a else a


@compiled
def pymod(a: float, b: float) -> float:
    """Python's float ``%`` (and ``np.mod``): numba's ``%`` follows CPython's float_rem."""
    return a % b


@compiled
def npsign(x: float) -> float:
    if x > 0.0:
        return 1.0
    if x < 0.0:
        return -1.0
    if x == 0.0:
        return 0.0
    return x


@compiled
def isclose(a: float, b: float, rel_tol: float) -> bool:
    """``math.isclose(a, b, rel_tol=rel_tol)``."""
    if a == b:
        return True
    if math.isinf(a) or math.isinf(b):
        return False
    diff = abs(b - a)
    return diff <= abs(rel_tol * b) or diff <= abs(rel_tol * a) or diff <= 0.0


@compiled
def _pairwise_leaf(a: np.ndarray, lo: int, n: int) -> float:
    """numpy's pairwise sum of up to 128 values: eight running sums, then a tree."""
    if n < 8:
        res = 0.0
        for i in range(n):
            res += a[lo + i]
        return res
    r0, r1, r2, r3 = a[lo], a[lo + 1], a[lo + 2], a[lo + 3]
    r4, r5, r6, r7 = a[lo + 4], a[lo + 5], a[lo + 6], a[lo + 7]
    i = 8
    while i < n - (n % 8):
        r0 += a[lo + i]
        r1 += a[lo + i + 1]
        r2 += a[lo + i + 2]
        r3 += a[lo + i + 3]
        r4 += a[lo + i + 4]
        r5 += a[lo + i + 5]
        r6 += a[lo + i + 6]
        r7 += a[lo + i + 7]
        i += 8
    res = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
    while i < n:
        res += a[lo + i]
        i += 1
    return res


@compiled
def pairwise_sum(a: np.ndarray, lo: int, n: int) -> float:
    """numpy's pairwise summation (``np.add.reduce``, and so ``np.mean``) of a[lo:lo+n]:
    past 128 values, the halves (the first a multiple of 8) summed alike and added. The
    recursion is unrolled on a stack: numba's cache does not keep recursive functions."""
    if n <= 128:
        return _pairwise_leaf(a, lo, n)
    los = np.empty(64, np.int64)
    ns = np.empty(64, np.int64)
    stage = np.zeros(64, np.int64)
    left = np.empty(64)
    top = 0
    los[0], ns[0] = lo, n
    ret = 0.0
    while True:
        cl, cn = los[top], ns[top]
        if cn <= 128:
            ret = _pairwise_leaf(a, cl, cn)
            top -= 1
            continue
        half = cn // 2
        half -= half % 8
        if stage[top] == 0:
            stage[top] = 1
            top += 1
            los[top], ns[top], stage[top] = cl, half, 0
        elif stage[top] == 1:
            left[top] = ret
            stage[top] = 2
            top += 1
            los[top], ns[top], stage[top] = cl + half, cn - half, 0
        else:
            ret = left[top] + ret
            top -= 1
            if top < 0:
                return ret


@compiled
def quantise(levels: np.ndarray, continuous: bool, pct: float) -> float:
    """OverrideTable.quantise on a finite request."""
    x = pymin(pymax(pct, levels[0]), levels[levels.size - 1])
    if continuous:
        return x
    lo_i, hi_i = 0, levels.size     # bisect_left
    while lo_i < hi_i:
        mid = (lo_i + hi_i) // 2
        if levels[mid] < x:
            lo_i = mid + 1
        else:
            hi_i = mid
    upper = min(max(lo_i, 1), levels.size - 1)
    lo, hi = levels[upper - 1], levels[upper]
    return hi if hi - x < x - lo else lo


# --- the feed drive (core/drive.py) ---------------------------------------------------------


@compiled
def delayed(state: np.ndarray, queue_at: int, index_slot: int, length: int,
            value: float) -> float:
    """A dead time of ``length`` samples: ``value`` goes in, the value put in ``length`` samples
    ago comes out (``length`` 0: ``value`` itself). The line is state[queue_at:queue_at +
    length], its next place state[index_slot]: the PMC's dead time in the plant and its model
    in the sliding mode law's Smith predictor."""
    if length <= 0:
        return value
    q = int(state[index_slot])
    out = state[queue_at + q]
    state[queue_at + q] = value
    state[index_slot] = (q + 1) % length
    return out


@compiled
def requeue(state: np.ndarray, queue_at: int, index_slot: int, was: int, length: int,
            held: float) -> None:
    """A dead time of ``was`` samples (:func:`delayed`) made ``length`` long, the values
    pending in their order: for a longer one the oldest repeated before them, for a shorter
    one the oldest dropped (none pending: ``held``). The line starts again at its first
    place: a model of the PMC's dead time taking the one the drift monitor named."""
    at = int(state[index_slot])
    pending = np.empty(max(was, 1))
    if was <= 0:
        pending[0] = held
    for j in range(was):
        pending[j] = state[queue_at + (at + j) % was]
    for j in range(length):
        state[queue_at + j] = pending[max(j - (length - pending.size), 0)]
    state[index_slot] = 0.0


@compiled
def table_row(table: np.ndarray, key: float) -> int:
    """The first row of ``table`` whose column 0 is ``key`` (a tool's number in a per-tool
    table), -1 where none is."""
    for row in range(table.shape[0]):
        if table[row, 0] == key:
            return row
    return -1
