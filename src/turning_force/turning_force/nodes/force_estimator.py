"""``force_estimator``: cutting force from the feed-drive currents.

Subscribes ``servo/currents`` (turning_force_msgs/ServoCurrents); publishes ``force/estimate``
(turning_force_msgs/ForceEstimate), one per block. The work is
:class:`turning_force.core.estimation.ForceEstimator`; parameters are
:class:`turning_force.core.estimation.EstimatorSettings` (``ros2 param describe`` lists them
with units and ranges). A block with non-finite samples or an out-of-order stamp is published
as ``STATUS_INVALID_INPUT`` with the last good, finite force.
"""

from __future__ import annotations

import sys
from collections.abc import Sequence
from typing import Any

from rclpy.node import Node
from turning_force_msgs.msg import ForceEstimate, ServoCurrents

from turning_force.core.estimation import EstimateStatus, EstimatorSettings, ForceEstimator
from turning_force.nodes.convert import estimate_to_msg, servo_currents_to_block
from turning_force.nodes.parameters import SettingsParameters
from turning_force.nodes.spin import run_nodes

__all__ = ['ForceEstimatorNode', 'main']


class ForceEstimatorNode(Node):
    """Force and force rate from ``servo/currents`` to ``force/estimate``."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__('force_estimator', **kwargs)
        self.parameters = SettingsParameters(self, EstimatorSettings, self._reconfigure)
        self._estimator = ForceEstimator(self.parameters.current)
        self._publisher = self.create_publisher(ForceEstimate, 'force/estimate', 10)
        self.create_subscription(ServoCurrents, 'servo/currents', self._on_currents, 10)

    def _reconfigure(self, settings: EstimatorSettings) -> None:
        self._estimator = ForceEstimator(settings)

    def _on_currents(self, msg: ServoCurrents) -> None:
        estimate = self._estimator.update(servo_currents_to_block(msg))
        if estimate.status == EstimateStatus.INVALID_INPUT:
            self.get_logger().warning(f'servo/currents: {estimate.detail}',
                                      throttle_duration_sec=1.0)
        out = estimate_to_msg(estimate)
        out.header.frame_id = msg.header.frame_id
        self._publisher.publish(out)


def main(args: Sequence[str] | None = None) -> int:
    return run_nodes(lambda: [ForceEstimatorNode()], args)


if __name__ == '__main__':
    sys.exit(main())
