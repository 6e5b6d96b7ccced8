"""``lathe_sim``: the simulated lathe, standing in for the machine.

Subscribes ``pmc/feed_override`` (turning_force_msgs/FeedOverride): the PMC bits are decoded with
the override table, as the CNC would read them. Publishes, once per control period,
``machine/inputs`` (the simulated program enable, threading and dial, before the block's
currents so that the bridge has them when it answers), ``machine/spindle_speed``
(std_msgs/Float64 [rpm], the spindle encoder's speed at the block's end, unless
``spindle_speed_wired`` is false: the input unplugged), with ``tool_wired`` ``machine/tool``
(std_msgs/Int32, the simulated program's tool number), ``servo/currents`` (a block of DAQ
samples), ``servo/joint_state`` (feed axis ``z``: position [m], velocity [m/s], effort = true
cutting force [N]) and ``sim/cutting_state`` (ground truth); with ``dynamometer`` also
``force/measured`` (geometry_msgs/WrenchStamped, ``wrench.force.z`` [N], for ``turning-force
calibrate --map``); with ``publish_clock`` it owns ``/clock`` and advances it one control period
per step (lock-step). Parameters: :class:`turning_force.core.plant.settings.PlantSettings`, and
``machine_file`` and ``backend``, shared with ``pmc_bridge``: with ``backend: modbus_tcp`` the
override is read each step from the coils of the simulated PMC's Modbus/TCP server, as the PMC
would: the loop closes through the real protocol.

On the wall clock it measures, per block, the time from the block's currents going out to the
override answering it coming back (the whole loop as the PMC would see it), and reports it on
``/diagnostics`` over ``latency_window_s`` (:class:`turning_force.nodes.diagnostics.AnswerLatency`:
``LATENCY_KEYS``); the status is WARN while the window holds a missed period.
"""

from __future__ import annotations

import sys
import time
from typing import Any

import numpy as np
from geometry_msgs.msg import WrenchStamped
from rclpy.node import Node
from rclpy.task import Future
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64, Int32
from turning_force_msgs.msg import CuttingState, FeedOverride, MachineInputs, ServoCurrents

from turning_force.core import kernel
from turning_force.core.catalog import LatheSimNodeSettings
from turning_force.core.errors import ConfigError, TurningForceError
from turning_force.core.plant.lathe import LathePlant
from turning_force.core.plant.settings import Dynamometer, PlantBlock, PlantSettings
from turning_force.core.pmc.machine import load_machine
from turning_force.core.pmc.overrides import get_table
from turning_force.nodes.convert import (
    block_to_servo_currents,
    inputs_to_msg,
    last_sample_ns,
    set_stamp,
    stamp_to_ns,
)
from turning_force.nodes.diagnostics import AnswerLatency, Diagnostics
from turning_force.nodes.parameters import SettingsParameters, declare
from turning_force.nodes.spin import STREAM_DEPTH, node_main, timer_callback
from turning_force.nodes.spindle import SPINDLE_SPEED_TOPIC, TOOL_TOPIC

__all__ = ['LatheSimNode', 'main']


