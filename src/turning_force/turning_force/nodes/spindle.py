"""``machine/spindle_speed`` on a node: the live spindle speed while it is fresh.

``lathe_sim`` publishes the simulated spindle's speed there (under constant surface speed, G96, it
changes through a facing cut); on the machine a node that reads the spindle encoder or an analog
input publishes it. The controller's laws and the PMC bridge's feed-follow check use it; once
nothing came for ``spindle_speed_stale_s`` (the input unplugged) they fall back to the
``spindle_speed_rpm`` parameter, and ``/diagnostics`` says so (WARN) at every report until it
comes back.
"""

from __future__ import annotations

import math

from rclpy.node import Node
from std_msgs.msg import Float64

from turning_force.nodes.diagnostics import Diagnostics

__all__ = ['SPINDLE_SPEED_TOPIC', 'TOOL_TOPIC', 'SpindleSpeedInput']

SPINDLE_SPEED_TOPIC = 'machine/spindle_speed'
# The tool in use (std_msgs/Int32, the T code's tool number): it selects its section of the
# tools file (core/tools.py) in force_controller and pmc_bridge; lathe_sim publishes the
# simulated program's, before the block's currents, as it does the spindle speed.
TOOL_TOPIC = 'machine/tool'


class SpindleSpeedInput:
    """The speed from ``machine/spindle_speed`` (std_msgs/Float64 [rpm]): :meth:`rpm` is the
    latest while it is fresh, NaN (the parameter) once it is ``stale_after_s`` old or was never
    given; ``stale_after_s`` 0: the topic is not read. A value that is not a speed (not finite,
    not above 0) is refused with a warning and counts as none."""

    def __init__(self, node: Node, diagnostics: Diagnostics, stale_after_s: float,
                 parameter_rpm: float) -> None:
        self._diagnostics = diagnostics
        self._stale_after_s = stale_after_s
        self.parameter_rpm = parameter_rpm
        self._rpm = math.nan
        if stale_after_s > 0:
            diagnostics.watch(SPINDLE_SPEED_TOPIC, stale_after_s=stale_after_s)
            diagnostics.add_provider(self._values)
            node.create_subscription(Float64, SPINDLE_SPEED_TOPIC, self._on_speed, 10)

    def _on_speed(self, msg: Float64) -> None:
        self._diagnostics.received(SPINDLE_SPEED_TOPIC)
        value = float(msg.data)
        if math.isfinite(value) and value > 0.0:
            self._rpm = value
            return
        self._rpm = math.nan
        self._diagnostics.warn(f'{SPINDLE_SPEED_TOPIC}: {value!r} rpm is not a spindle speed: '
                               f'spindle_speed_rpm ({self.parameter_rpm:g} rpm) used')

    def rpm(self) -> float:
        """The live speed [rpm], or NaN where it is stale or not read."""
        if self._stale_after_s <= 0 or self._diagnostics.stale(SPINDLE_SPEED_TOPIC):
            return math.nan
        return self._rpm

    def _values(self) -> dict[str, str]:
        live = self.rpm()
        if math.isnan(live):
            self._diagnostics.warn(f'{SPINDLE_SPEED_TOPIC} unplugged (nothing for '
                                   f'{self._stale_after_s:g} s): spindle_speed_rpm '
                                   f'({self.parameter_rpm:g} rpm) used')
            return {'spindle_speed_rpm': f'{self.parameter_rpm:g}',
                    'spindle_speed_from': 'spindle_speed_rpm parameter'}
        return {'spindle_speed_rpm': f'{live:.1f}', 'spindle_speed_from': SPINDLE_SPEED_TOPIC}
