"""pmc_bridge as a lifecycle node on a Modbus/TCP module (a pymodbus server on 127.0.0.1): the
transitions driven through ~/change_state and ~/get_state as `ros2 lifecycle set` would, the
hand-back on deactivate, and the I/O faults in FeedOverride and /diagnostics: a server killed
and restarted (safe, then recovered, re-armed only when told), late, refusing writes."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from lifecycle_msgs.msg import Transition
from lifecycle_msgs.srv import ChangeState, GetState
from rclpy.node import Node
from rclpy.parameter import Parameter
from std_srvs.srv import Trigger
from turning_force_msgs.msg import FeedCommand, FeedOverride

from modbus_helpers import ServerProcess, coil_pattern, local_machine, write_machine
from turning_force.core.pmc.overrides import get_table
from turning_force.io.modbus_pmc import CoilReader
from turning_force.io.pmc_server import SimulatedPmcServer
from turning_force.nodes.pmc_bridge import BridgeStartError, PmcBridgeNode

FIG8 = Path(__file__).resolve().parents[2] / 'config' / 'experiments' / 'park1998_fig8.yaml'
TABLE = get_table('fanuc_0t_4bit')
TIMEOUT_S = 1.0   # generous on a loaded machine; the late-server test sets its own


def pattern(pct: float) -> list[bool]:
    """The discrete inputs 2-5 of the operator's dial at ``pct`` (direct logic)."""
    return list(TABLE.encode(pct)[1])


class Operator:
    """A test node: the controller's commands, the bridge's answers, the lifecycle services and
    the arm service, as `ros2 lifecycle set` and `ros2 service call` would use them."""

    def __init__(self, context, executor, spin_until) -> None:
        self.node = Node('operator', context=context)
        executor.add_node(self.node)
        self.spin_until = spin_until
        self.overrides: list[FeedOverride] = []
        self.statuses: list[DiagnosticStatus] = []
        self.node.create_subscription(FeedOverride, 'pmc/feed_override', self.overrides.append,
                                      10)
        self.node.create_subscription(
            DiagnosticArray, '/diagnostics',
            lambda m: self.statuses.extend(s for s in m.status if s.name == '/pmc_bridge'), 10)
        self.commands = self.node.create_publisher(FeedCommand, 'control/feed_command', 10)
        self._sec = 0

    def command(self, pct: float) -> None:
        self._sec += 1
        msg = FeedCommand(override_pct=pct, controller='smc')
        msg.header.stamp.sec = self._sec
        self.commands.publish(msg)

    def until(self, condition, pct: float = 60.0, timeout_s: float = 15.0) -> bool:
        """Command ``pct`` each spin until ``condition()`` holds."""
        def check() -> bool:
            if condition():
                return True
            self.command(pct)
            return False
        return self.spin_until(check, timeout_s)

    def last(self) -> FeedOverride:
        return self.overrides[-1]

    def call(self, kind, service: str, request):
        client = self.node.create_client(kind, service)
        assert client.wait_for_service(timeout_sec=30.0)
        future = client.call_async(request)
        assert self.spin_until(future.done)
        return future.result()

    def transition(self, transition_id: int) -> bool:
        request = ChangeState.Request(transition=Transition(id=transition_id))
        return self.call(ChangeState, '/pmc_bridge/change_state', request).success

    def state(self) -> str:
        return self.call(GetState, '/pmc_bridge/get_state', GetState.Request()).current_state.label

    def arm(self) -> bool:
        return self.call(Trigger, '/pmc_bridge/arm', Trigger.Request()).success


@pytest.fixture
def operator(context, executor, spin_until):
    return Operator(context, executor, spin_until)


@pytest.fixture
def server():
    with SimulatedPmcServer(local_machine()) as s:   # the 0-T's output image mirrored at 512
        s.set_discrete_inputs(2, pattern(100.0))      # the operator's dial at 100 %
        yield s


def bridge_on(context, executor, machine_file, *, autostart: bool = False, **parameters):
    # No force comes in: the entry feed off, so the coils show the request as the gate passed it.
    values = {'machine_file': str(machine_file), 'backend': 'modbus_tcp',
              'air_cut_override_pct': 0.0, **parameters}
    bridge = PmcBridgeNode(autostart=autostart, context=context, parameter_overrides=[
        Parameter(name, value=value) for name, value in values.items()])
    executor.add_node(bridge)
    return bridge


