"""Each node in-process: its topics, its parameters (a bad value rejected with its reason), and
the safety behaviours. Own Context per test, spun with deadlines, no sleeps."""

from __future__ import annotations

import math

import pytest
from rclpy.node import Node
from rclpy.parameter import Parameter
from std_msgs.msg import Float64
from std_srvs.srv import Trigger
from turning_force_msgs.msg import (
    CuttingState,
    FeedCommand,
    FeedOverride,
    ForceEstimate,
    ServoCurrents,
)

from turning_force.core.control import drift
from turning_force.core.control.law import CS_DRIFT
from turning_force.core.errors import ConfigError
from turning_force.core.estimation.settings import EstimatorSettings
from turning_force.nodes.force_controller import REFERENCE_QOS, ForceControllerNode
from turning_force.nodes.force_estimator import FRICTION_CORRECTION_TOPIC, ForceEstimatorNode
from turning_force.nodes.lathe_sim import LatheSimNode
from turning_force.nodes.pmc_bridge import PmcBridgeNode
from turning_force.nodes.session_recorder import SessionRecorderNode


class Probe:
    """A test node: publishers to and recorders of a node's topics."""

    def __init__(self, context, executor) -> None:
        self.node = Node('probe', context=context)
        executor.add_node(self.node)
        self.received: dict[str, list] = {}

    def listen(self, cls, topic, qos=10) -> list:
        box = self.received.setdefault(topic, [])
        self.node.create_subscription(cls, topic, box.append, qos)
        return box

    def publisher(self, cls, topic, qos=10):
        return self.node.create_publisher(cls, topic, qos)


def until_heard(spin_until, publisher, message, box, count=1, timeout_s=10.0):
    """Publish ``message`` until ``box`` holds ``count`` items (discovery may drop the first)."""
    def heard() -> bool:
        if len(box) < count:
            publisher.publish(message)
        return len(box) >= count
    return spin_until(heard, timeout_s)


def block(t0_s: float, current_v_a: float = 1.0, n: int = 10, nan: bool = False):
    msg = ServoCurrents(sample_period_s=1e-3, phase_u_a=[0.0] * n,
                        phase_v_a=[current_v_a] * n, rotor_angle_rad=[0.0] * n,
                        feed_rate_mm_min=[120.0] * n)
    if nan:
        msg.phase_u_a[3] = math.nan
    ns = round(t0_s * 1e9)
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(ns, 1_000_000_000)
    return msg


def set_parameter(node, name, value):
    return node.set_parameters([Parameter(name, value=value)])[0]


# --- lathe_sim -------------------------------------------------------------------------------

def test_lathe_sim_publishes_a_block_and_reads_the_pmc_bits(context, executor, spin_until):
    sim = LatheSimNode(lockstep=True, context=context)
    executor.add_node(sim)
    probe = Probe(context, executor)
    currents = probe.listen(ServoCurrents, 'servo/currents')
    truth = probe.listen(CuttingState, 'sim/cutting_state')
    overrides = probe.publisher(FeedOverride, 'pmc/feed_override')
    assert spin_until(lambda: bool(sim.step()) and bool(currents) and bool(truth))
    assert len(currents[0].phase_u_a) == 10 and currents[0].sample_period_s == 1e-3
    assert truth[0].override_pct == 100.0
    # 50 % on the FANUC 0-T: code 5, written active low: 1010 (bit 0 first).
    command = FeedOverride(applied_pct=999.0, pmc_bits=[False, True, False, True],
                           table='fanuc_0t_4bit')
    assert spin_until(lambda: overrides.publish(command) or sim.applied_pct == 50.0)
    sim.step()
    assert spin_until(lambda: truth[-1].override_pct == 50.0)


def test_lathe_sim_rejects_changes_to_a_running_plant(context, executor):
    sim = LatheSimNode(lockstep=True, context=context)
    result = set_parameter(sim, 'servo_time_constant_s', 0.2)
    assert not result.successful and 'read-only' in result.reason


# --- force_estimator -------------------------------------------------------------------------

