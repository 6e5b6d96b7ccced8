"""Our messages are real ROS 2 types: two nodes on one executor exchange every one of them."""

from __future__ import annotations

import pytest
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from turning_force_msgs.msg import (
    CuttingState,
    FeedCommand,
    FeedOverride,
    ForceEstimate,
    ServoCurrents,
)


def filled(kind):
    """A message with every field set to a value that is not its default."""
    msg = kind()
    msg.header.stamp.sec, msg.header.stamp.nanosec = 12, 345_678_901
    msg.header.frame_id = 'lathe1/z_axis'
    if kind is ServoCurrents:
        msg.sample_period_s = 1e-3
        msg.phase_u_a = [0.5, -1.25, 3.0]
        msg.phase_v_a = [-0.25, 0.75, -1.5]
        msg.rotor_angle_rad = [0.0, 1.0, 6.2]
        msg.feed_rate_mm_min = [120.0, 119.5, 121.25]
    elif kind is ForceEstimate:
        msg.force_n, msg.force_rate_n_s = 512.5, -1250.0
        msg.current_q_a, msg.friction_current_a = 3.1, 0.45
        msg.status, msg.detail = ForceEstimate.STATUS_SATURATED, 'phase current 31 A'
    elif kind is FeedCommand:
        msg.override_pct, msg.tracking_error_n = 113.6, -12.5
        msg.sliding_variable, msg.reference_force_n = -250.0, 500.0
        msg.controller = 'smc'
    elif kind is FeedOverride:
        msg.applied_pct, msg.requested_pct = 110.0, 113.6
        msg.pmc_code, msg.pmc_bits = 11, [False, False, True, False]
        msg.table, msg.armed = 'fanuc_0t_4bit', True
        msg.reason, msg.detail = FeedOverride.REASON_WATCHDOG, 'feed command 0.3 s old'
    elif kind is CuttingState:
        msg.force_n, msg.depth_of_cut_mm, msg.spindle_speed_rpm = 498.0, 2.0, 600.0
        msg.feed_mm_rev, msg.feed_rate_mm_min = 0.114, 68.4
        msg.specific_cutting_force_n_mm2, msg.override_pct = 2200.0, 60.0
    return msg


def as_dict(msg) -> dict:
    out = {}
    for name in msg.get_fields_and_field_types():
        value = getattr(msg, name)
        if hasattr(value, 'get_fields_and_field_types'):
            value = as_dict(value)
        elif not isinstance(value, str | int | float | bool):
            value = list(value)
        out[name] = value
    return out


@pytest.mark.parametrize('kind', [ServoCurrents, ForceEstimate, FeedCommand, FeedOverride,
                                  CuttingState])
def test_every_field_arrives_intact(context, executor, spin_until, kind):
    sender = Node('sender', context=context)
    receiver = Node('receiver', context=context)
    executor.add_node(sender)
    executor.add_node(receiver)
    qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
    received = []
    receiver.create_subscription(kind, 'roundtrip', received.append, qos)
    publisher = sender.create_publisher(kind, 'roundtrip', qos)
    sent = filled(kind)
    assert as_dict(sent) != as_dict(kind()), 'the test message must differ from the default'

    def delivered() -> bool:
        if not received:
            publisher.publish(sent)   # until discovery has matched the two
        return bool(received)

    assert spin_until(delivered)
    assert as_dict(received[0]) == as_dict(sent)

