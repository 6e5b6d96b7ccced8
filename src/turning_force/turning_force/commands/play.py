"""``turning-force replay BAG --publish``: the session's sensor topics into a live graph.

Like ``ros2 bag play`` (which is not on PyPI): the recorded ``servo/currents``,
``servo/joint_state`` and ``force/reference`` are published as recorded, bytes unchanged, at
their recorded spacing divided by ``rate``, under the namespace of this process's ROS arguments.
Whatever graph is running (``ros2 run`` nodes, ``turning_force_graph`` without its simulator)
takes them from there. The session is checked first as :func:`read_session` checks it: a
session missing messages is refused unless ``partial``.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import rclpy
from rclpy.context import Context
from rclpy.node import Node
from rclpy.publisher import Publisher

from turning_force.commands.run import print_progress
from turning_force.nodes.force_controller import REFERENCE_QOS
from turning_force.nodes.session_recorder import GRAPH_TOPICS
from turning_force.session.bag import GRAPH_TYPES, BagError
from turning_force.session.reader import read_recording, read_session

__all__ = ['SENSOR_TOPICS', 'play']

DISCOVERY_S = 2.0   # longest wait for a subscriber to servo/currents before playing [s]

SENSOR_TOPICS: dict[str, type] = {topic: GRAPH_TOPICS[topic] for topic in (
    'servo/currents', 'servo/joint_state', 'force/reference')}


def _relative(topic: str) -> str | None:
    return next((t for t in SENSOR_TOPICS if topic == t or topic.endswith('/' + t)), None)


def play(bag: Path, rate: float = 1.0, context: Context | None = None,
         show_progress: bool = True, partial: bool = False) -> int:
    """Publish the bag's sensor topics; return how many messages went out."""
    if not rate > 0:
        raise BagError(f'--rate {rate!r}: must be positive')
    read_session(bag, partial)   # a foreign, damaged or incomplete session stops here
    recording = read_recording(bag)
    queue: list[tuple[int, int, str, bytes]] = []   # (log time, file order, topic, CDR)
    for name, info in recording.topics.items():
        relative = _relative(name)
        if relative is None:
            continue
        if info.msgtype != GRAPH_TYPES[relative]:
            raise BagError(f'{bag}: {name} is {info.msgtype}, not {GRAPH_TYPES[relative]}')
        queue += [(stamp, len(queue) + k, relative, raw)
                  for k, (stamp, raw) in enumerate(recording.messages.get(name, []))]
    queue.sort()
    own_context = context is None
    if context is None:
        context = Context()
        rclpy.init(context=context)
    node = Node('session_player', context=context)
    publishers: dict[str, Publisher[Any]] = {
        topic: node.create_publisher(cls, topic, REFERENCE_QOS if topic == 'force/reference'
                                     else 100)
        for topic, cls in SENSOR_TOPICS.items()}
    sent = 0
    try:
        # As ros2 bag play, it does not wait for a graph; but it gives discovery a moment, so
        # that the first blocks are not published to nobody.
        deadline = time.monotonic() + DISCOVERY_S
        while (publishers['servo/currents'].get_subscription_count() == 0
               and time.monotonic() < deadline):
            time.sleep(0.01)
        start_wall = time.monotonic()
        start_bag = queue[0][0] if queue else 0
        for timestamp, _, relative_topic, raw in queue:
            due = start_wall + (timestamp - start_bag) * 1e-9 / rate
            delay = due - time.monotonic()
            if delay > 0:
                time.sleep(delay)  # pacing the playback, as ros2 bag play does
            publishers[relative_topic].publish(raw)
            sent += 1
            if show_progress:
                print_progress(sent, len(queue))
    finally:
        node.destroy_node()
        if own_context:
            rclpy.try_shutdown(context=context)
    return sent
