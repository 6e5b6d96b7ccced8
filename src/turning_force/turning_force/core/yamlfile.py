"""YAML files as a user writes them: UTF-8 text, each key once, every error one line that names
the file (experiment files, ``--params`` overlays, machine files, ``--set`` values)."""

from __future__ import annotations

import math
import os
import tempfile
from pathlib import Path
from typing import TYPE_CHECKING, Any

import yaml
from yaml.nodes import MappingNode

from turning_force.core.errors import ConfigError

__all__ = ['load_yaml', 'read_text', 'read_yaml_file', 'replace_file', 'yaml_error_text',
           'yaml_text']


# libyaml's parser where PyYAML was built with it (the wheels are): an experiment file in 2 ms
# instead of 30, a tenth of the command's start-up.
if TYPE_CHECKING:
    _SafeLoader = yaml.SafeLoader
else:
    _SafeLoader = getattr(yaml, 'CSafeLoader', yaml.SafeLoader)


class _UniqueKeyLoader(_SafeLoader):
    """PyYAML's safe loader, refusing a key given twice in one mapping (it keeps the last)."""

    def construct_mapping(self, node: MappingNode, deep: bool = False) -> dict[Any, Any]:
        if not isinstance(node, MappingNode):   # the base class says what it expected
            return super().construct_mapping(node, deep)
        seen: dict[Any, int] = {}
        for key_node, _ in node.value:
            if key_node.tag == 'tag:yaml.org,2002:merge':   # '<<: *defaults' may be overridden
                continue
            key = self.construct_object(key_node, deep=True)
            try:
                first = seen.get(key)
            except TypeError:   # unhashable: the base class says so
                continue
            if first is not None:
                raise yaml.constructor.ConstructorError(
                    None, None, f'duplicate key {key!r} (first on line {first + 1})',
                    key_node.start_mark)
            seen[key] = key_node.start_mark.line
        return super().construct_mapping(node, deep)


def load_yaml(text: str) -> Any:
    """YAML text -> Python data, a key given twice refused; errors as ``yaml.YAMLError``.

    PyYAML's constructors raise plain ``ValueError`` and friends for text its resolver
    mistook for a date (``2024-13-45``) or an explicit tag on a bad value (``!!int abc``);
    those are bad YAML too.
    """
    try:
        return yaml.load(text, Loader=_UniqueKeyLoader)
    except (ValueError, TypeError, OverflowError, RecursionError) as exc:
        raise yaml.YAMLError(f'{type(exc).__name__}: {exc}') from exc


def yaml_error_text(exc: yaml.YAMLError) -> str:
    """A YAML error as one line: where (1-based) and what."""
    if isinstance(exc, yaml.MarkedYAMLError):
        mark = exc.problem_mark or exc.context_mark
        what = ', '.join(str(p) for p in (exc.context, exc.problem) if p)
        if mark is not None:
            return f'line {mark.line + 1}, column {mark.column + 1}: {what}'
    return ' '.join(str(exc).split())


def read_text(path: Path, what: str = '') -> str:
    """A file's UTF-8 text; ``ConfigError`` naming it (and ``what`` it is) otherwise."""
    try:
        return path.read_bytes().decode('utf-8')
    except OSError as exc:
        raise ConfigError(f'{path}: cannot read{what}: {exc.strerror}') from exc
    except UnicodeDecodeError as exc:
        line = exc.object[:exc.start].count(b'\n') + 1
        raise ConfigError(f'{path}: not UTF-8 text: byte 0x{exc.object[exc.start]:02x} on line '
                          f'{line}') from exc


def read_yaml_file(path: Path, what: str = '') -> Any:
    """A YAML file's data: UTF-8, each key once; ``ConfigError`` naming the file otherwise."""
    text = read_text(path, what)
    try:
        return load_yaml(text)
    except yaml.YAMLError as exc:
        raise ConfigError(f'{path}: not valid YAML: {yaml_error_text(exc)}') from exc


def replace_file(path: Path, text: str, what: str = '') -> None:
    """Write ``text`` to ``path`` at once (a temporary file renamed over it: never half
    written); ``ConfigError`` naming it (and ``what`` it is) otherwise."""
    path.parent.mkdir(parents=True, exist_ok=True)
    try:
        fd, tmp = tempfile.mkstemp(prefix=f'.{path.name}.', dir=path.parent)
        with os.fdopen(fd, 'w') as stream:
            stream.write(text)
        os.replace(tmp, path)
    except OSError as exc:
        raise ConfigError(f'{path}: cannot write{what}: {exc.strerror}') from exc


def yaml_text(value: Any) -> str:
    """A value as YAML that reads back to it: floats always with a point before the exponent
    (YAML 1.1 reads ``1e-05`` as text), tuples and lists in flow style, a word as it is and
    any other text quoted."""
    if isinstance(value, tuple):
        value = list(value)
    if isinstance(value, float) and math.isfinite(value):
        mantissa, e, exponent = repr(value).partition('e')
        return f'{mantissa}.0e{exponent}' if e and '.' not in mantissa else repr(value)
    if isinstance(value, str) and load_yaml(value) == value:
        return value
    dumped: str = yaml.safe_dump(value, default_flow_style=True, width=2**30)
    return dumped.removesuffix('\n').removesuffix('\n...')
