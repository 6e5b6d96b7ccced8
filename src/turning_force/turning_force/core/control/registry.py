"""The control laws by name: ours (each module of :mod:`turning_force.core.control.laws`) and
those other packages install under the ``turning_force.laws`` entry point group. The one list
the settings' choices, the settings themselves and the compiled dispatch are made from.

A law's module is imported when the law is first asked for; listing the names imports none.
"""

from __future__ import annotations

import dataclasses
import functools
import importlib
import importlib.util
import pkgutil
from collections.abc import Iterator, Mapping

from turning_force.core.codecache import LAW_GROUP, installed_laws
from turning_force.core.control.law import ControllerBase, Law
from turning_force.core.errors import ConfigError
from turning_force.core.settings import setting

__all__ = ['CONTROLLERS', 'DEFAULT', 'compose', 'law_modules', 'names']

OURS = 'turning_force.core.control.laws'
DEFAULT = 'smc'


@functools.cache
def law_modules() -> dict[str, str]:
    """Name -> module of every law: ours (the default first, then by name), then the installed
    ones by name. A name taken twice is an error that names both."""
    spec = importlib.util.find_spec(OURS)
    assert spec is not None and spec.submodule_search_locations is not None
    ours = sorted((info.name for info in pkgutil.iter_modules(spec.submodule_search_locations)
                   if not info.name.startswith('_')), key=lambda name: (name != DEFAULT, name))
    found = {name: f'{OURS}.{name}' for name in ours}
    for name, module, dist in installed_laws():
        if name in found:
            raise ConfigError(f'entry point {LAW_GROUP}: {name} = {module} (from {dist}): the '
                              f'law {name!r} is already {found[name]}')
        found[name] = module
    return found


def names() -> tuple[str, ...]:
    return tuple(law_modules())


@functools.cache
def _law(name: str) -> Law:
    module_name = law_modules()[name]
    try:
        module = importlib.import_module(module_name)
    except Exception as exc:
        raise ConfigError(f'control law {name!r}: its module {module_name} does not import: '
                          f'{exc!r}') from exc
    law = getattr(module, 'LAW', None)
    where = f'control law {name!r} ({module_name})'
    if not isinstance(law, Law):
        raise ConfigError(f'{where}: no LAW = turning_force.core.control.law.Law(...) in it')
    if law.name != name:
        raise ConfigError(f'{where}: its LAW is named {law.name!r}')
    if not (isinstance(law.settings, type) and issubclass(law.settings, ControllerBase)
            and law.settings.__module__ == module_name):
        raise ConfigError(f'{where}: its settings are not a ControllerBase subclass of its own')
    missing = [hook for hook in ('step', 'reset') if not callable(getattr(module, hook, None))]
    if missing:
        raise ConfigError(f'{where}: no compiled {" or ".join(missing)} in it')
    return law


class _Laws(Mapping[str, Law]):
    """Name -> :class:`Law`, each law's module imported at its first use."""

    def __getitem__(self, name: str) -> Law:
        if name not in law_modules():
            raise KeyError(name)
        return _law(name)

    def __iter__(self) -> Iterator[str]:
        return iter(law_modules())

    def __len__(self) -> int:
        return len(law_modules())


CONTROLLERS: Mapping[str, Law] = _Laws()


def compose() -> type[ControllerBase]:
    """The force controller's settings: what every law shares and each law's own, one
    dataclass (``force_controller`` parameters, validated, described, swept alike). A field
    two laws declare is an error that names both."""
    laws = [CONTROLLERS[name] for name in names()]
    owner: dict[str, str] = {}
    shared = {field.name for field in dataclasses.fields(ControllerBase)}
    for law in laws:
        for field in dataclasses.fields(law.settings):
            if field.name in shared:
                continue
            if owner.setdefault(field.name, law.name) != law.name:
                raise ConfigError(f'control law {law.name!r}: its setting {field.name} is '
                                  f"already the {owner[field.name]!r} law's")
    bases = tuple(dict.fromkeys(law.settings for law in laws)) or (ControllerBase,)
    namespace = {
        '__module__': 'turning_force.core.control.settings',
        '__qualname__': 'ControllerSettings',
        '__doc__': "The force controller (``force_controller`` parameters): every law's.",
        '__annotations__': {'controller': 'str'},
        'controller': setting(DEFAULT, 'Control law', choices=names()),
    }
    return dataclasses.dataclass(frozen=True)(type('ControllerSettings', bases, namespace))
