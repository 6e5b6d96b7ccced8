"""The live views against a running graph: ``turning-force view`` read by Foxglove's own
protocol client and ROS 2 decoders (the npm packages, under the Node that make setup installs in
the venv), and ``turning-force watch`` in a terminal that is not one (its last frame)."""

from __future__ import annotations

import json
import math
import os
import re
import select
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest
from rclpy.node import Node
from rclpy.parameter import Parameter
from rosbags.highlevel import AnyReader
from std_msgs.msg import Float64
from turning_force_msgs.msg import CutRecord, ForceEstimate

from graph_run import BIN, session_params, start, stop
from turning_force.nodes.force_controller import REFERENCE_QOS
from turning_force.nodes.live_view import (
    BAND_SCHEMA,
    BAND_TOPIC,
    LiveViewNode,
    Throttle,
    view_topic,
)
from turning_force.nodes.session_recorder import GRAPH_TOPICS, msgtype
from turning_force.session.bag import CUSTOM_PARAMETERS, typestore
from turning_force.session.codec import fields

ROOT = Path(__file__).resolve().parents[2]
CLIENT = ROOT / 'test' / 'foxglove_client' / 'client.js'
LAYOUT = ROOT / 'config' / 'foxglove' / 'turning_force.json'
NODE_MODULES = Path(sys.prefix) / 'foxglove-client' / 'node_modules'   # make setup's
NODES = ('lathe_sim', 'force_estimator', 'force_controller', 'pmc_bridge', 'session_recorder')
# The topics that stream, one message a block: the client must decode every one the session
# recorder logged over the same span.
STREAMING = {'/force/estimate': 'turning_force_msgs/msg/ForceEstimate',
             '/control/feed_command': 'turning_force_msgs/msg/FeedCommand',
             '/pmc/feed_override': 'turning_force_msgs/msg/FeedOverride'}
CLIENT_S = 3.0   # how long the client decodes, from its first force estimate [s] (and until
#                  the latched reference has come: ROS discovery can be slow on a loaded PC)
REFERENCE_N = 500.0   # park1998_fig8's, set on force/reference as an operator would
BAND_N = 25.0         # park1998_fig8's allowed_error_n


def first_line(process: subprocess.Popen[str], timeout_s: float) -> str:
    """The first line ``process`` prints on stdout ('' if it exits or is silent that long)."""
    assert process.stdout is not None
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        ready, _, _ = select.select([process.stdout], [], [], 0.2)
        if ready:
            return process.stdout.readline()
        if process.poll() is not None:
            return ''
    return ''


def turning_force(*args: str, stderr: int | None = subprocess.PIPE) -> subprocess.Popen[str]:
    # A wide terminal, so that no line of the watch's frame wraps.
    return subprocess.Popen([str(BIN / 'turning-force'), *args], stdout=subprocess.PIPE,
                            stderr=stderr, text=True, env={**os.environ, 'COLUMNS': '200'})


def recorded_stamps(bag: Path) -> dict[str, list[int]]:
    """The header stamps [ns] of each streaming topic's messages in the session."""
    stamps: dict[str, list[int]] = {topic: [] for topic in STREAMING}
    with AnyReader([bag], default_typestore=typestore()) as reader:
        for connection, _, raw in reader.messages():
            topic = next((t for t in STREAMING if connection.topic.endswith(t)), None)
            if topic is not None:
                stamp = reader.deserialize(raw, connection.msgtype).header.stamp
                stamps[topic].append(stamp.sec * 10**9 + stamp.nanosec)
    return stamps


