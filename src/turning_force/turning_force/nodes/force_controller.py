"""``force_controller``: the force control law, once per force estimate.

Subscribes ``force/estimate`` (turning_force_msgs/ForceEstimate), ``force/reference``
(std_msgs/Float64 [N], transient-local, so a late joiner gets the last one) and
``machine/spindle_speed`` (std_msgs/Float64 [rpm]: the laws' spindle speed while it is fresh, else
``spindle_speed_rpm``, :class:`turning_force.nodes.spindle.SpindleSpeedInput`) and
``machine/tool`` (std_msgs/Int32: the tool in use selects its section of ``tools_file`` from the
next estimate on, :meth:`turning_force.core.control.base.Controller.select_tool`); publishes
``control/feed_command`` (turning_force_msgs/FeedCommand), stamped as the estimate it answers,
and ``force/friction_correction`` (std_msgs/Float64 [N]) where the drift monitor read a friction
drift in the cut for the estimator to take off (``drift_friction_correction``).
It subscribes ``pmc/feed_override`` too: the override the bridge applied is the law's state
wherever the request did not go through as asked (the tool out of the cut or entering it, the
gate holding or shaping it), the anti-windup of
:func:`turning_force.core.control.update.controller_applied`.
The law is :mod:`turning_force.core.control`, chosen by ``controller``; parameters:
:class:`turning_force.core.control.ControllerSettings`. Reference and gains may change while
cutting and take effect at the next control period. An estimate that is not OK (invalid input,
stale) is not acted on: no command goes out, and the PMC bridge's watchdog takes over.
"""

from __future__ import annotations

import collections
import sys
from typing import Any

from builtin_interfaces.msg import Time
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from std_msgs.msg import Float64, Int32
from turning_force_msgs.msg import FeedCommand, FeedOverride, ForceEstimate

from turning_force.core.control import ControllerSettings, make_controller
from turning_force.core.kernel.chain import command_for
from turning_force.nodes.convert import estimate_from_msg, stamp_to_ns
from turning_force.nodes.diagnostics import Diagnostics
from turning_force.nodes.force_estimator import FRICTION_CORRECTION_TOPIC
from turning_force.nodes.parameters import SettingsParameters
from turning_force.nodes.spin import STREAM_DEPTH, node_main
from turning_force.nodes.spindle import TOOL_TOPIC, SpindleSpeedInput

__all__ = ['REFERENCE_QOS', 'ForceControllerNode', 'main']

# Answers of the bridge, and stamps of blocks, kept until the next estimate takes them.
ANSWERS_KEPT = 100
REFERENCE_QOS = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL,
                           reliability=ReliabilityPolicy.RELIABLE)


