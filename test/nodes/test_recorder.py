"""The recorder's disk work on a writer thread (SessionWriter ``background``): the same session
as writing on the caller's thread, and a failing disk still said, once, as the one BagError;
on sim time, messages that come before the clock has begun logged when it has."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import yaml
from builtin_interfaces.msg import Time
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.serialization import serialize_message
from rosbags.highlevel import AnyReader
from rosgraph_msgs.msg import Clock
from std_msgs.msg import Float64, String
from turning_force_msgs.msg import ForceEstimate

from turning_force.nodes.force_controller import REFERENCE_QOS
from turning_force.nodes.session_recorder import SessionRecorderNode
from turning_force.session.bag import CUSTOM_END, CUSTOM_PARAMETERS, SessionWriter, typestore
from turning_force.session.reader import settings_data

TOPICS = {'/a': 'std_msgs/msg/Float64', '/b': 'std_msgs/msg/Float64'}


def write(path: Path, background: bool, count: int) -> SessionWriter:
    writer = SessionWriter(path, flush_period_s=0.001, background=background,
                           queue_limit=64)   # a small queue: writes wait for the thread
    for topic, msgtype in TOPICS.items():
        writer.add_topic(topic, msgtype)
    for k in range(count):
        writer.write('/a' if k % 3 else '/b', 1_000 * k, serialize_message(Float64(data=k)))
    return writer


def read(path: Path) -> list[tuple[str, int, bytes]]:
    with AnyReader([path], default_typestore=typestore()) as reader:
        return [(c.topic, t, bytes(raw)) for c, t, raw in reader.messages()]


def test_a_writer_thread_writes_the_same_session(tmp_path):
    threaded = write(tmp_path / 'threaded', True, 5000)
    assert threaded.background and threaded.counts == {'/a': 3333, '/b': 1667}
    threaded.close()
    threaded.close()   # idempotent
    plain = write(tmp_path / 'plain', False, 5000)
    plain.close()
    assert read(tmp_path / 'threaded') == read(tmp_path / 'plain')   # every message, in order
    # The queue never held more than its limit (the writes waited for the thread instead).
    assert 0 < threaded.queue_high_water <= 64


FULL_DISK = """
import resource, signal, sys
from pathlib import Path
from rclpy.serialization import serialize_message
from std_msgs.msg import Float64
from turning_force.session.bag import BagError, SessionWriter

signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
path = Path(sys.argv[1])
writer = SessionWriter(path, flush_period_s=0.0, background=True)
writer.add_topic('/a', 'std_msgs/msg/Float64')
limit = 200_000   # a file size limit fails the write as a full disk would
resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))
said = []
for k in range(200_000):
    try:
        writer.write('/a', k, serialize_message(Float64(data=k)) * 8)
    except BagError as exc:
        said.append(('write', str(exc)))
        break
try:
    writer.close()
except BagError as exc:
    said.append(('close', str(exc)))