def test_the_lifecycle_driven_through_its_services(context, executor, operator, server,
                                                   tmp_path):
    path = write_machine(tmp_path / 'm.yaml', port=server.port, timeout_s=TIMEOUT_S)
    bridge = bridge_on(context, executor, path)
    assert operator.state() == 'unconfigured'
    assert server.writes == []   # nothing is written before configure
    # configure: the machine file is loaded, the module connected, the programmed feed written.
    assert operator.transition(Transition.TRANSITION_CONFIGURE)
    assert operator.state() == 'inactive'
    assert server.coils(0, 4) == coil_pattern(100.0)
    # Inactive, commands are answered with the programmed feed: the bridge does not act.
    assert operator.until(lambda: bool(operator.overrides))
    assert operator.last().applied_pct == 100.0 and 'inactive' in operator.last().detail
    # activate: may arm; armed, the controller's request goes to the coils.
    assert operator.transition(Transition.TRANSITION_ACTIVATE)
    assert operator.state() == 'active'
    assert operator.arm()
    assert operator.until(lambda: operator.last().reason == FeedOverride.REASON_NORMAL)
    assert operator.last().applied_pct == 60.0
    assert list(operator.last().pmc_bits) == list(TABLE.encode(60.0)[1])
    assert server.coils(0, 4) == server.coils(512, 4) == coil_pattern(60.0)
    # The machine's inputs, read each period: program enable on, the operator's dial at 70 %.
    server.set_discrete_inputs(0, [True, False, *pattern(70.0)])
    assert operator.until(lambda: bridge.inputs.operator_dial_pct == 70.0)
    assert bridge.inputs.program_enable and not bridge.inputs.threading
    bridge.set_output('alarm', True)
    assert operator.until(lambda: server.coils(4, 1) == [True])
    # deactivate: the feed is handed back to the operator's dial, and held there.
    assert operator.transition(Transition.TRANSITION_DEACTIVATE)
    assert operator.state() == 'inactive'
    assert operator.last().reason == FeedOverride.REASON_OPERATOR
    assert operator.last().applied_pct == 70.0 and server.coils(0, 4) == coil_pattern(70.0)
    count = len(operator.overrides)
    assert operator.until(lambda: len(operator.overrides) >= count + 5, pct=130.0)
    assert {m.applied_pct for m in operator.overrides[count:]} == {70.0}
    assert server.coils(0, 4) == coil_pattern(70.0)
    # cleanup releases the module: nothing more is written; shutdown finalizes.
    assert operator.transition(Transition.TRANSITION_CLEANUP)
    assert operator.state() == 'unconfigured' and bridge.backend is None
    writes = len(server.writes)
    operator.until(lambda: False, timeout_s=0.3)
    assert len(server.writes) == writes
    assert operator.transition(Transition.TRANSITION_UNCONFIGURED_SHUTDOWN)
    assert operator.state() == 'finalized'


def test_configure_fails_with_the_reason(context, executor, operator, tmp_path):
    # No module at that port.
    bridge = bridge_on(context, executor, write_machine(tmp_path / 'gone.yaml', port=1,
                                                        timeout_s=TIMEOUT_S))
    assert not operator.transition(Transition.TRANSITION_CONFIGURE)
    assert operator.state() == 'unconfigured'
    assert bridge.configure_error.endswith('cannot connect to 127.0.0.1:1')


def test_a_machine_file_that_disagrees_is_refused(context, tmp_path):
    path = write_machine(tmp_path / 'eight.yaml', 'fanuc_0i_8bit.yaml')
    with pytest.raises(BridgeStartError, match=r"eight.yaml: override_table = 'fanuc_8bit': "
                                               r"differs from the experiment's override_table = "
                                               r"'fanuc_0t_4bit'"):
        PmcBridgeNode(autostart=True, context=context, parameter_overrides=[
            Parameter('machine_file', value=str(path))])
    with pytest.raises(BridgeStartError, match=r"backend = 'modbus_tcp': no machine_file"):
        PmcBridgeNode(autostart=True, context=context, parameter_overrides=[
            Parameter('backend', value='modbus_tcp')])


def test_a_lathes_machine_file_on_a_desk_lends_its_table_only(context, executor, operator):
    # backend simulated (the default): the machine file's module is not touched.
    bridge = PmcBridgeNode(autostart=True, context=context, parameter_overrides=[
        Parameter('machine_file', value='config/machines/fanuc_0t.yaml')])
    executor.add_node(bridge)
    assert bridge.machine.name == 'fanuc_0t' and bridge.backend.code == 10   # 100 %


def test_a_server_killed_and_restarted(context, executor, operator, tmp_path):
    server = ServerProcess()
    try:
        path = write_machine(tmp_path / 'm.yaml', port=server.port, readback_address=None,
                             timeout_s=TIMEOUT_S)
        bridge = bridge_on(context, executor, path, autostart=True, armed=True)
        assert operator.until(lambda: operator.overrides and
                              operator.last().reason == FeedOverride.REASON_NORMAL)
        server.kill()
        # The bridge goes to its safe state and says why, in FeedOverride and /diagnostics.
        assert operator.until(lambda: operator.last().reason == FeedOverride.REASON_IO_FAULT)
        fault = operator.last()
        assert not fault.armed and 'connection lost' in fault.detail
        assert 'disarmed, reconnecting' in fault.detail
        assert not bridge.get_parameter('armed').value
        assert operator.until(lambda: any(s.level == DiagnosticStatus.ERROR and
                                          'IO_FAULT' in s.message for s in operator.statuses))
        # The module comes back on its port: the bridge reconnects (with back-off) and writes
        # the programmed feed, disarmed.
        server = ServerProcess(port=server.port)
        assert operator.until(lambda: operator.last().reason == FeedOverride.REASON_DISARMED)
        assert operator.last().applied_pct == 100.0
        reader = CoilReader(local_machine(port=server.port, timeout_s=TIMEOUT_S))
        assert reader.read_pct() == 100.0
        # It stays disarmed, whatever the controller asks, until it is told.
        count = len(operator.overrides)
        assert operator.until(lambda: len(operator.overrides) >= count + 10)
        assert {m.reason for m in operator.overrides[count:]} == {FeedOverride.REASON_DISARMED}
        assert operator.arm()
        assert operator.until(lambda: operator.last().reason == FeedOverride.REASON_NORMAL)
        assert reader.read_pct() == 60.0
        reader.close()
    finally:
        server.stop()


