"""``pmc_bridge``: what reaches the CNC's PMC, safe first. A lifecycle (managed) node.

Subscribes ``control/feed_command`` (turning_force_msgs/FeedCommand), ``force/estimate``
(turning_force_msgs/ForceEstimate), ``machine/inputs``, ``servo/currents`` (the axis feed the DAQ
recorded, against the override applied: the gate's feed-follow check) and
``machine/spindle_speed`` (the speed that check judges the feed at); publishes
``pmc/feed_override`` (turning_force_msgs/FeedOverride), ``pmc/cuts``
(turning_force_msgs/CutRecord) and, with ``teach_file``, ``force/reference`` (std_msgs/Float64,
transient-local); writes the PMC backend.
Parameters: :class:`turning_force.core.pmc.settings.BridgeSettings`, and ``autostart`` (configure
and activate at start). The decisions (disarmed, watchdog, invalid command, overload hold, the
shop-floor behaviours) are :class:`turning_force.core.pmc.gate.OverrideGate`'s.

Lifecycle (docs/machine-pc.md): configure loads ``machine_file`` (refusing wiring that is not
safe when de-energised) and opens the backend; activate lets the gate run and arm (``armed`` or
``~/arm``); deactivate, cleanup and shutdown hand the feed back: the operator's dial where
wired, else 100 %, never above ``hand_back_pct`` (docs/safety.md). With ``backend: modbus_tcp``
each override goes to the module in one request and is read back
(:class:`turning_force.io.modbus_pmc.ModbusPmc`); an I/O fault (a malformed answer included:
never an exception) disarms the bridge, says why (``REASON_IO_FAULT``, ``/diagnostics``) and
reconnects with back-off; arming is refused while it lasts, and the bridge stays disarmed after
it until armed again. A period without an answer is a miss, counted on ``/diagnostics``; only
``max_missed_periods`` in a row are a fault. The machine's inputs come from the module where
the machine file wires them, else from ``machine/inputs``; every ``FeedOverride`` records the
inputs its decision saw, so that replay decides alike. Every watchdog, timeout and rate limit
reads the steady clock (``/clock`` in sim time), never the wall clock.
"""

from __future__ import annotations

import dataclasses
import math
import sys
from dataclasses import replace
from typing import Any

import numpy as np
from rcl_interfaces.msg import SetParametersResult
from rclpy.clock import Clock
from rclpy.clock_type import ClockType
from rclpy.lifecycle import LifecycleNode, LifecycleState, TransitionCallbackReturn
from rclpy.parameter import Parameter
from std_msgs.msg import Float64, Header, Int32
from std_srvs.srv import Trigger
from turning_force_msgs.msg import (
    CutRecord,
    FeedCommand,
    FeedOverride,
    ForceEstimate,
    MachineInputs,
    ServoCurrents,
)

from turning_force.core import kernel
from turning_force.core.catalog import BridgeNodeSettings
from turning_force.core.errors import ConfigError, TurningForceError, short_repr
from turning_force.core.kernel.chain import check_taught_reference, command_for_would_act
from turning_force.core.pmc.gate import OverrideGate
from turning_force.core.pmc.machine import Machine, load_machine
from turning_force.core.pmc.overrides import OverrideTable
from turning_force.core.pmc.settings import BridgeSettings, Decision, Reason
from turning_force.core.pmc.shopfloor import (
    NO_INPUTS,
    InputValues,
    Learned,
    save_teach_file,
    taught_reference,
)
from turning_force.nodes.convert import (
    cut_to_msg,
    estimate_from_msg,
    inputs_from_msg,
    inputs_to_msg,
    ns_to_stamp,
)
from turning_force.nodes.diagnostics import Diagnostics
from turning_force.nodes.force_controller import REFERENCE_QOS
from turning_force.nodes.parameters import SettingsParameters, declare
from turning_force.nodes.spin import STREAM_DEPTH, NodeTime, node_main, timer_callback
from turning_force.nodes.spindle import TOOL_TOPIC, SpindleSpeedInput

__all__ = ['BridgeStartError', 'PmcBridgeNode', 'SimulatedPmc', 'main']

# Reasons that are the option at work, not news: not logged as warnings.
QUIET_REASONS = (Reason.NORMAL, Reason.DISARMED, Reason.OPERATOR, Reason.AIR_CUT,
                 Reason.RISE_LIMIT, Reason.FEED_FLOOR, Reason.TEACH_IN)


