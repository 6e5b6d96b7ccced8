"""Where numba keeps the compiled code's machine code, without importing numba.

``$NUMBA_CACHE_DIR`` (or the user's cache folder, ``$XDG_CACHE_HOME`` or ``~/.cache``, under
``turning_force/numba``), in a folder named for the hash of every source of
``turning_force.core``, of the control laws other packages install (the ``turning_force.laws``
entry points) and numba's version. numba checks only the file that defines a function
when it reads its cache, not the files of the functions it calls: a folder per version of the
whole core means a change anywhere never pairs with old machine code, and nothing is ever
written into the installed package.
"""

from __future__ import annotations

import functools
import hashlib
import importlib.util
import os
import sys
from pathlib import Path

__all__ = ['LAW_GROUP', 'STAMP', 'cache_dir', 'cache_is_warm', 'installed_laws',
           'source_hash']

LAW_GROUP = 'turning_force.laws'

STAMP = 'turning_force_kernel.sha256'
CORE = Path(__file__).resolve().parent


@functools.cache
def installed_laws() -> tuple[tuple[str, str, str], ...]:
    """The laws other packages install: (name, module, distribution) of each
    ``turning_force.laws`` entry point, by name."""
    if not _may_declare(LAW_GROUP):
        return ()
    import importlib.metadata

    found = []
    for point in importlib.metadata.entry_points(group=LAW_GROUP):
        dist = point.dist.name if point.dist is not None else '?'
        found.append((point.name, point.value.partition(':')[0].strip(), dist))
    return tuple(sorted(found))


def _may_declare(group: str) -> bool:
    """Whether a distribution on ``sys.path`` may declare entry points of ``group``: one's
    entry_points.txt names it, or a path entry is no folder to look in (a zip). A look before
    importlib.metadata, whose import and scan cost 30-60 ms at every start where none does."""
    needle = group.encode()
    for entry in sys.path:
        try:
            with os.scandir(entry or '.') as found:
                folders = [item.path for item in found
                           if item.name.endswith(('.dist-info', '.egg-info'))]
        except NotADirectoryError:
            return True
        except OSError:   # not there
            continue
        for folder in folders:
            try:
                if needle in Path(folder, 'entry_points.txt').read_bytes():
                    return True
            except OSError:
                continue
    return False


@functools.cache
def source_hash() -> str:
    """The SHA-256 of numba's version (its ``_version.py``), where ``turning_force.core`` is
    and every source of it, and the module of every installed law."""
    numba = importlib.util.find_spec('numba')
    version = Path(numba.origin).with_name('_version.py') if numba and numba.origin else None
    digest = hashlib.sha256(version.read_bytes() if version and version.is_file() else b'')
    # numba files a function's machine code under its source file's path: two checkouts of the
    # same sources keep apart, or one's stamp would call the other's cache warm.
    digest.update(str(CORE).encode())
    for path in sorted(CORE.rglob('*.py')):
        digest.update(path.relative_to(CORE).as_posix().encode())
        digest.update(path.read_bytes())
    for name, module, _ in installed_laws():
        digest.update(f'{name}={module}'.encode())
        try:
            spec = importlib.util.find_spec(module)
        except (ImportError, ValueError):   # the registry says what is wrong with it
            continue
        if spec is not None and spec.origin and Path(spec.origin).is_file():
            digest.update(Path(spec.origin).read_bytes())
    return digest.hexdigest()


def cache_dir() -> Path:
    """Where numba keeps the compiled code's machine code (see the module's text)."""
    base = os.environ.get('NUMBA_CACHE_DIR', '').strip()
    if not base:
        home = os.environ.get('XDG_CACHE_HOME', '').strip() or str(Path.home() / '.cache')
        base = str(Path(home) / 'turning_force' / 'numba')
    return Path(base) / source_hash()[:20]


def cache_is_warm() -> bool:
    """Whether the cache holds the machine code of today's sources (a stamp
    :func:`turning_force.core.kernel.load` leaves once it has compiled them)."""
    stamp = cache_dir() / STAMP
    return stamp.is_file() and stamp.read_text().strip() == source_hash()