def test_foxglove_client_decodes_what_the_recorder_logged_and_watch_shows_it(
        context, tmp_path, fig8):
    namespace = f'/live_{os.getpid()}'
    bag = tmp_path / 'session'
    graph = start('turning_force_graph', namespace, fig8, '--params-file',
                  str(session_params(tmp_path / 'session.yaml', bag)))
    # The reference, latched (transient-local), published before any view runs.
    operator = Node('operator', context=context)
    operator.create_publisher(Float64, f'{namespace}/force/reference', REFERENCE_QOS).publish(
        Float64(data=REFERENCE_N))
    live = ('--namespace', namespace, '--experiment', str(fig8))
    view = turning_force('view', *live, '--port', '0', stderr=subprocess.DEVNULL)
    watch = turning_force('watch', *live, '--duration', '9')
    try:
        line = first_line(view, 30.0)
        url = re.search(r'ws://127\.0\.0\.1:\d+', line)   # bound to this machine by default
        assert url is not None, line
        client = subprocess.run(
            [str(BIN / 'node'), str(CLIENT), url.group(0), str(CLIENT_S), '/force/reference'],
            env={**os.environ, 'NODE_PATH': str(NODE_MODULES)}, capture_output=True,
            text=True, timeout=60, check=False)
        assert client.returncode == 0, client.stderr
        screen, watch_errors = watch.communicate(timeout=30)
        assert watch.returncode == 0, watch_errors
    finally:
        for process in (view, watch):
            if process.poll() is None:
                stop(process)
        stop(graph)
        operator.destroy_node()
    topics = json.loads(client.stdout)['topics']
    stamps = recorded_stamps(bag)
    for topic, schema_name in STREAMING.items():
        seen = topics[topic]
        assert (seen['encoding'], seen['schemaEncoding'], seen['schemaName']) == \
            ('cdr', 'ros2msg', schema_name)
        # In the order they came (the publisher's: the client's and the recorder's alike).
        heard = [sec * 10**9 + nanosec for sec, nanosec in seen['stamps']]
        logged = stamps[topic]
        # Over the span the client listened, from the first message it decoded to the last,
        # found in the recorder's log, it decoded every message the recorder logged: as many,
        # at the same stamps. The span is one of arrival, not of stamps: the bridge stamps a
        # change it publishes between blocks with its own clock, ahead of the blocks' DAQ
        # stamps by the graph's latency, so under load such a message, published before the
        # client subscribed, has a stamp inside the client's first and last. The first and
        # last stamps are left out: a stamp may be shared by two messages, one heard, one not.
        first, last = heard[0], heard[-1]
        opened, closed = logged.index(first), len(logged) - 1 - logged[::-1].index(last)
        inside = sorted(s for s in heard if s not in (first, last))
        logged_inside = sorted(s for s in logged[opened:closed + 1] if s not in (first, last))
        assert len(inside) >= 100, topic
        assert inside == logged_inside, topic
    # The latched reference, published before the client subscribed: sent again to it.
    assert topics['/force/reference']['schemaName'] == 'std_msgs/msg/Float64'
    assert REFERENCE_N in topics['/force/reference']['values']
    # The session's settings, latched by the recorder: YAML of its custom data (its keys
    # here), with the graph's parameters once the recorder has captured them.
    assert topics['/session/settings']['schemaName'] == 'std_msgs/msg/String'
    settings = topics['/session/settings']['values']
    assert 'turning_force.versions_json' in settings[0]
    assert any(CUSTOM_PARAMETERS in keys for keys in settings), settings
    # /diagnostics, once a second from every node.
    assert {f'{namespace}/{n}' for n in NODES} <= set(topics['/diagnostics']['values'])
    # The band about the reference the controller regulates to, fig8's allowed_error_n.
    assert topics['/view/band']['values'][0] == {
        'reference_n': REFERENCE_N, 'low_n': REFERENCE_N - BAND_N, 'high_n': REFERENCE_N + BAND_N}
    # The terminal view's last frame: the regulated force beside the reference and its band,
    # the override requested and applied, the gate armed, no alarm, every node heard.
    assert f'turning_force {namespace}' in screen
    assert re.search(rf'reference\s+{REFERENCE_N:.1f} N  band ±{BAND_N:g} N  error [+-]\d', screen)
    force = re.search(r'force\s+(-?\d+\.\d) N  status OK', screen)
    assert force is not None, screen
    # Fig. 8's cut, regulated: the force near the reference (a depth step doubles it for a
    # moment, Park Fig. 8: within 60 % of the reference whenever the frame is drawn).
    assert abs(float(force.group(1)) - REFERENCE_N) < 0.6 * REFERENCE_N, screen
    assert re.search(r'override requested\s+\d+\.\d %  \(smc\)', screen), screen
    assert re.search(r'override applied\s+\d+\.0 %  code \d+  table fanuc_0t_4bit', screen)
    assert re.search(r'gate\s+armed  reason (NORMAL|RISE_LIMIT)  in the cut', screen), screen
    # No alarm output, no stop request (a busy machine may make lathe_sim warn of missed
    # periods: an alarm of the row, rightly, so the row is not asserted empty).
    assert re.search(r'alarms\s+\S', screen), screen
    assert 'ALARM output set' not in screen and 'STOP requested' not in screen, screen
    for node in NODES:   # each heard on /diagnostics (WARN: see the alarms above)
        assert re.search(rf'{namespace}/{node} (OK|WARN)\b', screen), screen
    estimates = re.search(r'force/estimate (\d+)', screen)
    assert estimates is not None and int(estimates.group(1)) >= 100, screen


