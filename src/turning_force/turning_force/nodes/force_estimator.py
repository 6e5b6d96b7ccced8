"""``force_estimator``: cutting force from the feed-drive currents.

Subscribes ``servo/currents`` (turning_force_msgs/ServoCurrents); publishes ``force/estimate``
(turning_force_msgs/ForceEstimate), one per block. Subscribes ``force/friction_correction``
(std_msgs/Float64 [N]): a friction drift the controller's drift monitor read in the cut, which
the estimate takes off from the next block on
(:meth:`~turning_force.core.estimation.estimator.ForceEstimator.correct`; a WARN on
/diagnostics and in the log says so). The work is
:class:`turning_force.core.estimation.estimator.ForceEstimator`; parameters are
:class:`turning_force.core.estimation.settings.EstimatorSettings` (``ros2 param describe`` lists
them with units and ranges). A block with non-finite samples or an out-of-order stamp is published
as ``STATUS_INVALID_INPUT`` with the last good, finite force (stamped as the block it answers);
when blocks stop coming for five block periods, ``STATUS_STALE`` estimates say so every
``STALE_CHECK_S``. """

from __future__ import annotations

import math
import sys
from typing import Any

import numpy as np
from rclpy.node import Node
from std_msgs.msg import Float64
from turning_force_msgs.msg import ForceEstimate, ServoCurrents

from turning_force.core import kernel
from turning_force.core.estimation.estimator import ForceEstimator, rezeroed_text
from turning_force.core.estimation.settings import (
    FRICTION_REACH_MARGIN,
    EstimateStatus,
    EstimatorSettings,
)
from turning_force.core.estimation.settings import ForceEstimate as Estimate
from turning_force.core.plant.drive import CurrentBlock
from turning_force.nodes.convert import (
    estimate_to_msg,
    last_sample_ns,
    servo_currents_to_block,
    set_stamp,
)
from turning_force.nodes.diagnostics import Diagnostics
from turning_force.nodes.parameters import SettingsParameters
from turning_force.nodes.spin import STREAM_DEPTH, node_main, timer_callback

__all__ = ['FRICTION_CORRECTION_TOPIC', 'ForceEstimatorNode', 'main']


STALE_CHECK_S = 0.1
# The friction [N] the controller's drift monitor read in the cut (std_msgs/Float64).
FRICTION_CORRECTION_TOPIC = 'force/friction_correction'


# How a re-zero's estimate detail begins (estimator.rezeroed_text).
REZEROED = rezeroed_text(1.0).split(':')[0]
# How long the axis runs past the measured friction (FRICTION_REACH_MARGIN) before it is said.
REACH_S = 0.5