writer.close()   # once said, not again
print(said)
"""


def test_a_full_disk_on_the_writer_thread_is_one_bag_error(tmp_path):
    bag = tmp_path / 'full'
    run = subprocess.run([sys.executable, '-c', FULL_DISK, str(bag)], capture_output=True,
                         text=True, timeout=120, check=False)
    assert run.returncode == 0, run.stderr
    said = eval(run.stdout.strip().splitlines()[-1])
    assert len(said) == 1, said   # from a write, or from close if the writes were all queued
    assert said[0][1] == (f'{bag}: cannot write the session: File too large; what was written '
                          f'before stays readable (`turning-force repair {bag}`)')
    assert 'Traceback' not in run.stderr


def recorder_on_sim_time(context, executor, path: Path) -> SessionRecorderNode:
    recorder = SessionRecorderNode(context=context, parameter_overrides=[
        Parameter('output_dir', value=str(path)), Parameter('capture_parameters', value=False),
        Parameter('use_sim_time', value=True)])
    executor.add_node(recorder)
    return recorder


def test_messages_before_sim_time_begins_are_logged_when_it_does(context, executor, spin_until,
                                                                 tmp_path):
    # A lock-step graph's first block: the simulator publishes /clock (the block's end, 10 ms)
    # and the block's messages, which may reach the recorder before the /clock does. They are
    # logged at 10 ms, not at 0, in the order they came.
    recorder = recorder_on_sim_time(context, executor, tmp_path / 'session')
    probe = Node('probe', context=context)
    executor.add_node(probe)
    estimates = probe.create_publisher(ForceEstimate, 'force/estimate', 10)
    clock = probe.create_publisher(Clock, '/clock', 10)
    assert spin_until(lambda: estimates.get_subscription_count() == 1
                      and clock.get_subscription_count() >= 1)
    estimates.publish(ForceEstimate(force_n=1.0))
    assert spin_until(lambda: recorder.diagnostics.received_count('/force/estimate') == 1)
    assert recorder.writer.counts.get('/force/estimate', 0) == 0   # held: no time yet
    clock.publish(Clock(clock=Time(sec=0, nanosec=10_000_000)))
    assert spin_until(lambda: recorder.get_clock().now().nanoseconds == 10_000_000)
    estimates.publish(ForceEstimate(force_n=2.0))
    assert spin_until(lambda: recorder.writer.counts.get('/force/estimate', 0) == 2)
    recorder.close()
    got = [(t, m.force_n) for _, t, m in decoded(tmp_path / 'session')]
    assert got == [(10_000_000, 1.0), (10_000_000, 2.0)]


def test_messages_are_kept_when_sim_time_never_begins(context, executor, spin_until, tmp_path):
    recorder = recorder_on_sim_time(context, executor, tmp_path / 'session')
    probe = Node('probe', context=context)
    executor.add_node(probe)
    estimates = probe.create_publisher(ForceEstimate, 'force/estimate', 10)
    assert spin_until(lambda: estimates.get_subscription_count() == 1)
    estimates.publish(ForceEstimate(force_n=3.0))
    assert spin_until(lambda: recorder.diagnostics.received_count('/force/estimate') == 1)
    recorder.close()
    assert [(t, m.force_n) for _, t, m in decoded(tmp_path / 'session')] == [(0, 3.0)]


def decoded(path: Path) -> list[tuple[str, int, object]]:
    """The graph's messages recorded (the session's settings left out)."""
    with AnyReader([path], default_typestore=typestore()) as reader:
        return [(c.topic, t, reader.deserialize(raw, c.msgtype))
                for c, t, raw in reader.messages() if c.topic != '/session/settings']


def test_the_recorder_latches_the_sessions_settings_and_records_them(context, executor,
                                                                      spin_until, tmp_path):
    # session/settings (issue 18): the settings as YAML, published transient-local, so that a
    # live view that joins late gets them, and recorded in the bag before the first message
    # and again as it closes (with how the recording ended).
    path = tmp_path / 'session'
    recorder = SessionRecorderNode(context=context, custom_data={CUSTOM_PARAMETERS: '{"a": 1}'},
                                   parameter_overrides=[Parameter('output_dir', value=str(path)),
                                                        Parameter('capture_parameters',
                                                                  value=False)])
    executor.add_node(recorder)
    late = Node('late', context=context)
    executor.add_node(late)
    got: list[str] = []
    late.create_subscription(String, 'session/settings', lambda m: got.append(m.data),
                             REFERENCE_QOS)
    assert spin_until(lambda: bool(got))
    assert yaml.safe_load(got[-1])[CUSTOM_PARAMETERS] == '{"a": 1}'
    estimates = late.create_publisher(ForceEstimate, 'force/estimate', 10)
    assert spin_until(lambda: estimates.get_subscription_count() == 1)
    estimates.publish(ForceEstimate(force_n=1.0))
    assert spin_until(lambda: recorder.writer.counts.get('/force/estimate', 0) == 1)
    recorder.close()
    recorded = [(topic, data) for topic, _, data in read(path) if topic == '/session/settings']
    assert len(recorded) == 2
    first, last = (settings_data([data])[0] for _, data in recorded)
    assert first[CUSTOM_PARAMETERS] == last[CUSTOM_PARAMETERS] == '{"a": 1}'
    assert CUSTOM_END not in first
    assert json.loads(last[CUSTOM_END]) == {'stopped_by': None, 'blocks': 0, 'planned': None}
