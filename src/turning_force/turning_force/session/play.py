"""``turning-force replay BAG --publish``: the session's sensor topics into a live graph.

Like ``ros2 bag play`` (which is not on PyPI): the recorded ``servo/currents``,
``servo/joint_state`` and ``force/reference`` are published as recorded, bytes unchanged, at
their recorded spacing divided by ``rate``, under the namespace of this process's ROS arguments.
Whatever graph is running (``ros2 run`` nodes, ``turning_force_graph`` without its simulator)
takes them from there.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import rclpy
from rclpy.context import Context
from rclpy.node import Node
from rclpy.publisher import Publisher
from rosbags.highlevel import AnyReader, AnyReaderError
from rosbags.rosbag2 import ReaderError
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64
from turning_force_msgs.msg import ServoCurrents

from turning_force.nodes.force_controller import REFERENCE_QOS
from turning_force.session.bag import BagError, typestore
from turning_force.session.run import print_progress

__all__ = ['SENSOR_TOPICS', 'play']

SENSOR_TOPICS: dict[str, type] = {
    'servo/currents': ServoCurrents,
    'servo/joint_state': JointState,
    'force/reference': Float64,
}


def play(bag: Path, rate: float = 1.0, context: Context | None = None,
         show_progress: bool = True) -> int:
    """Publish the bag's sensor topics; return how many messages went out."""
    if not rate > 0:
        raise BagError(f'--rate {rate!r}: must be positive')
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
        with AnyReader([bag], default_typestore=typestore()) as reader:
            chosen = [c for c in reader.connections
                      if any(c.topic.endswith(t) for t in SENSOR_TOPICS)]
            total = sum(c.msgcount for c in chosen)
            start_wall, start_bag = time.monotonic(), None
            for connection, timestamp, raw in reader.messages(connections=chosen):
                if start_bag is None:
                    start_bag = timestamp
                due = start_wall + (timestamp - start_bag) * 1e-9 / rate
                delay = due - time.monotonic()
                if delay > 0:
                    time.sleep(delay)  # pacing the playback, as ros2 bag play does
                topic = next(t for t in SENSOR_TOPICS if connection.topic.endswith(t))
                publishers[topic].publish(bytes(raw))
                sent += 1
                if show_progress:
                    print_progress(sent, total)
    except (AnyReaderError, ReaderError, OSError) as exc:
        raise BagError(f'{bag}: cannot play the session: {exc}') from exc
    finally:
        node.destroy_node()
        if own_context:
            rclpy.try_shutdown(context=context)
    return sent