class BlockFeeder:
    """Publishes blocks of currents 10 ms apart; remembers the stamps sent [ns]."""

    def __init__(self, probe: Probe) -> None:
        self.publisher = probe.publisher(ServoCurrents, 'servo/currents')
        self.sent_ns: list[int] = []

    def __call__(self) -> None:
        t_s = 0.01 * (len(self.sent_ns) + 1)
        self.sent_ns.append(round(t_s * 1e9))
        self.publisher.publish(block(t_s))


@pytest.fixture
def estimator_rig(context, executor):
    executor.add_node(ForceEstimatorNode(context=context))
    probe = Probe(context, executor)
    return probe.listen(ForceEstimate, 'force/estimate'), BlockFeeder(probe)


def test_estimator_publishes_one_estimate_per_block(estimator_rig, spin_until):
    estimates, feed = estimator_rig
    assert spin_until(lambda: feed() or len(estimates) >= 3)
    assert all(e.status == ForceEstimate.STATUS_OK for e in estimates)
    # Each estimate carries the time of its block's last sample: the block's stamp + 9 ms.
    for e in estimates:
        assert e.header.stamp.nanosec - 9_000_000 in feed.sent_ns


def test_estimator_marks_bad_blocks_invalid_and_stays_finite(estimator_rig, spin_until):
    estimates, feed = estimator_rig
    blocks = feed.publisher
    assert spin_until(lambda: feed() or len(estimates) >= 1)
    assert spin_until(lambda: estimates[-1].header.stamp.nanosec == feed.sent_ns[-1] + 9_000_000)
    good = estimates[-1].force_n
    blocks.publish(block(2.0, nan=True))
    assert spin_until(lambda: estimates[-1].status != ForceEstimate.STATUS_OK)
    bad = estimates[-1]
    assert bad.status == ForceEstimate.STATUS_INVALID_INPUT
    assert 'non-finite' in bad.detail and bad.force_n == good and math.isfinite(bad.force_rate_n_s)
    count = len(estimates)
    blocks.publish(block(0.001))   # a stamp before the last good one
    assert spin_until(lambda: len(estimates) > count)
    assert estimates[-1].status == ForceEstimate.STATUS_INVALID_INPUT
    assert 'not after' in estimates[-1].detail


def test_estimator_takes_a_friction_correction_off_from_the_next_block(context, executor,
                                                                       spin_until):
    # The controller's drift monitor read 20 N of friction drift in the cut
    # (force/friction_correction): the estimator's friction scale takes it at the blocks'
    # feed and the next estimate is 20 N lower (the blocks are constant: the filter is at
    # rest, its state moves with the scale); it says so on /diagnostics.
    node = ForceEstimatorNode(context=context)
    executor.add_node(node)
    probe = Probe(context, executor)
    estimates = probe.listen(ForceEstimate, 'force/estimate')
    feed = BlockFeeder(probe)
    def answered() -> bool:   # the estimate of the last block sent is in
        return bool(estimates) and (estimates[-1].header.stamp.nanosec
                                    == feed.sent_ns[-1] + 9_000_000)

    assert spin_until(lambda: feed() or len(estimates) >= 3)
    assert spin_until(answered)
    before = estimates[-1].force_n
    corrections = probe.publisher(Float64, FRICTION_CORRECTION_TOPIC)
    assert spin_until(lambda: corrections.get_subscription_count() > 0)
    corrections.publish(Float64(data=20.0))   # once: each one heard is taken off
    assert spin_until(lambda: node.diagnostics.received_count(FRICTION_CORRECTION_TOPIC) > 0)
    feed()
    assert spin_until(answered)
    assert estimates[-1].force_n == pytest.approx(before - 20.0, abs=1e-6)
    assert node._estimator.friction_scale > 1.0


# --- force_controller ------------------------------------------------------------------------

def estimate(force_n: float, sec: int = 1, status: int = ForceEstimate.STATUS_OK):
    msg = ForceEstimate(force_n=force_n, force_rate_n_s=0.0, status=status)
    msg.header.stamp.sec = sec
    return msg


@pytest.fixture
def controller_rig(context, executor):
    """A controller node, what it commands, and a publisher of estimates to it."""
    executor.add_node(ForceControllerNode(context=context))
    probe = Probe(context, executor)
    return (probe.listen(FeedCommand, 'control/feed_command'),
            probe.publisher(ForceEstimate, 'force/estimate'))