class ForceControllerNode(Node):
    """Force estimate and reference in, feed command out."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__('force_controller', **kwargs)
        self.parameters = SettingsParameters(self, ControllerSettings, self._retune)
        settings = self.parameters.current
        # Compiled: its code is loaded here, before the first estimate.
        self._controller = make_controller(settings)
        self.diagnostics = Diagnostics(self)
        self.diagnostics.watch('force/estimate', stale_after_s=5 * settings.control_period_s)
        self.diagnostics.set_value('controller', settings.controller)
        self.diagnostics.set_value('model', 'commissioned')
        self._reachable = True
        self._oscillating = False
        self._drift = 0
        self._model = ''
        self.spindle = SpindleSpeedInput(self, self.diagnostics, settings.spindle_speed_stale_s,
                                         settings.spindle_speed_rpm)
        self._publisher = self.create_publisher(FeedCommand, 'control/feed_command', STREAM_DEPTH)
        self._command = FeedCommand()   # refilled per estimate (rclpy serialises on publish)
        self._correction = self.create_publisher(Float64, FRICTION_CORRECTION_TOPIC, 10)
        self.create_subscription(ForceEstimate, 'force/estimate', self._on_estimate, 10)
        self.create_subscription(Float64, 'force/reference', self._on_reference, REFERENCE_QOS)
        self._applied: collections.deque[FeedOverride] = collections.deque(maxlen=ANSWERS_KEPT)
        self._blocks: set[int] = set()   # the stamps of the blocks estimated (answers match)
        self.create_subscription(FeedOverride, 'pmc/feed_override', self._on_applied, 10)
        self._tool: int | None = None   # machine/tool: taken with the next estimate
        self.create_subscription(Int32, TOOL_TOPIC, self._on_tool, 10)

    def _on_tool(self, msg: Int32) -> None:
        self.diagnostics.received(TOOL_TOPIC)
        self._tool = int(msg.data)

    def _retune(self, settings: ControllerSettings) -> None:
        self._controller.retune(settings)
        self.spindle.parameter_rpm = settings.spindle_speed_rpm

    def _on_reference(self, msg: Float64) -> None:
        self.diagnostics.received('force/reference')
        value = msg.data
        result = self.set_parameters([Parameter('reference_force_n', value=float(value))])[0]
        if not result.successful:
            text = f'force/reference: {value!r} N rejected: {result.reason}'
            self.diagnostics.error(text, log=True)

    def _on_applied(self, msg: FeedOverride) -> None:
        self._applied.append(msg)

    def _take_applied(self, before: Time) -> None:
        """The overrides applied that answer the blocks before ``before`` (the estimate now
        in), in order: the core loop's order, each block's answer after its command, whichever
        comes first over DDS. Only answers to blocks count (stamped as the block's estimate):
        the bridge's own writes between blocks (waiting for the first command) answer none."""
        limit = stamp_to_ns(before)
        while self._applied and stamp_to_ns(self._applied[0].header.stamp) < limit:
            msg = self._applied.popleft()
            if stamp_to_ns(msg.header.stamp) in self._blocks:
                self._controller.applied(msg.applied_pct, msg.engaged, msg.reason)
        self._blocks.add(limit)
        while len(self._blocks) > ANSWERS_KEPT:
            self._blocks.discard(min(self._blocks))

    def _on_estimate(self, msg: ForceEstimate) -> None:
        self.diagnostics.received('force/estimate')
        self._take_applied(msg.header.stamp)
        # The tool after the answers before this block, as the core loop's chain takes them.
        if self._tool is not None and self._tool != self._controller.tool_number:
            if not self._controller.select_tool(self._tool):
                self.diagnostics.set_value('tool', f'{self._tool} (no section: settings kept)')
            else:
                self.diagnostics.set_value('tool', str(self._tool))
        self._controller.spindle_speed(self.spindle.rpm())
        out = command_for(self._controller, estimate_from_msg(msg))
        if out is None:
            self.diagnostics.warn(f'force/estimate status {msg.status}: {msg.detail}')
            return
        command = self._command
        command.override_pct = float(out.override_pct)
        command.tracking_error_n = float(out.error_n)
        command.sliding_variable = float(out.sliding_variable)
        command.reference_reachable = bool(out.reachable)
        command.reference_force_n = self._controller.reference_force_n
        command.controller = self._controller.name
        command.header = msg.header   # the estimate's, received anew each time
        self._publisher.publish(command)
        self.diagnostics.published('control/feed_command')
        offset = self._controller.friction_correction()
        if offset != 0.0:   # the drift monitor's friction reading, to the estimator
            self._correction.publish(Float64(data=offset))
            self.diagnostics.published(FRICTION_CORRECTION_TOPIC)
        if out.oscillating != self._oscillating:
            self._oscillating = out.oscillating
            self.diagnostics.set_value('oscillating', out.oscillating)
            if out.oscillating:
                settings = self._controller.in_use
                text = (f'the loop oscillates: the force error swings by '
                        f'{settings.oscillation_swing_n:g} N or more, again and again; '
                        f'oscillation_reaction {settings.oscillation_reaction} from '
                        f'{out.override_pct:g} %, until the run ends or the tool changes '
                        '(or the law takes a lag drift the drift monitor names)')
                if settings.oscillation_reaction == 'none':
                    text = text.split(';')[0] + '; oscillation_reaction none: regulating on'
                self.diagnostics.warn(text, log=True)
            elif self._controller.model:   # let go: the law took a lag drift (control.update)
                self.get_logger().info(f'oscillation reaction let go: {self._controller.model} '
                                       '(drift_adopt_model); the loop is watched afresh')
        if out.drift != self._drift:   # the drift monitor named a cause (control.drift)
            self._drift = out.drift
            text = self._controller.drift
            self.diagnostics.set_value('drift', text)
            if text:
                self.diagnostics.warn(f'the machine drifted from its identified model: {text}',
                                      log=True)
        if self._controller.model != self._model:   # the law took a lag drift (drift_adopt_model)
            self._model = self._controller.model
            self.diagnostics.set_value('model', self._model or 'commissioned')
            if self._model:
                self.get_logger().info(f'{self._model} (drift_adopt_model)')
        if out.reachable != self._reachable:
            self._reachable = out.reachable
            self.diagnostics.set_value('reference_reachable', out.reachable)
            if not out.reachable:
                text = (f'reference {command.reference_force_n:g} N cannot be reached: the feed '
                        f'sits at {out.override_pct:g} % with the force {out.error_n:+.0f} N off')
                self.diagnostics.warn(text, log=True)


main = node_main(ForceControllerNode)


if __name__ == '__main__':
    sys.exit(main())
