"""The loop's machine inputs on the graph: the live spindle speed (``machine/spindle_speed``)
reaches the controller's laws, and its absence is reported; a run whose feed stops following
the override (override cancel switched on mid-cut) stops regulating and says why, in the run's
output, on ``/diagnostics`` and in the session."""

from __future__ import annotations

import json

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from rclpy.node import Node
from std_msgs.msg import Float64
from turning_force_msgs.msg import FeedCommand, FeedOverride, ForceEstimate

from turning_force.cli import main
from turning_force.core.pmc.settings import Reason
from turning_force.nodes.force_controller import ForceControllerNode
from turning_force.session.reader import read_session


def test_the_controller_takes_the_spindle_speed_and_warns_without_it(context, executor,
                                                                      spin_until):
    controller = ForceControllerNode(context=context)
    executor.add_node(controller)
    probe = Node('probe', context=context)
    executor.add_node(probe)
    reports: list[DiagnosticStatus] = []
    probe.create_subscription(DiagnosticArray, '/diagnostics', lambda m: reports.extend(
        s for s in m.status if s.name == '/force_controller'), 10)
    commands: list[FeedCommand] = []
    probe.create_subscription(FeedCommand, 'control/feed_command', commands.append, 10)
    estimates = probe.create_publisher(ForceEstimate, 'force/estimate', 10)
    speed = probe.create_publisher(Float64, 'machine/spindle_speed', 10)

    # Unplugged: the parameter (600 rpm), and /diagnostics warns (reported once a second).
    assert spin_until(lambda: bool(reports), 10.0)
    assert reports[-1].level == DiagnosticStatus.WARN
    assert 'machine/spindle_speed unplugged' in reports[-1].message
    assert 'spindle_speed_rpm (600 rpm) used' in reports[-1].message

    # Plugged in: the speed and the estimates at 50 Hz on a timer of the probe's (published
    # only when the wait polls, a loaded machine's gaps had the input read as unplugged
    # again: over 0.5 s). The laws take the live speed with the next estimate.
    def plugged() -> None:
        speed.publish(Float64(data=1500.0))
        estimates.publish(ForceEstimate(force_n=450.0))

    probe.create_timer(0.02, plugged)
    assert spin_until(lambda: controller._controller.spindle_speed_rpm == 1500.0, 10.0)
    # The next reports say where the speed comes from, and warn of it no more (a report
    # composed before the plug-in may still be on its way: the first that says the topic).
    seen = len(reports)

    def live() -> DiagnosticStatus | None:
        return next((r for r in reports[seen:] if {v.key: v.value for v in r.values}.get(
            'spindle_speed_from') == 'machine/spindle_speed'), None)

    assert spin_until(lambda: live() is not None, 10.0)
    report = live()
    assert report is not None and 'spindle_speed' not in report.message


def test_override_cancel_mid_cut_stops_the_graph_regulating_and_says_why(capfd, tmp_path,
                                                                         fig8):
    # 3 mm from the start: the force holds near 38 % (fig8's file says why); override cancel
    # (M49) at 1.5 s runs the axis at 100 %.
    assert main(['run', str(fig8), '--out', str(tmp_path / 's'), '--json',
                 '--set', 'experiment.duration_s=2.6', '--set', 'lathe_sim.depth_mm=[3.0,3.0,3.0]',
                 '--set', 'lathe_sim.override_cancel_span_s=[1.5,3.0]']) == 0
    out = json.loads(capfd.readouterr().out)
    assert 'regulation stopped at' in out['handed_back']
    stopped_s = float(out['handed_back'].split('at ')[1].split(' s')[0])
    assert 1.5 < stopped_s <= 2.5     # within 1 s of the switch
    session = read_session(tmp_path / 's')
    reasons = session.signals['override_reason']
    first = int((reasons == Reason.FEED_NOT_FOLLOWING).argmax())
    assert session.t_s[first] == stopped_s or abs(session.t_s[first] - stopped_s) < 0.006
    assert (reasons[first:] == Reason.FEED_NOT_FOLLOWING).all()
    assert (session.signals['answered_override_pct'][first:] == 100.0).all()
    # The bridge said why on /diagnostics (the session holds it).
    from rosbags.highlevel import AnyReader

    with AnyReader([tmp_path / 's']) as reader:
        connections = [c for c in reader.connections if c.topic == '/diagnostics']
        texts = [s.message for c, _, raw in reader.messages(connections=connections)
                 for s in reader.deserialize(raw, c.msgtype).status
                 if s.name == '/pmc_bridge' and s.level == 1]   # WARN
    assert any('FEED_NOT_FOLLOWING: the feed does not follow the override' in t for t in texts)
    # And the FeedOverride message carries the reason's sentence.
    with AnyReader([tmp_path / 's']) as reader:
        connections = [c for c in reader.connections if c.topic == '/pmc/feed_override']
        details = {reader.deserialize(raw, c.msgtype).detail
                   for c, _, raw in reader.messages(connections=connections)}
    assert any('regulation stopped, feed handed back' in d for d in details)
    assert FeedOverride.REASON_FEED_NOT_FOLLOWING == Reason.FEED_NOT_FOLLOWING
