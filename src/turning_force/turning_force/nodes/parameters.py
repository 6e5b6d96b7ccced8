"""ROS parameters declared from the core's settings declarations (one source of truth).

Every field of a :class:`~turning_force.core.settings.Settings` class becomes a parameter with a
``ParameterDescriptor``: its description with unit and range, a numeric range where one applies,
and ``read_only`` unless the field may change while cutting. Values set at run time are checked
by building the settings object with them: a bad value is rejected with the core's reason.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable
from typing import Any, Generic, TypeVar

from rcl_interfaces.msg import (
    FloatingPointRange,
    IntegerRange,
    ParameterDescriptor,
    SetParametersResult,
)
from rclpy.exceptions import InvalidParameterTypeException, InvalidParameterValueException
from rclpy.node import Node
from rclpy.parameter import Parameter

from turning_force.core.catalog import NODES
from turning_force.core.errors import ConfigError
from turning_force.core.settings import Settings, Spec

__all__ = ['ROS_PARAMETERS', 'SettingsParameters', 'check_overrides', 'declare', 'descriptor']

# rclpy's own parameters, which every node has.
ROS_PARAMETERS = frozenset({'use_sim_time', 'start_type_description_service'})


def check_overrides(node: Node, own: Iterable[str] = ()) -> None:
    """Refuse to start with a parameter no node of the graph declares: a typo.

    rclpy ignores values given for undeclared parameters, so ``overload_force_nn: 900`` in a
    params file would silently leave the default limit in force. A name that another node
    declares is fine (``/**`` gives every node the whole shared section); ``own`` adds the
    names of a node's own settings.
    """
    # rclpy keeps the overrides only in this attribute; there is no public accessor.
    overrides: dict[str, Any] = getattr(node, '_parameter_overrides', {})
    known = set(ROS_PARAMETERS) | set(own)
    for entry in NODES:
        known.update(entry.fields())
    unknown = sorted(n for n in overrides if n not in known and not n.startswith('qos_overrides.'))
    if unknown:
        raise ConfigError(f'{node.get_fully_qualified_name()}: {", ".join(unknown)}: no node of '
                          'turning_force declares such a parameter (a typo?)')


def declare(node: Node, kind: type[Settings], name: str) -> Any:
    """Declare one field of ``kind`` as a parameter of ``node`` (a parameter of how the node
    runs, read once at start: :mod:`turning_force.core.catalog`) and return its value, checked
    as the settings check it."""
    scalar, spec = kind.fields()[name]
    default = getattr(kind(), name)
    array = kind._is_array(name)
    node.declare_parameter(name, list(default) if array else default,
                           descriptor(name, scalar, spec, array))
    value = node.get_parameter(name).value
    try:
        return getattr(kind.from_params({name: value}), name)
    except ConfigError as exc:
        raise ConfigError(f'{node.get_fully_qualified_name()}: {exc}') from exc

S = TypeVar('S', bound=Settings)


def descriptor(name: str, kind: type, spec: Spec, array: bool) -> ParameterDescriptor:
    """The ``ParameterDescriptor`` of one settings field."""
    unit = f' [{spec.unit}]' if spec.unit else ''
    text = f'{spec.description}{unit}'
    if kind in (int, float) and (spec.low is not None or spec.high is not None):
        text += f'; range {spec.range_text()}'
    if spec.choices:
        text += f'; one of {", ".join(spec.choices)}'
    if spec.cite:
        text += f'; {spec.cite}'
    d = ParameterDescriptor(name=name, description=text, read_only=not spec.dynamic)
    low, high = spec.low, spec.high
    if low is not None and high is not None and not array:
        if kind is float:
            d.floating_point_range = [FloatingPointRange(from_value=float(low),
                                                         to_value=float(high), step=0.0)]
        elif kind is int:
            d.integer_range = [IntegerRange(from_value=math.ceil(low), to_value=math.floor(high),
                                            step=1)]
    return d


class SettingsParameters(Generic[S]):
    """A node's parameters for one settings class, kept as a validated, frozen object.

    ``current`` is the settings in force. A parameter change is validated in the on-set
    callback (rejected with the ``ConfigError`` text) and applied in the post-set callback,
    which then calls ``on_change(new_settings)``.
    """

    def __init__(self, node: Node, kind: type[S],
                 on_change: Callable[[S], None] | None = None) -> None:
        self._node = node
        self._kind = kind
        self._on_change = on_change
        fields = kind.fields()
        defaults = kind()
        self._names = list(fields)
        try:
            for name, (scalar, spec) in fields.items():
                array = kind._is_array(name)
                default = getattr(defaults, name)
                try:
                    node.declare_parameter(name, list(default) if array else default,
                                           descriptor(name, scalar, spec, array))
                except (InvalidParameterValueException, InvalidParameterTypeException) as exc:
                    raise ConfigError(f'{node.get_fully_qualified_name()}: {kind.SECTION}.{name}'
                                      f': {exc}') from exc
            check_overrides(node, fields)
            self.current: S = kind.from_params(self._values())
        except ConfigError as exc:
            node.get_logger().fatal(str(exc))
            raise
        node.add_on_set_parameters_callback(self._validate)
        node.add_post_set_parameters_callback(self._apply)

    def _values(self, changes: dict[str, Any] | None = None) -> dict[str, Any]:
        values = {n: self._node.get_parameter(n).value for n in self._names}
        values.update(changes or {})
        return values

    def _validate(self, parameters: list[Parameter[Any]]) -> SetParametersResult:
        changes = {p.name: p.value for p in parameters if p.name in self._names}
        if not changes:
            return SetParametersResult(successful=True)
        try:
            self._kind.from_params(self._values(changes))
        except ConfigError as exc:
            return SetParametersResult(successful=False, reason=str(exc))
        return SetParametersResult(successful=True)

    def _apply(self, parameters: list[Parameter[Any]]) -> None:
        if not any(p.name in self._names for p in parameters):
            return
        self.current = self._kind.from_params(self._values())
        if self._on_change is not None:
            self._on_change(self.current)