class BridgeStartError(TurningForceError):
    """The bridge could not be configured or activated (the reason is in the text)."""


class SimulatedPmc:
    """The PMC backend of a simulated machine: remembers what was written."""

    polled = False

    def __init__(self) -> None:
        self.code = -1
        self.bits: tuple[bool, ...] = ()
        self.writes = 0

    def write(self, code: int, bits: tuple[bool, ...]) -> None:
        self.code, self.bits = code, bits
        self.writes += 1


class PmcBridgeNode(LifecycleNode):
    """Feed command in, override to the PMC out, through the safety gate."""

    def __init__(self, *, autostart: bool | None = None, **kwargs: Any) -> None:
        """``autostart``: configure and activate now (true), wait for transitions (false), or
        as the ``autostart`` parameter says (``None``)."""
        super().__init__('pmc_bridge', **kwargs)
        kernel.load()   # the compiled code, before the first block (compiled on a cold cache)
        # The gate's clock, without a clock call per message: steady (or /clock), never the
        # wall clock, which NTP or an operator may step either way.
        self._time = NodeTime(self, steady=True)
        # Set first: the context's cleanup may destroy a node whose parameters were refused.
        self.machine: Machine | None = None
        self.backend: Any = None        # SimulatedPmc or ModbusPmc once configured
        self.inputs: Any = None         # InputValues from the module, once read
        self._module_inputs = NO_INPUTS  # those of the module's inputs the machine file wires
        self._dial_read: float | None = None   # the dial as last read (raised when confirmed)
        self._topic_inputs = NO_INPUTS   # machine/inputs (the simulated machine's)
        self._topic_tool: int | None = None   # machine/tool (the tool in use)
        self.cuts: list[CutRecord] = []  # the cuts published on pmc/cuts
        self._gate_outputs: dict[str, bool] = {}   # the outputs as the gate last set them
        self.io_fault = ''
        self.misses = 0
        self.configure_error = ''
        self._active = False
        declare(self, BridgeNodeSettings, 'autostart')
        self.parameters = SettingsParameters(self, BridgeSettings, self._reconfigure)
        self.add_on_set_parameters_callback(self._refuse_arming_in_fault)
        settings = self.parameters.current
        self.gate = OverrideGate(settings)
        self._exchanged = False         # an exchange since the last timer tick
        self._last_written: Decision | None = None
        self._last_exchanged: Decision | None = None   # the last one the module read back
        self._last_reason: Reason | None = None
        self._last_published: tuple[float, Reason] | None = None
        self.diagnostics = Diagnostics(self)
        self.diagnostics.watch('control/feed_command', stale_after_s=settings.watchdog_period_s)
        self.diagnostics.set_value('state', 'unconfigured')
        self.diagnostics.add_provider(lambda: {'arming': self.state_text()})
        self._publisher = self.create_publisher(FeedOverride, 'pmc/feed_override', STREAM_DEPTH)
        self._override = FeedOverride()   # refilled per write (rclpy serialises on publish)
        self._cut_publisher = self.create_publisher(CutRecord, 'pmc/cuts', 10)
        self._reference_publisher = self.create_publisher(Float64, 'force/reference',
                                                          REFERENCE_QOS)
        self.create_subscription(MachineInputs, 'machine/inputs', self._on_inputs, 10)
        self.create_subscription(Int32, TOOL_TOPIC, self._on_tool, 10)
        self.create_subscription(FeedCommand, 'control/feed_command', self._on_command, 10)
        self.create_subscription(ForceEstimate, 'force/estimate', self._on_estimate, 10)
        self._feed_mm_min = math.nan   # the last block's mean axis feed, until its estimate
        self.create_subscription(ServoCurrents, 'servo/currents', self._on_currents, 10)
        self.spindle = SpindleSpeedInput(self, self.diagnostics, settings.spindle_speed_stale_s,
                                         settings.spindle_speed_rpm)
        self.create_service(Trigger, '~/arm', self._on_arm)
        self.create_service(Trigger, '~/disarm', self._on_disarm)
        # The period's timer on the steady clock too (a wall-clock timer stalls when the date
        # is set back); on /clock in sim time, for lock-step determinism.
        sim_time = bool(self.get_parameter('use_sim_time').value)
        self.create_timer(settings.control_period_s, timer_callback(self._on_timer),
                          clock=None if sim_time else Clock(clock_type=ClockType.STEADY_TIME))
        if self.get_parameter('autostart').value if autostart is None else autostart:
            self.start()

    # --- lifecycle ---------------------------------------------------------------------------

    def start(self) -> None:
        """Configure and activate now; :class:`BridgeStartError` says why when it cannot."""
        if self.trigger_configure() != TransitionCallbackReturn.SUCCESS:
            raise BridgeStartError(f'{self.get_fully_qualified_name()}: configure failed: '
                                   f'{self.configure_error or "see the log"}')
        if self.trigger_activate() != TransitionCallbackReturn.SUCCESS:
            raise BridgeStartError(f'{self.get_fully_qualified_name()}: activate failed')

    def stop(self) -> None:
        """Deactivate (hand the feed back) and release the module, from whatever state."""
        if self._active:
            self.trigger_deactivate()
        if self.backend is not None:
            self.trigger_cleanup()

    @property
    def active(self) -> bool:
        return self._active

    def destroy_node(self) -> None:
        """Hand the feed back and release the module before the node goes."""
        try:
            self.stop()
        finally:
            node_time = getattr(self, '_time', None)   # absent when parameters were refused
            if node_time is not None:
                node_time.close()
            super().destroy_node()

    def on_configure(self, state: LifecycleState) -> TransitionCallbackReturn:
        try:
            self._configure()
        except TurningForceError as exc:
            self.configure_error = str(exc)
            self.diagnostics.error(self.configure_error, log=True)
            self._release()
            return TransitionCallbackReturn.FAILURE
        self.configure_error = ''
        self.diagnostics.set_value('state', 'inactive')
        return TransitionCallbackReturn.SUCCESS

    def on_activate(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._active = True
        self.gate.restart()   # starts again (and arms, if armed is set) at its next callback
        self.diagnostics.set_value('state', 'active')
        return TransitionCallbackReturn.SUCCESS

    def on_deactivate(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._active = False
        self.gate.disarm()
        self.gate.close()   # the cut still open, marked incomplete
        self._publish_cuts()
        self.diagnostics.set_value('state', 'inactive')
        self._write(self._hand_back(), None)
        return TransitionCallbackReturn.SUCCESS

    def on_cleanup(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._release()
        self.diagnostics.set_value('state', 'unconfigured')
        return TransitionCallbackReturn.SUCCESS

    def on_shutdown(self, state: LifecycleState) -> TransitionCallbackReturn:
        if self._active:
            self._active = False
            self._write(self._hand_back(), None)
        self._release()
        self.diagnostics.set_value('state', 'finalized')
        return TransitionCallbackReturn.SUCCESS

    def on_error(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._active = False
        if self.backend is not None:
            self._write(self._hand_back(), None)
        self._release()
        self.diagnostics.set_value('state', 'unconfigured')
        return TransitionCallbackReturn.SUCCESS

    def _configure(self) -> None:
        settings = self.parameters.current
        where = self.get_fully_qualified_name()
        machine = None
        if settings.machine_file:
            machine = load_machine(settings.machine_file)
            machine.check_table(settings.override_table)
            machine.check_de_energised(settings.hand_back_pct)
        if settings.backend == 'modbus_tcp':
            if machine is None or machine.modbus is None:
                what = ('no machine_file' if machine is None
                        else f'{machine.source} has backend.type {machine.backend!r}')
                raise ConfigError(f"{where}: backend = 'modbus_tcp': {what}; the module's "
                                  'host, port and coils come from a machine file')
            from turning_force.io.modbus_pmc import ModbusPmc

            machine.modbus.check_miss_budget(settings.control_period_s, machine.source)
            backend: Any = ModbusPmc(machine, settings.control_period_s)
            fault = backend.connect()
            if fault:
                raise BridgeStartError(f'{where}: {fault}')
            self.inputs = self._module_inputs = backend.inputs
            self._take_inputs()
            self.diagnostics.set_value('backend', backend.where)
            self.diagnostics.set_value('io_timeout_ms', f'{backend.timeout_s * 1e3:.1f}')
        else:
            backend = SimulatedPmc()
            self.diagnostics.set_value('backend', 'simulated')
        self.machine, self.backend, self.io_fault = machine, backend, ''
        self._last_written = None
        self._write(self._hand_back(), None)   # a known state: the programmed feed
        if self.io_fault:
            raise BridgeStartError(f'{where}: {self.io_fault}')
        self._teach_in(settings)

    def _teach_in(self, settings: BridgeSettings) -> None:
        """Publish the tool's taught reference (a malformed file fails the configuration)."""
        if not settings.teach_file:
            return
        if settings.teach_in:
            self.diagnostics.set_value('teach-in', f'learning cut for {settings.tool}')
            return
        reference = taught_reference(settings)
        if reference is None:
            text = (f'{settings.teach_file}: tool {settings.tool} not taught: the controller '
                    'keeps its reference_force_n')
            self.diagnostics.warn(text, log=True)
            return
        check_taught_reference(reference, settings)
        self._reference_publisher.publish(Float64(data=reference))
        self.get_logger().info(f'{settings.tool}: taught reference {reference:g} N from '
                               f'{settings.teach_file}')
        self.diagnostics.set_value('teach-in', f'{settings.tool}: reference {reference:g} N')

    def _release(self) -> None:
        self._active = False
        if self.backend is not None and self.backend.polled:
            self.backend.close()
        self.backend = None

    # --- what to write -------------------------------------------------------------------------

    @property
    def table(self) -> OverrideTable:
        return self.gate.table

    def _hand_back(self, requested_pct: float = float('nan')) -> Decision:
        """Inactive: the operator's dial where one is wired and read, else the programmed feed;
        never above ``hand_back_pct``, whatever the dial reads (an unwired 4-bit dial reads
        150 %, the code of all inputs off: docs/safety.md)."""
        level = self.parameters.current.hand_back_pct
        dial = None if self.inputs is None else self.inputs.operator_dial_pct
        if dial is not None and dial < level:
            pct = self.table.level_at_most(dial)
            reason = Reason.OPERATOR
            detail = f"inactive: feed handed back to the operator's dial ({dial:g} %)"
        else:
            pct, reason = level, Reason.DISARMED
            detail = ('inactive: programmed feed' if level >= 100.0
                      else f'inactive: the hand-back level ({level:g} %)')
            if dial is not None:
                detail += f"; the operator's dial reads {dial:g} %"
        code, bits = self.table.encode(pct)
        return Decision(pct, requested_pct, code, bits, False, reason, detail,
                        self.gate.inputs)

    def _decide(self, requested_pct: float = float('nan')) -> Decision:
        if self._active:
            return self.gate.decide(self._now_s())
        return self._hand_back(requested_pct)

    def _answer(self, requested_pct: float = float('nan')) -> Decision:
        """The decision that answers a block: the gate's (its per-block state moves on: rise
        limit, cut log, teach-in) while active."""
        if not self._active:
            return self._hand_back(requested_pct)
        decision = self.gate.answer(self._now_s())
        learned = self.gate.take_learned()
        if learned is not None:
            self._learned(learned)
        self._publish_cuts()
        return decision

    def _learned(self, learned: Learned) -> None:
        """A learning cut has ended: keep its level in the teach-in file, set the reference."""
        settings = self.parameters.current
        if learned.refused:
            text = f'teach-in for {learned.tool}: not learned: {learned.refused}'
            self.diagnostics.warn(text, log=True)
            return
        taught = learned.taught
        try:
            save_teach_file(settings.teach_file, learned.tool, taught)
        except ConfigError as exc:   # the reference is still set for this session
            self.diagnostics.error(str(exc), log=True)
        # Published before the override that answers this block: the controller has it for the
        # next block, as the core loop's chain retunes its controller after this one.
        self._reference_publisher.publish(Float64(data=taught.reference_force_n))
        text = (f'teach-in for {learned.tool}: learned {taught.learned_force_n:.1f} N, '
                f'reference {taught.reference_force_n:.1f} N ({settings.teach_file})')
        self.get_logger().info(text)
        self.diagnostics.set_value('teach-in', text)

    def _publish_cuts(self) -> None:
        for record in self.gate.take_cuts():
            self.cuts.append(record)
            self._cut_publisher.publish(cut_to_msg(record))
            self.diagnostics.set_value('cuts', len(self.cuts))

    def set_output(self, name: str, value: bool) -> None:
        """Set an output of the machine file (``alarm``, ``stop_request``) at the next period."""
        if self.backend is None or not self.backend.polled:
            raise ConfigError(f'{self.get_fully_qualified_name()}: outputs.{name}: no module '
                              'configured')
        self.backend.set_output(name, value)

    # --- callbacks ---------------------------------------------------------------------------

    def _now_s(self) -> float:
        now = self._time.ns() * 1e-9
        if not self.gate.started and self._active:
            self.gate.start(now)
        return now

    def _reconfigure(self, settings: BridgeSettings) -> None:
        self.gate.reconfigure(settings, self._now_s())

    def _refuse_arming_in_fault(self, parameters: list[Parameter[Any]]) -> SetParametersResult:
        """``armed`` cannot be set while the module is in fault (nor through ``ros2 param``)."""
        for parameter in parameters:
            if parameter.name == 'armed' and parameter.value and self.io_fault:
                return SetParametersResult(successful=False, reason=(
                    f'arm refused: the module is in fault: {self.io_fault}'))
        return SetParametersResult(successful=True)

    def arm(self) -> tuple[bool, str]:
        """Arm as ``~/arm`` does: (whether it acts, what the service would answer)."""
        response = self._set_armed(True, Trigger.Response())
        return bool(response.success), str(response.message)

    def state_text(self) -> str:
        """What state the bridge is in and what arms it, in one line (the machine's first)."""
        settings = self.parameters.current
        where = self.get_fully_qualified_name()
        if self.configure_error:
            return f'{where}: not configured: {self.configure_error}'
        state = 'active' if self._active else ('inactive' if self.backend is not None
                                               else 'unconfigured')
        if self.io_fault:
            return f'{where}: {state}, in fault, disarmed: {self.io_fault}'
        if settings.armed:
            return f'{where}: {state}, armed'
        wired = self.machine is not None and self.machine.inputs.program_enable is not None
        enable = (', and acts only while the program-enable input is on' if wired
                  and settings.program_enable_required else '')
        return (f'{where}: {state}, disarmed (the programmed feed, at most '
                f'{settings.hand_back_pct:g} %): it never arms by itself; arm it with '
                f'`ros2 service call {where}/arm std_srvs/srv/Trigger`{enable}')

    def _set_armed(self, armed: bool, response: Trigger.Response) -> Trigger.Response:
        result = self._set_parameter('armed', armed)
        if armed and result.successful:
            held = self.gate.arm(self._now_s())  # re-arming clears a hold, if the force is down
            if held:
                response.success = False
                response.message = f'armed, but the feed stays held: {held}'
                self._write(self.gate.decide(self._now_s()), None)
                return response
        response.success = result.successful
        response.message = 'armed' if armed else 'disarmed'
        if not result.successful:
            response.message = result.reason
        elif armed and not self._active:
            response.message = 'armed; acts once active'
        self._write(self._decide(), None)
        return response

    def _set_parameter(self, name: str, value: Any) -> Any:
        return self.set_parameters([Parameter(name, value=value)])[0]

    def _on_arm(self, request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        return self._set_armed(True, response)

    def _on_disarm(self, request: Trigger.Request,
                   response: Trigger.Response) -> Trigger.Response:
        return self._set_armed(False, response)

    def _on_command(self, msg: FeedCommand) -> None:
        self.diagnostics.received('control/feed_command')
        if self._active:
            self.gate.on_command(msg.override_pct, self._now_s(), bool(msg.reference_reachable))
        self._write(self._answer(msg.override_pct), msg)

    def _on_inputs(self, msg: MachineInputs) -> None:
        self.diagnostics.received('machine/inputs')
        self._topic_inputs = inputs_from_msg(msg)
        self._take_inputs()

    def _on_tool(self, msg: Int32) -> None:
        self.diagnostics.received(TOOL_TOPIC)
        self._topic_tool = int(msg.data)
        before = self.gate.tool_number
        self._take_inputs()
        if self.gate.tool_number != before:
            self.diagnostics.set_value('tool', str(self.gate.tool_number))
            if self.gate.tool_unknown:
                self.diagnostics.error(f'{TOOL_TOPIC}: tool {msg.data} has no section in '
                                       f'{self.gate.settings.tools_file}: feed handed back',
                                       log=True)

    def _take_inputs(self) -> None:
        """The inputs in force: the module's where the machine file wires them, else the
        topics'."""
        topic = dataclasses.replace(self._topic_inputs, tool_number=self._topic_tool)
        self.gate.on_inputs(self._module_inputs.over(topic))

    def _on_currents(self, msg: ServoCurrents) -> None:
        self.diagnostics.received('servo/currents')
        feed = msg.feed_rate_mm_min
        self._feed_mm_min = float(np.mean(feed)) if len(feed) else math.nan

    def _on_estimate(self, msg: ForceEstimate) -> None:
        self.diagnostics.received('force/estimate')
        estimate = estimate_from_msg(msg)
        if self._active and self.gate.on_estimate(estimate.force_n, estimate.status):
            self._write(self.gate.decide(self._now_s()), None)  # hold now, not at next command
        if self._active:   # the block's feed, judged as the chain does: after its estimate
            self.gate.on_feed(self._feed_mm_min, self.spindle.rpm())
        self._feed_mm_min = math.nan
        if command_for_would_act(estimate):
            return   # the controller's command for this block will answer it
        # No command will answer this block: the gate answers it (watchdog, hold), stamped as
        # the block, so that the PMC and a lock-step run see a decision for every block.
        self._write(self._answer(), msg)

    def _on_timer(self) -> None:
        # The command path writes what commands decide; the timer writes what time decides
        # (a stale command), so a dead controller still leads to the safe override. It writes
        # only a change: the PMC holds its value, and a lock-step run stays deterministic.
        # A module is also polled (written, read back, inputs read) in a period without a
        # command, so that a fault or an input change is seen within a period or two.
        exchanged, self._exchanged = self._exchanged, False
        if self.backend is None:
            return
        decision = self._decide()
        last = self._last_written
        changed = last is None or (decision.applied_pct, decision.reason) != (last.applied_pct,
                                                                               last.reason)
        if changed or (self.backend.polled and not exchanged):
            self._write(decision, None, always=False)

    # --- the write -------------------------------------------------------------------------

    def _write(self, decision: Decision, answers: FeedCommand | ForceEstimate | None,
               always: bool = True) -> None:
        """Write a decision to the backend and publish what the PMC got: always an answer to a
        block (a command, or an estimate no command will follow); otherwise, with ``always``
        false (the timer), only a change."""
        if self.backend is None:
            return   # unconfigured: no PMC to write to
        self._last_written = decision
        if self._active:
            self._set_outputs(decision)
        written = self._exchange(decision)
        self._exchanged = True
        outcome = (written.applied_pct, written.reason)
        if answers is None and not always and outcome == self._last_published:
            return
        self._last_published = outcome
        msg = self._override
        msg.applied_pct = written.applied_pct
        msg.requested_pct = written.requested_pct
        msg.pmc_code = written.code
        msg.pmc_bits = list(written.bits)
        msg.table = self.table.name
        msg.armed = written.armed
        msg.reason = int(written.reason)
        msg.detail = written.detail
        inputs_to_msg(written.inputs, msg)   # the inputs the decision saw, as machine/inputs
        msg.engaged = written.engaged
        msg.alarm = written.alarm
        msg.stop_request = written.stop_request
        tool = written.inputs.tool_number
        msg.tool_number = -1 if tool is None else int(tool)
        if answers is not None:
            msg.header = answers.header   # answers this block (lock-step matches on it)
        else:
            msg.header = Header(stamp=ns_to_stamp(self._time.ns()))
        self._publisher.publish(msg)
        self.diagnostics.published('pmc/feed_override')
        if written.reason != self._last_reason:
            if written.reason not in QUIET_REASONS:
                self.diagnostics.warn(f'{written.reason.name}: {written.detail}', log=True)
            self._last_reason = written.reason
        self.diagnostics.set_value('reason', written.reason.name)
        self.diagnostics.set_value('applied_pct', written.applied_pct)

    def _exchange(self, decision: Decision) -> Decision:
        """Put ``decision`` on the PMC; what the PMC got (an I/O fault decision on a fault:
        whatever goes wrong with the module, never an exception)."""
        backend = self.backend
        if not backend.polled:
            backend.write(decision.code, decision.bits)
            return decision
        try:
            return self._exchange_module(backend, decision)
        except Exception as exc:
            backend.close()
            return self._fault(decision, f'{backend.where}: {type(exc).__name__}: '
                                         f'{short_repr(str(exc))}')

    def _exchange_module(self, backend: Any, decision: Decision) -> Decision:
        if not backend.connected and not backend.missed_in_row:
            if not backend.reconnect_due():
                return self._fault(decision, backend.fault)
            fault = backend.connect()
            if fault:
                return self._fault(decision, fault)
        result = backend.write(decision.code, decision.bits)
        if result.missed:
            return self._missed(decision, result.missed)
        if not result.ok:   # the inputs as they were: none were read
            return self._fault(decision, result.fault)
        self.inputs = self._module_inputs = self._confirmed(result.inputs)
        self._take_inputs()   # for the next decision: these were read after this one
        self._report_inputs()
        self.diagnostics.set_value('io_round_trip_ms', f'{result.round_trip_s * 1e3:.2f}')
        self._count_misses()
        if self.io_fault:
            self.get_logger().info(f'{backend.where}: answering again; the bridge stays '
                                   'disarmed until armed')
            self.diagnostics.set_value('io', 'ok')
            self.io_fault = ''
        # What the PMC really sees: the bits read back (equal to those written, or a fault).
        seen = replace(decision, applied_pct=self.table.decode(result.bits), bits=result.bits)
        self._last_exchanged = seen
        return seen

    def _confirmed(self, inputs: InputValues) -> InputValues:
        """The module's inputs, the operator's dial raised only once two reads in a row agree
        (lowered at once): one corrupted answer must not raise the feed."""
        dial, last = inputs.operator_dial_pct, self._dial_read
        self._dial_read = dial
        held = self._module_inputs.operator_dial_pct
        if dial is None or held is None or dial <= held or dial == last:
            return inputs
        return replace(inputs, operator_dial_pct=held)

    def _count_misses(self) -> None:
        backend = self.backend
        if backend.misses != self.misses:
            self.misses = backend.misses
            self.diagnostics.set_value('io_misses', backend.misses)
            self.diagnostics.set_value('io_retries', backend.retries)

    def _missed(self, decision: Decision, missed: str) -> Decision:
        """No answer this period, within the miss budget: the PMC holds what it held (the last
        level read back), and the next period writes again."""
        self._count_misses()
        last = self._last_exchanged
        if last is None:
            return self._fault(decision, missed)
        return replace(last, requested_pct=decision.requested_pct,
                       detail=f'{last.detail}; {missed}')

    def _fault(self, decision: Decision, fault: str) -> Decision:
        if self.backend is not None and self.backend.polled:
            self._count_misses()
        if not self.io_fault:
            self.diagnostics.error(f'IO_FAULT: {fault}', log=True)
            self.diagnostics.set_value('io', f'fault: {fault}')
            if self.parameters.current.armed:
                self._set_parameter('armed', False)   # re-armed only when told
            self.gate.disarm()
        self.io_fault = fault
        modbus = self.machine.modbus if self.machine is not None else None
        pct = min(modbus.fail_safe_pct if modbus is not None else 100.0,
                  self.parameters.current.hand_back_pct)
        code, bits = self.table.encode(pct)
        return Decision(pct, decision.requested_pct, code, bits, False, Reason.IO_FAULT,
                        f"{fault}; disarmed, reconnecting; the module's watchdog should hold "
                        f'{pct:g} %', decision.inputs, decision.engaged)

    def _set_outputs(self, decision: Decision) -> None:
        """The gate's alarm and stop request to the module's outputs, where the file wires
        them, when the gate raises or clears them (:meth:`set_output` may set them between)."""
        if self.machine is None or self.backend is None or not self.backend.polled:
            return
        wired = self.machine.outputs.points()
        for name, value in (('alarm', decision.alarm), ('stop_request', decision.stop_request)):
            if name in wired and self._gate_outputs.get(name, False) != value:
                self.backend.set_output(name, value)
                self._gate_outputs[name] = value

    def _report_inputs(self) -> None:
        inputs = self.inputs
        for name in ('program_enable', 'threading', 'operator_dial_pct'):
            value = getattr(inputs, name)
            if value is not None:
                self.diagnostics.set_value(f'input {name}', value)


main = node_main(PmcBridgeNode)


if __name__ == '__main__':
    sys.exit(main())
