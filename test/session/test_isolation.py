"""A lock-step run is a world of its own: another graph on the same ROS domain (another run, a
machine's graph) neither hears it nor is heard by it, and the run names anyone on its topics."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest
from rclpy.node import Node
from rosbags.highlevel import AnyReader
from turning_force_msgs.msg import FeedOverride, ServoCurrents

from turning_force.commands.run import foreign_endpoints, run_lockstep
from turning_force.core.experiment import load_experiment
from turning_force.core.kernel.simulate import simulate
from turning_force.session.bag import typestore
from turning_force.session.reader import read_session, recorded_metrics

# Another graph in its own process, on this process's domain and discovery settings: it
# publishes what a second run or a machine would (currents, estimates, commands, a 0 % feed
# hold) and counts what it hears on the same topics, by the frame_id its own messages
# ('foreign') and the test's witness ('witness') carry; 'other' would be the run's. Commands
# on stdin: 'counts' prints the counts as one JSON line; end of input stops it.
FOREIGN = textwrap.dedent("""
    import json, sys, threading
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from turning_force_msgs.msg import FeedCommand, FeedOverride, ForceEstimate, ServoCurrents

    rclpy.init()
    node = Node('foreign_graph')
    heard = {}

    def count(topic):
        def take(msg):
            who = msg.header.frame_id if msg.header.frame_id in ('witness', 'foreign') else 'other'
            heard[f'{topic} {who}'] = heard.get(f'{topic} {who}', 0) + 1
        return take

    topics = {'servo/currents': ServoCurrents, 'force/estimate': ForceEstimate,
              'control/feed_command': FeedCommand, 'pmc/feed_override': FeedOverride}
    publishers = []
    for topic, cls in topics.items():
        node.create_subscription(cls, topic, count(topic), 100)
        publishers.append(node.create_publisher(cls, topic, 100))
    junk = [ServoCurrents(sample_period_s=1e-3, phase_u_a=[50.0] * 10, phase_v_a=[50.0] * 10,
                          rotor_angle_rad=[0.0] * 10, feed_rate_mm_min=[1.0] * 10),
            ForceEstimate(force_n=5000.0), FeedCommand(override_pct=0.0, controller='smc'),
            FeedOverride(applied_pct=0.0, pmc_code=0, pmc_bits=[True] * 4,
                         table='fanuc_0t_4bit', armed=True)]   # a feed hold, 0 %
    for msg in junk:
        msg.header.frame_id = 'foreign'
    node.create_timer(0.005, lambda: [p.publish(m) for p, m in zip(publishers, junk)])
    commands = []

    def read_commands():
        for line in sys.stdin:
            commands.append(line)
        commands.append(None)

    threading.Thread(target=read_commands, daemon=True).start()
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    print('ready', flush=True)
    while not commands or commands[-1] is not None:
        executor.spin_once(timeout_sec=0.01)
        while commands and commands[0] is not None:
            commands.pop(0)
            print(json.dumps(heard), flush=True)
    executor.remove_node(node)
    node.destroy_node()
    rclpy.shutdown()
""")


@pytest.fixture
def foreign_graph():
    process = subprocess.Popen([sys.executable, '-c', FOREIGN], stdin=subprocess.PIPE,
                               stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    assert process.stdout.readline() == 'ready\n'

    def counts() -> dict[str, int]:
        process.stdin.write('counts\n')
        process.stdin.flush()
        return json.loads(process.stdout.readline())

    try:
        yield counts
    finally:
        process.stdin.close()
        process.wait(timeout=20)


def test_a_run_neither_hears_nor_is_heard_by_another_graph_on_its_domain(
        foreign_graph, context, executor, spin_until, fig8, tmp_path):
    # First, that the foreign graph is there and talks: a node of an ordinary context (the
    # test's, same domain) hears its currents, and it hears this witness's override.
    witness = Node('witness', context=context)
    executor.add_node(witness)
    currents: list[ServoCurrents] = []
    witness.create_subscription(ServoCurrents, 'servo/currents', currents.append, 100)
    feed = witness.create_publisher(FeedOverride, 'pmc/feed_override', 100)
    marked = FeedOverride(applied_pct=100.0)
    marked.header.frame_id = 'witness'
    assert spin_until(lambda: len(currents) >= 10, 20.0)
    assert spin_until(lambda: feed.publish(marked) or
                      foreign_graph().get('pmc/feed_override witness', 0) > 0, 20.0)
    discovery = os.environ.get('ROS_AUTOMATIC_DISCOVERY_RANGE')

    # Then a run on the same domain, while the foreign graph publishes at 200 Hz.
    experiment = load_experiment(fig8).with_sets(['experiment.duration_s=2.0'])
    bag = tmp_path / 'isolated'
    run_lockstep(experiment, bag)

    heard = foreign_graph()
    assert {k: v for k, v in heard.items() if k.endswith(' other')} == {}, heard
    # Nothing foreign was heard: exactly one message per block on each topic of the chain, all
    # from the run's own nodes, and the metrics the core loop gives for the same file.
    with AnyReader([bag], default_typestore=typestore()) as reader:
        counts = {c.topic: c.msgcount for c in reader.connections}
    for topic in ('/servo/currents', '/force/estimate', '/control/feed_command'):
        assert counts[topic] == 200, (topic, counts)
    session = read_session(bag)
    core = simulate(experiment).metrics
    for name, value in recorded_metrics(session).items():
        assert value == pytest.approx(core[name], rel=1e-9, abs=1e-12), name
    # The run set its own discovery for its own context only.
    assert os.environ.get('ROS_AUTOMATIC_DISCOVERY_RANGE') == discovery


def test_the_run_names_a_foreign_node_on_its_topics(context, executor):
    # The second line of defence, on an ordinary context where others are visible: anyone
    # but the run's own nodes on its topics is named with the topic.
    own = Node('lathe_sim', context=context)
    intruder = Node('intruder', namespace='/lathe1', context=context)
    own.create_publisher(ServoCurrents, 'servo/currents', 10)
    own.create_subscription(FeedOverride, 'pmc/feed_override', lambda _: None, 10)
    topics = ['servo/currents', 'pmc/feed_override']
    assert foreign_endpoints(own, {'/lathe_sim'}, topics) == []
    intruder.create_subscription(ServoCurrents, '/servo/currents', lambda _: None, 10)
    intruder.create_publisher(FeedOverride, '/pmc/feed_override', 10)
    assert foreign_endpoints(own, {'/lathe_sim'}, topics) == [
        '/servo/currents: subscription /lathe1/intruder',
        '/pmc/feed_override: publisher /lathe1/intruder']
    for node in (own, intruder):
        node.destroy_node()


def test_a_node_refuses_a_bad_ros_domain_in_one_line():
    # rcl would stop with a traceback (or, above 232, Fast DDS with a port error).
    for domain in ('abc', '233'):
        node = subprocess.run(
            [str(Path(sys.prefix) / 'bin' / 'force_estimator')],
            env={**os.environ, 'ROS_DOMAIN_ID': domain}, capture_output=True, text=True,
            timeout=60, check=False)
        assert node.returncode == 2
        assert node.stderr == (f"turning_force: ROS_DOMAIN_ID='{domain}': expected an integer "
                               'from 0 to 232\n')