def test_a_server_that_answers_late(context, executor, operator, server, tmp_path):
    path = write_machine(tmp_path / 'm.yaml', port=server.port, timeout_s=0.05)
    bridge_on(context, executor, path, autostart=True, armed=True)
    assert operator.until(lambda: operator.overrides and
                          operator.last().reason == FeedOverride.REASON_NORMAL)
    server.latency_s = 0.5   # ten times the timeout
    assert operator.until(lambda: operator.last().reason == FeedOverride.REASON_IO_FAULT)
    assert 'no answer within 50.0 ms' in operator.last().detail
    server.latency_s = 0.0
    assert operator.until(lambda: operator.last().reason == FeedOverride.REASON_DISARMED)


def test_a_server_that_refuses_writes(context, executor, operator, server, tmp_path):
    path = write_machine(tmp_path / 'm.yaml', port=server.port, timeout_s=TIMEOUT_S)
    bridge_on(context, executor, path, autostart=True, armed=True)
    assert operator.until(lambda: operator.overrides and
                          operator.last().reason == FeedOverride.REASON_NORMAL)
    server.refuse_writes = True
    assert operator.until(lambda: operator.last().reason == FeedOverride.REASON_IO_FAULT)
    assert 'refused, exception code 4 (device failure)' in operator.last().detail
    # Every write the server was sent was a level's whole pattern, refused ones included.
    levels = {tuple(coil_pattern(level)) for level in TABLE.levels_pct}
    assert {w.values for w in server.writes if w.address == 0} <= levels


def test_the_machine_entry_point_never_arms_by_itself(context, executor, spin_until, server,
                                                     tmp_path):
    # turning_force_machine on the lathe PC: it configures and activates the bridge at start,
    # never arms it by itself (not even with pmc_bridge.armed = true in a file: issue 18 item
    # 7), says so on its first line and on /diagnostics, and arms on ~/arm; at SIGINT it
    # deactivates the bridge (the feed handed back) and releases the module.
    namespace = f'/machine_{os.getpid()}'
    path = write_machine(tmp_path / 'm.yaml', port=server.port, timeout_s=TIMEOUT_S)
    session = tmp_path / 'session.yaml'
    session.write_text(
        f'/**:\n  ros__parameters: {{machine_file: {path}, backend: modbus_tcp}}\n'
        '/**/pmc_bridge:\n  ros__parameters: {armed: true}\n'
        f'/**/session_recorder:\n  ros__parameters: {{output_dir: {tmp_path / "bag"}}}\n')
    process = subprocess.Popen(
        [str(Path(sys.prefix) / 'bin' / 'turning_force_machine'), '--ros-args',
         '--params-file', str(FIG8), '--params-file', str(session), '-r', f'__ns:={namespace}'],
        stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    try:
        assert process.stdout is not None
        first = process.stdout.readline()
        assert first.startswith('turning_force_machine: the PMC bridge starts disarmed and never '
                                'arms by itself: arm it with its ~/arm service'), first
        node = Node('controller', context=context)
        executor.add_node(node)
        commands = node.create_publisher(FeedCommand, f'{namespace}/control/feed_command', 10)
        arming: list[str] = []
        node.create_subscription(DiagnosticArray, '/diagnostics', lambda m: arming.extend(
            v.value for s in m.status if s.name == f'{namespace}/pmc_bridge'
            for v in s.values if v.key == 'arming'), 10)

        def commanding(condition):
            def check() -> bool:
                commands.publish(FeedCommand(override_pct=60.0, controller='smc'))
                return condition()
            return check

        assert spin_until(commanding(lambda: bool(arming)), 60.0)
        assert f'{namespace}/pmc_bridge: active, disarmed' in arming[-1]
        assert f'ros2 service call {namespace}/pmc_bridge/arm std_srvs/srv/Trigger' in arming[-1]
        assert server.coils(0, 4) == coil_pattern(100.0)   # commanded 60 %, not armed
        client = node.create_client(Trigger, f'{namespace}/pmc_bridge/arm')
        assert client.wait_for_service(timeout_sec=30.0)
        future = client.call_async(Trigger.Request())
        assert spin_until(future.done, 30.0) and future.result().success
        assert spin_until(commanding(lambda: server.coils(0, 4) == coil_pattern(60.0)), 30.0)
    finally:
        process.send_signal(signal.SIGINT)
        output, _ = process.communicate(timeout=30)
    assert process.returncode == 0, output
    assert server.coils(0, 4) == coil_pattern(100.0)   # handed back on the way out
