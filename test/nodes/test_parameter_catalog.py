"""Every parameter each node declares is one the catalog explains (turning-force describe,
docs/parameters.md), and its ROS descriptor says what the catalog says: the same declaration
makes both."""

from __future__ import annotations

from typing import Any

import pytest
from rclpy.node import Node

from turning_force.core.catalog import parameters
from turning_force.nodes.force_controller import ForceControllerNode
from turning_force.nodes.force_estimator import ForceEstimatorNode
from turning_force.nodes.lathe_sim import LatheSimNode
from turning_force.nodes.parameters import ROS_PARAMETERS
from turning_force.nodes.pmc_bridge import PmcBridgeNode
from turning_force.nodes.servo_daq import DaqError, ServoDaqNode
from turning_force.nodes.session_recorder import SessionRecorderNode


def declared(node: Node) -> dict[str, Any]:
    """The node's parameters and their descriptors, rclpy's own left out."""
    names = [n for n in node._parameters if n not in ROS_PARAMETERS]
    return dict(zip(names, node.describe_parameters(names), strict=True))


def servo_daq(context: Any) -> Node:
    """The DAQ node as far as it gets without NI's driver: its parameters are declared before
    it opens the device, which fails here with a DaqError (the node says which is missing)."""
    node = ServoDaqNode.__new__(ServoDaqNode)
    with pytest.raises(DaqError):
        node.__init__(context=context)   # type: ignore[misc]
    return node


@pytest.mark.parametrize('name', ['lathe_sim', 'force_estimator', 'force_controller',
                                  'pmc_bridge', 'session_recorder', 'servo_daq'])
def test_each_node_declares_what_the_catalog_explains(context, tmp_path, name):
    make = {
        'lathe_sim': lambda: LatheSimNode(lockstep=True, context=context),
        'force_estimator': lambda: ForceEstimatorNode(context=context),
        'force_controller': lambda: ForceControllerNode(context=context),
        'pmc_bridge': lambda: PmcBridgeNode(autostart=False, context=context),
        'session_recorder': lambda: SessionRecorderNode(
            context=context, parameter_overrides=[_output(tmp_path)]),
        'servo_daq': lambda: servo_daq(context),
    }[name]
    node = make()
    try:
        descriptors = declared(node)
        explained = {p.name: p for p in parameters(name)}
        assert set(descriptors) == set(explained)
        for key, d in descriptors.items():
            p = explained[key]
            assert d.description.startswith(p.spec.description), key
            if p.spec.unit and p.kind in (int, float):
                assert f'[{p.spec.unit}]' in d.description, key
            if p.spec.cite:
                assert p.spec.cite in d.description, key
            assert d.read_only == (not p.spec.dynamic), key
            if p.kind is float and not isinstance(p.default, tuple):
                (span,) = d.floating_point_range
                assert (span.from_value, span.to_value) == (p.spec.low, p.spec.high), key
    finally:
        node.destroy_node()


def _output(tmp_path: Any) -> Any:
    from rclpy.parameter import Parameter

    return Parameter('output_dir', value=str(tmp_path / 'session'))
