"""The shop-floor behaviours on the machine's wiring: pmc_bridge on a Modbus/TCP module (a pymodbus
server on 127.0.0.1, the FANUC 0-T file's points) reads the program enable, the threading input
and the operator's dial from its discrete inputs, acts on them, records them in FeedOverride,
and raises the alarm and stop/retract request on its coils; a teach-in file reaches the
controller's reference topic."""

from __future__ import annotations

from functools import partial

import pytest
from rclpy.node import Node
from rclpy.parameter import Parameter
from std_msgs.msg import Float64
from std_srvs.srv import Trigger
from turning_force_msgs.msg import CutRecord, FeedCommand, FeedOverride, ForceEstimate

from modbus_helpers import coil_pattern, local_machine, write_machine
from turning_force.core.pmc.overrides import get_table
from turning_force.core.pmc.shopfloor import TaughtTool, save_teach_file
from turning_force.io.pmc_server import SimulatedPmcServer
from turning_force.nodes.force_controller import REFERENCE_QOS
from turning_force.nodes.pmc_bridge import BridgeStartError, PmcBridgeNode

TABLE = get_table('fanuc_0t_4bit')
ENABLE, THREADING, DIAL, ALARM, STOP = 0, 1, 2, 4, 5   # config/machines/fanuc_0t.yaml


def dial(pct: float) -> list[bool]:
    """The discrete inputs 2-5 of the operator's dial at ``pct`` (the 0-T's own code)."""
    return list(TABLE.encode(pct)[1])


class Controller:
    """A test node in the controller's place: an estimate and a command per block."""

    def __init__(self, context, executor, spin_until) -> None:
        self.node = Node('controller', context=context)
        executor.add_node(self.node)
        self.spin_until = spin_until
        self.overrides: list[FeedOverride] = []
        self.cuts: list[CutRecord] = []
        self.references: list[float] = []
        self.node.create_subscription(FeedOverride, 'pmc/feed_override', self.overrides.append,
                                      10)
        self.node.create_subscription(CutRecord, 'pmc/cuts', self.cuts.append, 10)
        self.node.create_subscription(Float64, 'force/reference',
                                      lambda m: self.references.append(m.data), REFERENCE_QOS)
        self.estimates = self.node.create_publisher(ForceEstimate, 'force/estimate', 10)
        self.commands = self.node.create_publisher(FeedCommand, 'control/feed_command', 10)
        self.force_n = 500.0
        self._k = 0

    def block(self, pct: float = 60.0) -> None:
        self._k += 1
        estimate = ForceEstimate(force_n=self.force_n)
        estimate.header.stamp.sec = self._k
        self.estimates.publish(estimate)
        command = FeedCommand(override_pct=pct, reference_reachable=True, controller='smc')
        command.header = estimate.header
        self.commands.publish(command)

    def until(self, condition, pct: float = 60.0, timeout_s: float = 15.0) -> bool:
        def check() -> bool:
            if condition():
                return True
            self.block(pct)
            return False
        return self.spin_until(check, timeout_s)

    def answered(self, count: int, pct: float = 60.0) -> None:
        """``count`` blocks in lock step: each published alone and answered before the next.

        :meth:`until` publishes a block on every spin, faster than the bridge takes them, so its
        depth-10 queues drop the oldest; a detector that needs every block of a level (the
        breakage window) is fed with this instead."""
        for _ in range(count):
            self.block(pct)
            assert self.spin_until(partial(self._answered, self._k), 15.0), self._k

    def _answered(self, sec: int) -> bool:
        return any(o.header.stamp.sec == sec for o in self.overrides[-5:])

    def last(self) -> FeedOverride:
        return self.overrides[-1]

    def arm(self) -> bool:
        client = self.node.create_client(Trigger, '/pmc_bridge/arm')
        assert client.wait_for_service(timeout_sec=30.0)
        future = client.call_async(Trigger.Request())
        assert self.spin_until(future.done)
        return future.result().success


@pytest.fixture
def controller(context, executor, spin_until):
    return Controller(context, executor, spin_until)


@pytest.fixture
def server():
    with SimulatedPmcServer(local_machine()) as s:
        s.set_discrete_inputs(DIAL, dial(150.0))
        yield s


def bridge_on(context, executor, server, tmp_path, **parameters) -> PmcBridgeNode:
    path = write_machine(tmp_path / 'm.yaml', port=server.port, timeout_s=1.0)
    values = {'machine_file': str(path), 'backend': 'modbus_tcp', 'armed': True, **parameters}
    bridge = PmcBridgeNode(autostart=True, context=context, parameter_overrides=[
        Parameter(name, value=value) for name, value in values.items()])
    executor.add_node(bridge)
    return bridge