def test_controller_answers_each_estimate_with_its_stamp(controller_rig, spin_until):
    commands, estimates = controller_rig
    assert until_heard(spin_until, estimates, estimate(450.0, sec=7), commands)
    command = commands[-1]
    assert command.header.stamp.sec == 7 and command.controller == 'smc'
    assert command.tracking_error_n == -50.0 and command.reference_force_n == 500.0
    assert 0.0 <= command.override_pct <= 150.0


def test_controller_passes_its_monitors_friction_reading_to_the_estimator(
        context, executor, spin_until):
    # The drift monitor asks the estimator to take 12 N of friction off (drift_correction's
    # request, set here where a friction drift read in the cut would set it): the next
    # command goes with it on force/friction_correction, once.
    node = ForceControllerNode(context=context)
    executor.add_node(node)
    probe = Probe(context, executor)
    commands = probe.listen(FeedCommand, 'control/feed_command')
    corrections = probe.listen(Float64, FRICTION_CORRECTION_TOPIC)
    estimates = probe.publisher(ForceEstimate, 'force/estimate')
    assert until_heard(spin_until, estimates, estimate(450.0), commands)
    node._controller.arrays[1][CS_DRIFT + drift.DS_CORRECT] = 12.0
    assert until_heard(spin_until, estimates, estimate(450.0, sec=2), corrections)
    count = len(commands)
    assert until_heard(spin_until, estimates, estimate(450.0, sec=3), commands, count + 1)
    assert [c.data for c in corrections] == [12.0]


def test_controller_ignores_estimates_it_cannot_trust(controller_rig, spin_until):
    commands, estimates = controller_rig
    assert until_heard(spin_until, estimates, estimate(450.0), commands)
    # until_heard may leave repeats in flight; one more, stamped 8, is answered after them all.
    estimates.publish(estimate(450.0, sec=8))
    assert spin_until(lambda: commands[-1].header.stamp.sec == 8)
    before = len(commands)
    for _ in range(20):
        estimates.publish(estimate(450.0, status=ForceEstimate.STATUS_INVALID_INPUT))
    # Then one good estimate: it is answered, the invalid ones were not.
    assert until_heard(spin_until, estimates, estimate(450.0, sec=9), commands, before + 1)
    assert len(commands) == before + 1 and commands[-1].header.stamp.sec == 9


def test_late_joining_controller_gets_the_reference(context, executor, spin_until):
    probe = Probe(context, executor)
    reference = probe.publisher(Float64, 'force/reference', REFERENCE_QOS)
    reference.publish(Float64(data=420.0))          # before the controller exists
    controller = ForceControllerNode(context=context)
    executor.add_node(controller)
    assert spin_until(
        lambda: controller.get_parameter('reference_force_n').value == 420.0)
    commands = probe.listen(FeedCommand, 'control/feed_command')
    estimates = probe.publisher(ForceEstimate, 'force/estimate')
    assert until_heard(spin_until, estimates, estimate(450.0), commands)
    assert commands[-1].reference_force_n == 420.0 and commands[-1].tracking_error_n == 30.0


def test_controller_gains_change_while_cutting_and_bad_ones_are_refused(context, executor):
    controller = ForceControllerNode(context=context)
    executor.add_node(controller)
    ok = set_parameter(controller, 'smc_epsilon_n', 150.0)
    assert ok.successful and controller._controller.settings.smc_epsilon_n == 150.0
    refused = set_parameter(controller, 'smc_lambda_per_s', 50.0)
    assert not refused.successful
    assert 'force_controller.smc_lambda_per_s = 50.0' in refused.reason
    assert 'Eq. 24' in refused.reason
    assert controller.get_parameter('smc_lambda_per_s').value == 20.0
    nan = set_parameter(controller, 'reference_force_n', math.nan)
    assert not nan.successful and 'reference_force_n' in nan.reason and 'nan' in nan.reason
    fixed = set_parameter(controller, 'controller', 'pi')
    assert not fixed.successful and 'read-only' in fixed.reason


