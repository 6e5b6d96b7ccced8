"""The control laws by name: the one list the settings' choices and the controller use. The
laws' modules (with their compiled code) are imported when a law is first asked for, so that
reading the settings imports no numba."""

from __future__ import annotations

import importlib
from collections.abc import Iterator, Mapping

from turning_force.core.control.law import Law

__all__ = ['CONTROLLERS', 'NAMES']

NAMES = ('smc', 'adaptive', 'adaptive_smc', 'adaptive_pp', 'pi', 'staircase')


class _Laws(Mapping[str, Law]):
    """Name -> :class:`Law`, each law's module imported at its first use."""

    def __getitem__(self, name: str) -> Law:
        if name not in NAMES:
            raise KeyError(name)
        law: Law = importlib.import_module(f'turning_force.core.control.{name}').LAW
        return law

    def __iter__(self) -> Iterator[str]:
        return iter(NAMES)

    def __len__(self) -> int:
        return len(NAMES)


CONTROLLERS: Mapping[str, Law] = _Laws()