def test_the_program_threading_and_dial_inputs_on_the_module(context, executor, controller,
                                                             server, tmp_path):
    bridge_on(context, executor, server, tmp_path, program_enable_required=True)
    # The program has not enabled the option (M811): the programmed feed, said and recorded.
    assert controller.until(lambda: controller.overrides and
                            controller.last().reason == FeedOverride.REASON_OPERATOR)
    last = controller.last()
    assert last.applied_pct == 100.0 and 'has not enabled adaptive feed' in last.detail
    assert (last.program_enable, last.threading, last.operator_dial_pct) == (0, 0, 150.0)
    assert server.coils(0, 4) == coil_pattern(100.0)
    # M810: the request goes through.
    server.set_discrete_inputs(ENABLE, [True])
    assert controller.until(lambda: controller.last().reason == FeedOverride.REASON_NORMAL)
    assert controller.last().applied_pct == 60.0 and controller.last().program_enable == 1
    # The operator turns the dial to 40 %: it keeps precedence.
    server.set_discrete_inputs(DIAL, dial(40.0))
    assert controller.until(lambda: controller.last().applied_pct == 40.0)
    assert controller.last().reason == FeedOverride.REASON_OPERATOR
    assert controller.last().operator_dial_pct == 40.0 and server.coils(0, 4) == coil_pattern(40.0)
    server.set_discrete_inputs(DIAL, dial(150.0))
    # Threading: FANUC runs it at 100 %; the bridge stands down.
    server.set_discrete_inputs(THREADING, [True])
    assert controller.until(lambda: controller.last().threading == 1)
    assert controller.until(lambda: controller.last().applied_pct == 100.0)
    assert 'thread cutting or tapping' in controller.last().detail
    server.set_discrete_inputs(THREADING, [False])
    assert controller.until(lambda: controller.last().applied_pct == 60.0)


def test_an_overload_reaction_raises_the_alarm_and_the_stop_request(context, executor,
                                                                    controller, server,
                                                                    tmp_path):
    # 0.8 x 2000 N = 1600 N for 0.05 s (five blocks): the stop/retract request and the alarm
    # go to coils 5 and 4; the feed is not held (the ladder's retract must move). Re-arming
    # clears them.
    bridge_on(context, executor, server, tmp_path, overload_reaction='stop',
              reaction_delay_s=0.05)
    assert controller.until(lambda: controller.overrides and
                            controller.last().reason == FeedOverride.REASON_NORMAL)
    assert server.coils(ALARM, 2) == [False, False]
    controller.force_n = 1700.0
    assert controller.until(lambda: controller.last().stop_request)
    assert controller.last().alarm and controller.last().applied_pct == 60.0
    assert controller.until(lambda: server.coils(ALARM, 2) == [True, True])
    controller.force_n = 500.0
    assert controller.until(lambda: len(controller.overrides) > 0, timeout_s=1.0)
    assert controller.last().stop_request                  # latched
    assert controller.arm()
    assert controller.until(lambda: not controller.last().stop_request)
    assert controller.until(lambda: server.coils(ALARM, 2) == [False, False])


def test_a_tool_breakage_holds_the_feed_and_the_cut_is_logged(context, executor, controller,
                                                              server, tmp_path):
    bridge_on(context, executor, server, tmp_path, breakage_spike_fraction=1.0,
              breakage_window_s=0.05, cut_settle_s=0.0, tool='T0303')
    assert controller.until(lambda: controller.overrides and controller.last().engaged)
    controller.answered(10)                                 # a level of 500 N, every block
    controller.force_n = 1200.0                             # seen: the window is full of it
    controller.answered(1)
    assert controller.until(
        lambda: controller.last().reason == FeedOverride.REASON_TOOL_BREAKAGE)
    assert controller.last().applied_pct == 0.0 and controller.last().alarm
    assert 'above its recent level' in controller.last().detail
    assert controller.until(lambda: server.coils(ALARM, 1) == [True])
    controller.force_n = 0.0                                # the tool is out
    assert controller.until(lambda: bool(controller.cuts))
    [cut] = controller.cuts
    assert cut.breakage and cut.tool == 'T0303' and cut.complete and cut.max_force_n == 1200.0
    assert cut.min_override_pct == 0.0


def test_the_taught_reference_goes_to_the_controller(context, executor, controller, server,
                                                     tmp_path):
    teach = tmp_path / 'teach.yaml'
    save_teach_file(teach, 'T0101', TaughtTool(440.0, 0.9, 396.0))
    bridge_on(context, executor, server, tmp_path, tool='T0101', teach_file=str(teach))
    assert controller.spin_until(lambda: controller.references == [396.0])


def test_a_malformed_teach_file_fails_the_configuration(context, server, tmp_path):
    teach = tmp_path / 'teach.yaml'
    teach.write_text('tools: {T0101: {learned_force_n: 440, teach_fraction: 0.9}}\n')
    path = write_machine(tmp_path / 'm.yaml', port=server.port, timeout_s=1.0)
    with pytest.raises(BridgeStartError, match=r'teach\.yaml: tools\.T0101\.reference_force_n '
                                               r'= None: expected a finite number above 0'):
        PmcBridgeNode(autostart=True, context=context, parameter_overrides=[
            Parameter('machine_file', value=str(path)), Parameter('tool', value='T0101'),
            Parameter('teach_file', value=str(teach))])