class LatheSimNode(Node):
    """The plant on the graph. ``step()`` advances it one control period.

    In real time a wall timer calls ``step()``; in lock-step (``lockstep=True``) the runner
    does, after the graph has answered the previous block.
    """

    FRAME = 'z_axis'

    def __init__(self, *, lockstep: bool = False, **kwargs: Any) -> None:
        super().__init__('lathe_sim', **kwargs)
        kernel.load()   # the compiled code, before the first block (compiled on a cold cache)
        self._publish_clock = bool(declare(self, LatheSimNodeSettings, 'publish_clock'))
        window_s = float(declare(self, LatheSimNodeSettings, 'latency_window_s'))
        self.parameters = SettingsParameters(self, PlantSettings)
        settings = self.parameters.current
        self._table = get_table(settings.override_table)
        self._applied_pct = settings.approach_override_pct   # the level the axis approached at
        self._coils = self._coil_reader(settings.override_table)
        self._plant = LathePlant(settings, initial_override_pct=self._applied_pct)
        # Plant time 0 is this node's clock at start (0 in lock-step sim time).
        self._t0_ns = 0 if lockstep else self.get_clock().now().nanoseconds
        self._awaited: tuple[int, Future[int]] | None = None
        self._last_ns = -1   # the answer stamp of the last block published
        # One message of each kind, refilled every period (rclpy serialises on publish).
        self._clock_msg = Clock()
        self._inputs_msg = MachineInputs()
        self._currents_msg = ServoCurrents()
        self._joint_msg = JointState(name=['z'])
        self._truth_msg = CuttingState()
        self._measured_msg = WrenchStamped()
        for message in (self._currents_msg, self._joint_msg, self._truth_msg,
                        self._measured_msg):
            message.header.frame_id = self.FRAME
        self.diagnostics = Diagnostics(self)
        self.latency: AnswerLatency | None = None
        if not lockstep:   # lock-step has no wall-clock period to keep
            self.latency = AnswerLatency(round(window_s / settings.control_period_s),
                                         settings.control_period_s)
            self.diagnostics.add_provider(self._latency_values)
        self.diagnostics.watch('pmc/feed_override', stale_after_s=5 * settings.control_period_s)
        self.diagnostics.set_value('override_from', 'pmc/feed_override' if self._coils is None
                                   else f'coils of modbus_tcp {self._coils.where}')
        self._clock_publisher = (self.create_publisher(Clock, '/clock', 10)
                                 if self._publish_clock else None)
        self._inputs = self.create_publisher(MachineInputs, 'machine/inputs', STREAM_DEPTH)
        self._speed_msg = Float64()
        self._speed = (self.create_publisher(Float64, SPINDLE_SPEED_TOPIC, 10)
                       if settings.spindle_speed_wired else None)
        self._tool_msg = Int32()
        self._tool = (self.create_publisher(Int32, TOOL_TOPIC, 10) if settings.tool_wired
                      else None)
        self._currents = self.create_publisher(ServoCurrents, 'servo/currents', STREAM_DEPTH)
        self._joint = self.create_publisher(JointState, 'servo/joint_state', STREAM_DEPTH)
        self._truth = self.create_publisher(CuttingState, 'sim/cutting_state', STREAM_DEPTH)
        self._dynamometer = (Dynamometer(settings.dynamometer_noise_n, settings.seed)
                             if settings.dynamometer else None)
        self._measured = (self.create_publisher(WrenchStamped, 'force/measured', 10)
                          if settings.dynamometer else None)
        self.create_subscription(FeedOverride, 'pmc/feed_override', self._on_override, 10)
        if not lockstep:
            self.create_timer(settings.control_period_s, timer_callback(self.step))

    def _coil_reader(self, override_table: str) -> Any:
        """The PMC's input image on Modbus/TCP, when ``backend`` is ``modbus_tcp``."""
        path = str(declare(self, LatheSimNodeSettings, 'machine_file'))
        backend = str(declare(self, LatheSimNodeSettings, 'backend'))
        if backend == 'simulated':
            return None
        where = self.get_fully_qualified_name()
        if backend != 'modbus_tcp' or not path:
            raise ConfigError(f'{where}: backend = {backend!r}: expected simulated, or '
                              'modbus_tcp with a machine_file')
        machine = load_machine(path)
        machine.check_table(override_table)
        from turning_force.io.modbus_pmc import CoilReader

        return CoilReader(machine)

    @property
    def applied_pct(self) -> float:
        return self._applied_pct

    def destroy_node(self) -> None:
        coils = getattr(self, '_coils', None)   # absent when the parameters were refused
        if coils is not None:
            coils.close()
        super().destroy_node()

    def _latency_values(self) -> dict[str, str]:
        assert self.latency is not None
        values = self.latency.values()
        if values['missed_periods'] != '0':
            self.diagnostics.warn(f'{values["missed_periods"]} missed periods in the last '
                                  f'{values["latency_window_s"]} s: the graph does not keep up')
        return values

    def _on_override(self, msg: FeedOverride) -> None:
        stamp_ns = stamp_to_ns(msg.header.stamp)
        if self.latency is not None:
            self.latency.answered(stamp_ns, time.perf_counter_ns())
        self.diagnostics.received('pmc/feed_override')
        if self._coils is None:   # else the PMC reads its coils at the next step
            self._take_override(msg)
        if self._awaited is not None and self._awaited[0] == stamp_ns:
            self._awaited[1].set_result(stamp_ns)
            self._awaited = None

    def _take_override(self, msg: FeedOverride) -> None:
        try:
            pct = (msg.applied_pct if self._table.continuous
                   else self._table.decode(tuple(msg.pmc_bits)))
        except ValueError as exc:
            self.diagnostics.error(f'pmc/feed_override: {exc}')
            return
        self._applied_pct = pct

    def answer(self, block: PlantBlock) -> Future[int]:
        """A future done when the override answering ``block`` (stamped with its last sample's
        time, as the estimate, command and override that answer it are) has arrived."""
        future: Future[int] = Future()
        self._awaited = (self._last_ns, future)
        return future

    def step(self) -> PlantBlock:
        """Advance one control period at the applied override and publish what it gives.

        The block's currents go out last, once everything else about the block is out: the
        bridge has the machine's inputs before it answers, and the loop's latency is measured
        from the currents on."""
        if self._coils is not None:
            try:
                self._applied_pct = self._coils.read_pct()
            except TurningForceError as exc:   # the PMC keeps the last override it read
                self.diagnostics.error(str(exc))
        block = self._plant.step(self._applied_pct)
        currents = block.currents
        message = block_to_servo_currents(currents, self.FRAME, self._currents_msg)
        first_ns = self._t0_ns + round(currents.t0_s * 1e9)
        set_stamp(message.header.stamp, first_ns)
        last_ns = last_sample_ns(message)   # the stamp of everything that answers the block
        if self._clock_publisher is not None:  # the block is complete one sample later
            set_stamp(self._clock_msg.clock, last_ns + round(currents.sample_period_s * 1e9))
            self._clock_publisher.publish(self._clock_msg)
        inputs = inputs_to_msg(block.inputs, self._inputs_msg)   # before the currents: the
        set_stamp(inputs.header.stamp, last_ns)   # bridge's answer to this block must see them
        self._inputs.publish(inputs)
        if self._speed is not None:
            self._speed_msg.data = float(block.spindle_speed_rpm)
            self._speed.publish(self._speed_msg)
            self.diagnostics.published(SPINDLE_SPEED_TOPIC)
        if self._tool is not None and block.inputs.tool_number is not None:
            self._tool_msg.data = int(block.inputs.tool_number)
            self._tool.publish(self._tool_msg)
        joint = self._joint_msg
        set_stamp(joint.header.stamp, last_ns)
        joint.position = [self._plant.position_mm / 1000.0]
        joint.velocity = [float(currents.feed_rate_mm_min[-1]) / 60000.0]
        joint.effort = [float(block.force_n[-1])]
        self._joint.publish(joint)
        s = self._plant.settings
        truth = self._truth_msg
        set_stamp(truth.header.stamp, last_ns)
        truth.force_n = float(block.force_n[-1])
        truth.depth_of_cut_mm = float(block.depth_mm[-1])
        truth.spindle_speed_rpm = float(block.spindle_speed_rpm)
        truth.feed_mm_rev = float(block.feed_mm_rev[-1])
        truth.feed_rate_mm_min = float(currents.feed_rate_mm_min[-1])
        truth.specific_cutting_force_n_mm2 = float(s.material_at(np.array([
            currents.t0_s + len(currents) * currents.sample_period_s]))[0])
        truth.override_pct = float(block.override_pct)
        self._truth.publish(truth)
        if self._dynamometer is not None and self._measured is not None:
            measured = self._measured_msg
            set_stamp(measured.header.stamp, last_ns)
            measured.wrench.force.z = self._dynamometer.read_n(block.force_n)
            self._measured.publish(measured)
            self.diagnostics.published('force/measured')
        self._last_ns = last_ns
        if self.latency is not None:
            self.latency.published(last_ns, time.perf_counter_ns())
        self._currents.publish(message)
        for topic in ('machine/inputs', 'servo/currents', 'servo/joint_state',
                      'sim/cutting_state'):
            self.diagnostics.published(topic)
        return block


main = node_main(LatheSimNode)


if __name__ == '__main__':
    sys.exit(main())