# --- pmc_bridge ------------------------------------------------------------------------------

def command(pct: float, sec: int = 1):
    msg = FeedCommand(override_pct=pct, controller='smc')
    msg.header.stamp.sec = sec
    return msg


@pytest.fixture
def bridge_probe(context, executor):
    # No force comes in (the tool out of the cut): the entry feed off, to see the safety gate
    # act on the request itself (test_shopfloor.py tests the entry feed).
    bridge = PmcBridgeNode(context=context, parameter_overrides=[
        Parameter('safe_override_pct', value=20.0), Parameter('overload_force_n', value=900.0),
        Parameter('watchdog_period_s', value=0.05), Parameter('air_cut_override_pct', value=0.0)])
    executor.add_node(bridge)
    probe = Probe(context, executor)
    overrides = probe.listen(FeedOverride, 'pmc/feed_override')
    return bridge, probe, overrides


def call(node, spin_until, service):
    client = node.create_client(Trigger, service)
    assert client.wait_for_service(timeout_sec=30.0)
    future = client.call_async(Trigger.Request())
    assert spin_until(future.done)
    return future.result()


def test_bridge_starts_disarmed_and_arms_by_service(context, executor, spin_until,
                                                    bridge_probe):
    bridge, probe, overrides = bridge_probe
    commands = probe.publisher(FeedCommand, 'control/feed_command')
    assert until_heard(spin_until, commands, command(113.0), overrides)
    assert spin_until(lambda: overrides[-1].requested_pct == 113.0)
    first = overrides[-1]
    assert (first.applied_pct, first.reason, first.armed) == (100.0,
                                                              FeedOverride.REASON_DISARMED, False)
    assert call(probe.node, spin_until, '/pmc_bridge/arm').success
    commands.publish(command(113.0, sec=2))
    assert spin_until(lambda: overrides[-1].reason == FeedOverride.REASON_NORMAL)
    normal = overrides[-1]
    assert normal.applied_pct == 110.0 and normal.armed
    assert normal.pmc_code == 11 and list(normal.pmc_bits) == [False, False, True, False]
    assert bridge.backend.code == 11
    assert call(probe.node, spin_until, '/pmc_bridge/disarm').success
    assert spin_until(lambda: overrides[-1].reason == FeedOverride.REASON_DISARMED)


def test_bridge_watchdog_sends_a_stale_command_to_the_safe_override(
        context, executor, spin_until, bridge_probe):
    bridge, probe, overrides = bridge_probe
    assert set_parameter(bridge, 'armed', True).successful
    commands = probe.publisher(FeedCommand, 'control/feed_command')
    assert until_heard(spin_until, commands, command(60.0), overrides)
    assert spin_until(lambda: overrides[-1].reason == FeedOverride.REASON_NORMAL)
    # No more commands: within a few watchdog periods the safe override goes out, with why.
    assert spin_until(lambda: overrides[-1].reason == FeedOverride.REASON_WATCHDOG, 5.0)
    assert overrides[-1].applied_pct == 20.0 and 'old' in overrides[-1].detail


def test_bridge_refuses_a_non_finite_command(context, executor, spin_until, bridge_probe):
    bridge, probe, overrides = bridge_probe
    assert set_parameter(bridge, 'armed', True).successful
    commands = probe.publisher(FeedCommand, 'control/feed_command')
    assert until_heard(spin_until, commands, command(math.nan), overrides)
    assert spin_until(lambda: overrides[-1].reason == FeedOverride.REASON_INVALID_COMMAND)
    assert overrides[-1].applied_pct == 20.0 and bridge.backend.code == 2