def test_a_port_in_use_is_one_line_and_exit_2():
    with socket.socket() as taken:
        taken.bind(('127.0.0.1', 0))
        taken.listen()
        port = taken.getsockname()[1]
        result = subprocess.run(
            [str(BIN / 'turning-force'), 'view', '--namespace', f'/taken_{os.getpid()}',
             '--port', str(port)], capture_output=True, text=True, timeout=60, check=False)
    assert result.returncode == 2, result.stderr
    assert re.search(rf'cannot serve on 127\.0\.0\.1:{port}: ', result.stderr), result.stderr
    assert 'Traceback' not in result.stderr


def test_the_rate_thins_a_stream_and_passes_every_event(context, executor, spin_until):
    # 50 estimates and 5 cut records published at once to a view forwarding 20 a second: it
    # takes every one, forwards every cut record and at most one estimate per 50 ms of the
    # time they took to arrive (one at the start).
    view = LiveViewNode(context=context, parameter_overrides=[
        Parameter('port', value=0), Parameter('rate_hz', value=20.0)])
    probe = Node('probe', context=context)
    executor.add_node(view)
    executor.add_node(probe)
    estimates = probe.create_publisher(ForceEstimate, 'force/estimate', 100)
    cuts = probe.create_publisher(CutRecord, 'pmc/cuts', 100)
    assert spin_until(lambda: estimates.get_subscription_count() and cuts.get_subscription_count())
    start = time.monotonic()
    for k in range(50):
        estimates.publish(ForceEstimate(force_n=float(k)))
    for k in range(5):
        cuts.publish(CutRecord(index=k + 1))
    diagnostics = view.diagnostics
    assert spin_until(lambda: diagnostics.received_count('force/estimate') == 50
                      and diagnostics.received_count('pmc/cuts') == 5)
    elapsed_s = time.monotonic() - start
    assert diagnostics.published_count('pmc/cuts') == 5
    assert 1 <= diagnostics.published_count('force/estimate') <= 1 + math.ceil(elapsed_s * 20)
    assert diagnostics.published_count('force/estimate') < 50


@pytest.mark.parametrize(('rate_hz', 'passed'), [(0.0, 1000), (20.0, 200), (1000.0, 1000)])
def test_the_rate_bounds_each_streaming_topic(rate_hz, passed):
    # 10 s of blocks at 10 ms: 20 Hz lets one in five through (every 50 ms, exactly: the
    # stamps are integers), 0 and anything at or above 100 Hz all of them.
    throttle = Throttle(rate_hz)
    assert sum(throttle.passes(k * 10_000_000) for k in range(1000)) == passed


def panels(tree: object) -> set[str]:
    """The panel ids a layout tree places."""
    if isinstance(tree, str):
        return {tree}
    assert isinstance(tree, dict)
    return panels(tree['first']) | panels(tree['second'])


def test_the_layout_plots_topics_and_fields_the_view_serves():
    layout = json.loads(LAYOUT.read_text())
    assert panels(layout['layout']) == set(layout['configById'])
    served = {view_topic(topic): msgtype(cls) for topic, cls in GRAPH_TOPICS.items()}
    paths = []
    for config in layout['configById'].values():
        paths += [p['value'] for p in config.get('paths', [])]
        paths += [config[key] for key in ('topicPath', 'topicToRender') if key in config]
    assert len(paths) >= 14
    store = typestore()
    for path in paths:
        topic, _, field = path.partition('.')
        if topic == BAND_TOPIC:
            assert field in BAND_SCHEMA['properties'], path
        else:
            assert topic in served, path
            assert not field or field in {f.path for f in fields(store, served[topic])}, path
