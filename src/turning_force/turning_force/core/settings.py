"""Validated, frozen settings objects built from ROS 2 parameter dictionaries.

Every setting is declared once, as a dataclass field made with :func:`setting`: its default, a
description, its unit, its allowed range or choices, and whether it may change while cutting. The
core validates from that declaration; the node layer declares ROS parameters (with
``ParameterDescriptor``) from the same declaration, so the two can never disagree.
"""

from __future__ import annotations

import dataclasses
import math
import typing
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, ClassVar, Self

from turning_force.core.errors import ConfigError

__all__ = ['DIMENSIONLESS', 'INT64_MAX', 'INT64_MIN', 'Settings', 'Spec', 'setting']

Scalar = bool | int | float | str

# What a ROS 2 integer parameter holds (int64): a larger value kills the node at declaration.
INT64_MIN, INT64_MAX = -(2**63), 2**63 - 1

# The unit of a number without one (a ratio, a damping, a count), written as engineers do.
DIMENSIONLESS = '-'


@dataclass(frozen=True)
class Spec:
    """What a setting means and which values it takes."""

    description: str
    unit: str = ''
    low: float | None = None
    high: float | None = None
    low_open: bool = False
    high_open: bool = False
    choices: tuple[str, ...] = ()
    dynamic: bool = False
    cite: str = ''

    @property
    def unit_text(self) -> str:
        """The unit after a number (`` N``), nothing for a dimensionless one."""
        return f' {self.unit}' if self.unit and self.unit != DIMENSIONLESS else ''

    def range_text(self) -> str:
        """The allowed range as an engineer writes it, e.g. ``(0, 1]``."""
        low = '-inf' if self.low is None else _number(self.low)
        high = 'inf' if self.high is None else _number(self.high)
        return f'{"(" if self.low_open or self.low is None else "["}{low}, {high}' + (
            ')' if self.high_open or self.high is None else ']'
        )


def _number(value: float) -> str:
    """A bound as written: an integer in full (the largest seed), a float briefly."""
    return str(value) if isinstance(value, int) else f'{value:g}'


def setting(
    default: Any,
    description: str,
    unit: str = '',
    *,
    low: float | None = None,
    high: float | None = None,
    low_open: bool = False,
    high_open: bool = False,
    choices: tuple[str, ...] = (),
    dynamic: bool = False,
    cite: str = '',
) -> Any:
    """Declare a settings field: default, description, unit, range and run-time mutability.

    ``unit`` is :data:`DIMENSIONLESS` for a number without one. ``dynamic`` marks values that
    may change while cutting (reference force, gains); the others are fixed for a session
    (read-only parameters in the node layer). ``cite``: the paper and equation the setting
    comes from (``'Park 1998, Eq. 10'``), where one does.
    """
    spec = Spec(description, unit, low, high, low_open, high_open, choices, dynamic, cite)
    if isinstance(default, list):
        default = tuple(default)
    return field(default=default, metadata={'spec': spec})


class Settings:
    """Base of the frozen settings dataclasses.

    Subclasses are ``@dataclass(frozen=True)`` with fields made by :func:`setting`, set
    ``SECTION`` to the parameter-file section they come from, and may override :meth:`check`
    for rules that tie several fields together.
    """

    SECTION: ClassVar[str] = ''

    def __post_init__(self) -> None:
        for name, (kind, spec) in self.fields().items():
            _check_value(self.SECTION, name, getattr(self, name), kind, spec)
        self.check()

    def check(self) -> None:
        """Cross-field rules; raise :class:`ConfigError` through :meth:`fail`."""

    def fail(self, name: str, reason: str) -> typing.NoReturn:
        """Raise a :class:`ConfigError` naming ``SECTION.name`` and its current value."""
        raise ConfigError(f'{self.SECTION}.{name} = {getattr(self, name)!r}: {reason}')

    @classmethod
    def fields(cls) -> dict[str, tuple[type, Spec]]:
        """Field name -> (scalar type, spec). Tuple fields report their element type."""
        return dict(_declaration(cls)[0])

    @classmethod
    def from_params(cls, params: Mapping[str, Any], *, strict: bool = True) -> Self:
        """Build from a parameter dictionary; unknown keys are an error when ``strict``.

        Integers are accepted where floats are expected and lists where arrays are; anything else
        of the wrong type is a :class:`ConfigError` naming the key and the value.
        """
        known = cls.fields()
        kwargs: dict[str, Any] = {}
        for name, value in params.items():
            if name not in known:
                if strict:
                    raise ConfigError(
                        f'{cls.SECTION}.{name} = {value!r}: unknown parameter; known: '
                        + ', '.join(sorted(known))
                    )
                continue
            kind = known[name][0]
            kwargs[name] = _coerce(cls.SECTION, name, value, kind, cls._is_array(name))
        return cls(**kwargs)

    @classmethod
    def _is_array(cls, name: str) -> bool:
        return name in _declaration(cls)[1]

    def to_params(self) -> dict[str, Any]:
        """The settings as a parameter dictionary (tuples as lists), for records and files."""
        out: dict[str, Any] = {}
        for name in self.fields():
            value = getattr(self, name)
            out[name] = list(value) if isinstance(value, tuple) else value
        return out

    def replace(self, **changes: Any) -> Self:
        """A validated copy with some values changed."""
        return dataclasses.replace(self, **changes)  # type: ignore[type-var]