def test_bridge_holds_the_feed_on_overload_until_re_armed(context, executor, spin_until,
                                                          bridge_probe):
    bridge, probe, overrides = bridge_probe
    assert set_parameter(bridge, 'armed', True).successful
    commands = probe.publisher(FeedCommand, 'control/feed_command')
    estimates = probe.publisher(ForceEstimate, 'force/estimate')
    assert until_heard(spin_until, commands, command(100.0), overrides)
    # Once the bridge has subscribed, every estimate published reaches it (reliable QoS): count
    # them, so that the test knows when the last one has been taken.
    assert spin_until(lambda: estimates.get_subscription_count() > 0)
    taken = bridge.diagnostics.received_count
    estimates.publish(estimate(950.0))
    assert spin_until(lambda: overrides[-1].reason == FeedOverride.REASON_OVERLOAD_HOLD)
    assert overrides[-1].applied_pct == 0.0 and '950 N' in overrides[-1].detail
    commands.publish(command(120.0, sec=3))      # the controller cannot lift the hold
    assert spin_until(lambda: overrides[-1].header.stamp.sec == 3)
    assert overrides[-1].reason == FeedOverride.REASON_OVERLOAD_HOLD
    # The force is back down: once the bridge has taken that estimate, re-arm.
    estimates.publish(estimate(400.0))
    assert spin_until(lambda: taken('force/estimate') == 2)
    assert call(probe.node, spin_until, '/pmc_bridge/arm').success
    commands.publish(command(120.0, sec=4))
    assert spin_until(lambda: overrides[-1].reason == FeedOverride.REASON_NORMAL)
    assert overrides[-1].applied_pct == 120.0


def test_bridge_rejects_a_bad_safe_override(context, executor, bridge_probe):
    bridge, _, _ = bridge_probe
    result = set_parameter(bridge, 'safe_override_pct', 150.0)  # full feed on a dead controller
    assert not result.successful
    assert 'out of range' in result.reason   # the descriptor's range, [0, 100)
    result = set_parameter(bridge, 'safe_override_pct', 99.0)   # the 0-T applies 100 % for it
    assert not result.successful
    assert 'safe_override_pct = 99.0: the fanuc_0t_4bit PMC would apply 100 %' in result.reason
    assert bridge.gate.settings.safe_override_pct == 20.0


# --- parameters from a file ------------------------------------------------------------------

def test_a_parameter_no_node_declares_is_refused_at_start(context):
    # rclpy would ignore it; a mistyped limit must not leave the default limit in force.
    with pytest.raises(ConfigError, match='overload_force_nn: no node of turning_force'):
        PmcBridgeNode(context=context,
                      parameter_overrides=[Parameter('overload_force_nn', value=900.0)])


def test_a_shared_parameter_of_another_node_is_accepted(context):
    # '/**' gives every node the whole shared section: the estimator starts, with its own
    # settings untouched, and does not take on a parameter it does not declare.
    node = ForceEstimatorNode(context=context,
                              parameter_overrides=[Parameter('spindle_speed_rpm', value=900.0)])
    assert not node.has_parameter('spindle_speed_rpm')
    assert node.parameters.current == EstimatorSettings()
    node.destroy_node()


def test_a_value_of_the_wrong_type_is_refused_at_start(context):
    with pytest.raises(ConfigError, match=r"pmc_bridge\.safe_override_pct: .*'INTEGER'"):
        PmcBridgeNode(context=context,
                      parameter_overrides=[Parameter('safe_override_pct', value=40)])


def test_the_largest_seed_a_file_may_give_is_a_ros_parameter(context):
    # The loader's bound on integers (int64, core/settings.py) is what rclpy holds.
    sim = LatheSimNode(lockstep=True, context=context,
                       parameter_overrides=[Parameter('seed', value=2**63 - 1)])
    assert sim.get_parameter('seed').value == 2**63 - 1
    sim.destroy_node()


@pytest.mark.parametrize(('name', 'value', 'message'), [
    ('flush_periodd_s', 1.0, 'flush_periodd_s: no node of turning_force declares'),
    ('flush_period_s', 0.0, r'session_recorder.flush_period_s = 0.0: outside \(0, 3600\] s'),
    ('capture_parameters', 'yes', r"session_recorder.capture_parameters: .*'STRING'"),
])
def test_the_recorder_refuses_a_bad_or_mistyped_parameter(context, tmp_path, name, value,
                                                          message):
    with pytest.raises(ConfigError, match=message):
        SessionRecorderNode(context=context, parameter_overrides=[
            Parameter('output_dir', value=str(tmp_path / 's')), Parameter(name, value=value)])
    assert not (tmp_path / 's').exists()