class ForceEstimatorNode(Node):
    """Force and force rate from ``servo/currents`` to ``force/estimate``."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__('force_estimator', **kwargs)
        kernel.load()   # the compiled code, before the first block (compiled on a cold cache)
        self.parameters = SettingsParameters(self, EstimatorSettings, self._reconfigure)
        self.diagnostics = Diagnostics(self)
        self._estimator = ForceEstimator(self.parameters.current)
        self._publisher = self.create_publisher(ForceEstimate, 'force/estimate', STREAM_DEPTH)
        self._out = ForceEstimate()   # refilled per block (rclpy serialises on publish)
        self.create_subscription(ServoCurrents, 'servo/currents', self._on_currents, 10)
        self.create_subscription(Float64, FRICTION_CORRECTION_TOPIC,
                                 self._on_friction_correction, 10)
        self._watching = False
        self._logged_scale = 1.0
        self._rezeroed_s = math.nan   # when an air move last re-zeroed the friction [node s]
        self._rezero_warned_s = -math.inf
        self._past_reach_s = 0.0   # how long the axis has run past the measured friction
        self.create_timer(STALE_CHECK_S, timer_callback(self._check_stale))

    def _reconfigure(self, settings: EstimatorSettings) -> None:
        self._estimator = ForceEstimator(settings)

    def _check_stale(self) -> None:
        if self._watching and self.diagnostics.stale('servo/currents'):
            last = self._estimator.last
            out = estimate_to_msg(last)
            out.status = ForceEstimate.STATUS_STALE
            out.detail = 'no servo/currents for five block periods'
            out.header.stamp = self.get_clock().now().to_msg()
            self._publisher.publish(out)
            self.diagnostics.published('force/estimate')

    def _on_friction_correction(self, msg: Float64) -> None:
        self.diagnostics.received(FRICTION_CORRECTION_TOPIC)
        line = self._estimator.correct(float(msg.data))
        if line:
            self._logged_scale = self._estimator.friction_scale   # no re-zero in air
            self.diagnostics.set_value('friction_scale', self._logged_scale)
            self.diagnostics.warn(line, log=True)

    def _on_currents(self, msg: ServoCurrents) -> None:
        self.diagnostics.received('servo/currents')
        if not self._watching and msg.sample_period_s > 0 and len(msg.phase_u_a):
            period = len(msg.phase_u_a) * msg.sample_period_s
            self.diagnostics.watch('servo/currents', stale_after_s=5 * period)
            self.diagnostics.received('servo/currents')
            self._watching = True
        block = servo_currents_to_block(msg)
        estimate = self._estimator.update(block)
        if estimate.status == EstimateStatus.INVALID_INPUT:
            self.get_logger().warning(f'servo/currents: {estimate.detail}',
                                      throttle_duration_sec=1.0)
            self.diagnostics.error(f'servo/currents: {estimate.detail}')
        elif estimate.status == EstimateStatus.SATURATED:
            self.diagnostics.warn(estimate.detail)
        self._watch_rezero(estimate)
        self._watch_reach(block)
        scale = self._estimator.friction_scale
        if abs(scale - self._logged_scale) > 0.02:   # log a re-zero once per 2 % of change
            self.get_logger().info(f'friction re-zeroed in air: {scale:.3f} x calibrated')
            self._logged_scale = scale
        self.diagnostics.set_value('friction_scale', scale)
        out = estimate_to_msg(estimate, self._out)
        out.header.frame_id = msg.header.frame_id
        # Stamped as the block it answers, valid or not: downstream (the bridge, lock-step
        # runs, the session reader) pairs answers with blocks by this stamp.
        set_stamp(out.header.stamp, last_sample_ns(msg))
        self._publisher.publish(out)
        self.diagnostics.published('force/estimate')


    def _watch_rezero(self, estimate: Estimate) -> None:
        """Issue 16: the friction re-zero needs air moves; where none came for
        ``rezero_stale_s`` (from the first block, or the last re-zero), a WARN says so, again
        every ``rezero_stale_s`` while it lasts."""
        settings = self.parameters.current
        now = estimate.t_s
        if estimate.detail.startswith(REZEROED) or math.isnan(self._rezeroed_s):
            self._rezeroed_s = now
        if settings.rezero_stale_s <= 0.0 or settings.rezero_below_n <= 0.0:
            return
        since = now - self._rezeroed_s
        self.diagnostics.set_value('since_friction_rezero_s', f'{since:.0f}')
        if since >= settings.rezero_stale_s and now - self._rezero_warned_s >= \
                settings.rezero_stale_s:
            self._rezero_warned_s = now
            self.diagnostics.warn(
                f'no air move has re-zeroed the friction for {since:.0f} s (rezero_stale_s '
                f'{settings.rezero_stale_s:g} s): a drift of the feed drive friction goes '
                'into the force estimate unseen; add an air move to the program, or '
                're-commission', log=True)

    def _watch_reach(self, block: CurrentBlock) -> None:
        """The axis past the fastest feed the friction was measured at
        (``friction_measured_to_mm_min``) by over FRICTION_REACH_MARGIN for REACH_S: a WARN
        says so, once each time it gets there. Past it the estimate holds Park Eq. 25's end
        value; on population seed 42's #2, commissioned at 654 rpm (measured to 196 mm/min),
        a G96 facing cut held 10 N over the reference from the spindle's clamp (1500 rpm)
        on."""
        reach = self.parameters.current.friction_measured_to_mm_min
        if reach <= 0.0 or block.feed_rate_mm_min.size == 0:
            return
        fastest = float(np.max(np.abs(block.feed_rate_mm_min)))
        if not fastest > (1.0 + FRICTION_REACH_MARGIN) * reach:
            self._past_reach_s = 0.0
            return
        before = self._past_reach_s
        self._past_reach_s += block.feed_rate_mm_min.size * block.sample_period_s
        if before < REACH_S <= self._past_reach_s:
            self.diagnostics.warn(
                f'the axis runs at {fastest:.0f} mm/min, past the {reach:.0f} mm/min the '
                "friction was measured to (friction_measured_to_mm_min): the estimate holds "
                "the curve's end there (Park Eq. 25), and a friction still falling reads as "
                'force; re-commission with the air move at this spindle speed', log=True)


main = node_main(ForceEstimatorNode)


if __name__ == '__main__':
    sys.exit(main())