# Per class: its fields' (scalar type, spec), and which are arrays. Read from the type hints
# once: typing.get_type_hints costs about a millisecond, and every construction validates.
_DECLARATIONS: dict[type, tuple[dict[str, tuple[type, Spec]], frozenset[str]]] = {}


def _declaration(cls: type) -> tuple[dict[str, tuple[type, Spec]], frozenset[str]]:
    found = _DECLARATIONS.get(cls)
    if found is None:
        hints = typing.get_type_hints(cls)
        fields: dict[str, tuple[type, Spec]] = {}
        for f in dataclasses.fields(cls):
            spec = f.metadata.get('spec')
            if spec is not None:
                fields[f.name] = (_scalar_type(hints[f.name]), spec)
        arrays = frozenset(n for n in fields if typing.get_origin(hints[n]) is tuple)
        found = _DECLARATIONS[cls] = (fields, arrays)
    return found


def _scalar_type(hint: Any) -> type:
    if typing.get_origin(hint) is tuple:
        hint = typing.get_args(hint)[0]
    if hint not in (bool, int, float, str):
        raise TypeError(f'unsupported settings field type {hint!r}')
    return typing.cast(type, hint)


def _coerce(section: str, name: str, value: Any, kind: type, array: bool) -> Any:
    where = f'{section}.{name} = {value!r}'
    if array:
        if not isinstance(value, list | tuple):
            raise ConfigError(f'{where}: expected a list of {kind.__name__}')
        return tuple(_coerce_scalar(where, v, kind) for v in value)
    return _coerce_scalar(where, value, kind)


def _coerce_scalar(where: str, value: Any, kind: type) -> Scalar:
    # bool is an int in Python; a flag given as 1 or a gain given as true is a typo.
    if kind is float and isinstance(value, int | float) and not isinstance(value, bool):
        try:
            return float(value)
        except OverflowError:   # an integer beyond the float range
            raise ConfigError(f'{where}: too large for a float') from None
    if kind is int and isinstance(value, int) and not isinstance(value, bool):
        if not INT64_MIN <= value <= INT64_MAX:
            raise ConfigError(f'{where}: outside the 64-bit range of a ROS integer parameter '
                              f'[{INT64_MIN}, {INT64_MAX}]')
        return value
    if kind in (bool, str) and isinstance(value, kind):
        return typing.cast(Scalar, value)
    hint = ''
    if kind is float and isinstance(value, str):
        try:
            float(value)
            hint = ' (YAML reads 1e6 as text: write 1.0e+6)'
        except ValueError:
            pass
    raise ConfigError(f'{where}: expected {kind.__name__}, got {type(value).__name__}{hint}')


def _check_value(section: str, name: str, value: Any, kind: type, spec: Spec) -> None:
    values = value if isinstance(value, tuple) else (value,)
    for v in values:
        where = f'{section}.{name} = {value!r}'
        if kind is str and spec.choices and v not in spec.choices:
            raise ConfigError(f'{where}: expected one of {", ".join(spec.choices)}')
        if kind in (int, float):
            if not isinstance(v, int | float) or isinstance(v, bool):
                raise ConfigError(f'{where}: expected {kind.__name__}')
            if isinstance(v, float) and not math.isfinite(v):
                raise ConfigError(f'{where}: must be finite')
            if isinstance(v, int) and not INT64_MIN <= v <= INT64_MAX:
                raise ConfigError(f'{where}: outside the 64-bit range of a ROS integer '
                                  f'parameter [{INT64_MIN}, {INT64_MAX}]')
            below = spec.low is not None and (v <= spec.low if spec.low_open else v < spec.low)
            above = spec.high is not None and (v >= spec.high if spec.high_open else v > spec.high)
            if below or above:
                raise ConfigError(f'{where}: outside {spec.range_text()}{spec.unit_text}')
