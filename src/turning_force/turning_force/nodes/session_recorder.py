"""``session_recorder``: every topic of the graph into a rosbag2 MCAP session.

Subscribes, without deserialising, to every topic of the graph (:data:`GRAPH_TOPICS`) and
writes them to ``output_dir`` as they come, stamped with this node's clock at receipt
(:class:`turning_force.nodes.spin.NodeTime`). A writer thread does the disk work, so that the
executor that runs the recorder with the control graph never waits for the disk
(``background=False`` writes on the executor's thread, for comparison). Embeds the experiment
file (``experiment_file``), the software versions and the resolved parameters: its owner
passes them (``custom_data``, :meth:`SessionRecorderNode.add_custom_data`), or with
``capture_parameters`` it
asks the graph's nodes over their parameter services. A killed recorder loses at most
``flush_period_s`` of data (``turning-force repair`` completes the session). A write that fails
stops the recording with one error, logged, on ``/diagnostics`` and in
:attr:`SessionRecorderNode.failure`; the graph goes on.
"""

from __future__ import annotations

import contextlib
import datetime
import functools
import importlib
import sys
from pathlib import Path
from typing import Any

from rclpy.node import Node
from rclpy.parameter import parameter_value_to_python
from rclpy.parameter_client import AsyncParameterClient
from rclpy.qos import QoSProfile
from std_msgs.msg import String

from turning_force.core.experiment import SETTINGS_OF, RecorderSettings
from turning_force.nodes.diagnostics import Diagnostics
from turning_force.nodes.force_controller import REFERENCE_QOS
from turning_force.nodes.parameters import SettingsParameters
from turning_force.nodes.spin import STREAM_DEPTH, NodeTime, node_main, timer_callback
from turning_force.session.bag import (
    CUSTOM_EXPERIMENT,
    CUSTOM_PARAMETERS,
    CUSTOM_VERSIONS,
    GRAPH_TYPES,
    SETTINGS_TOPIC,
    BagError,
    SessionWriter,
    dumps,
    settings_text,
    software_versions,
)

__all__ = ['GRAPH_TOPICS', 'LATCHED_TOPICS', 'SessionRecorderNode', 'main', 'msgtype',
           'topic_qos']


def msgtype(cls: type) -> str:
    """``turning_force_msgs.msg.ServoCurrents`` -> ``turning_force_msgs/msg/ServoCurrents``."""
    return f'{cls.__module__.split(".")[0]}/msg/{cls.__name__}'


def message_class(msgtype: str) -> type:
    """``turning_force_msgs/msg/ServoCurrents`` -> its generated class (:func:`msgtype`'s
    inverse)."""
    package, _, name = msgtype.split('/')
    cls: type = getattr(importlib.import_module(f'{package}.msg'), name)
    return cls


GRAPH_TOPICS: dict[str, type] = {topic: message_class(msgtype)
                                  for topic, msgtype in GRAPH_TYPES.items()}

# Published once, transient-local, so that a late joiner gets the last one (a latched topic).
LATCHED_TOPICS = frozenset({'force/reference', SETTINGS_TOPIC})


def topic_qos(topic: str) -> QoSProfile:
    """The QoS a subscriber to one of :data:`GRAPH_TOPICS` takes: transient-local for the
    latched ones, a queue of 100 for the others (a second of blocks at 10 ms)."""
    return REFERENCE_QOS if topic in LATCHED_TOPICS else QoSProfile(depth=STREAM_DEPTH)


class SessionRecorderNode(Node):
    """The graph's topics to one rosbag2 MCAP folder.

    ``background``: the disk work on a writer thread (true), or on the executor's thread.
    """

    def __init__(self, *, background: bool = True, custom_data: dict[str, str] | None = None,
                 **kwargs: Any) -> None:
        super().__init__('session_recorder', **kwargs)
        stamp = datetime.datetime.now().strftime('%Y%m%d_%H%M%S')
        # Declared from the core's RecorderSettings: ranges checked, a mistyped key refused.
        self.parameters = SettingsParameters(self, RecorderSettings)
        path = Path(self.get_parameter('output_dir').value or f'bags/session_{stamp}')
        custom = {CUSTOM_VERSIONS: dumps(software_versions()), **(custom_data or {})}
        experiment = str(self.get_parameter('experiment_file').value)
        if experiment:
            custom[CUSTOM_EXPERIMENT] = Path(experiment).read_text()
        self._parameters_given = CUSTOM_PARAMETERS in custom
        self._captured: dict[str, dict[str, Any]] = {}   # the graph's, as asked (capture)
        self.writer = SessionWriter(path, float(self.get_parameter('flush_period_s').value),
                                    background=background, custom_data=custom)
        self.diagnostics = Diagnostics(self)
        self._closed = False
        self.failure: BagError | None = None   # why recording stopped, if a write failed
        # The receipt time of every message, without a clock call per message.
        self._time = NodeTime(self)
        self._early: list[tuple[str, bytes]] = []   # received before sim time began
        # The custom data as a topic too, so that any bag tool keeps it (session/bag.py); and
        # published, latched, for a live view of the session.
        self.writer.record_settings(self.resolve_topic_name(SETTINGS_TOPIC))
        self._settings_publisher = self.create_publisher(String, SETTINGS_TOPIC, REFERENCE_QOS)
        self._publish_settings()
        self.create_timer(1.0, timer_callback(self._check_writer))
        for topic, cls in GRAPH_TOPICS.items():
            name = self.resolve_topic_name(topic)
            self.writer.add_topic(name, msgtype(cls))
            self.create_subscription(cls, topic, self._callback(name), topic_qos(topic),
                                     raw=True)
        self._asking: set[str] = set()
        self._parameter_clients: dict[str, AsyncParameterClient] = {}
        if self.get_parameter('capture_parameters').value:
            self.create_timer(1.0, self._capture_parameters)
        self.get_logger().info(f'recording to {path}')

    def _capture_parameters(self) -> None:
        """Ask each graph node not yet heard from for its parameters (once it is up)."""
        for name, kind in SETTINGS_OF.items():
            if name == 'experiment' or name in self._captured or name in self._asking:
                continue
            client = self._parameter_clients.get(name)
            if client is None:
                remote = f'{self.get_namespace().rstrip("/")}/{name}'
                client = self._parameter_clients[name] = AsyncParameterClient(self, remote)
            if not client.services_are_ready():
                continue
            self._asking.add(name)
            names = list(kind.fields())
            future = client.get_parameters(names)
            future.add_done_callback(functools.partial(self._on_parameters, name, names))

    def _on_parameters(self, node: str, names: list[str], future: Any) -> None:
        self._asking.discard(node)
        response = future.result()
        if response is None or len(response.values) != len(names):
            return
        self._captured[node] = {n: parameter_value_to_python(v)
                                for n, v in zip(names, response.values, strict=True)}
        self._publish_settings()

    def _callback(self, name: str) -> Any:
        write, received, stamp_ns = self.writer.write, self.diagnostics.received, self._time.ns
        sim_time = bool(self.get_parameter('use_sim_time').value)

        def record(data: bytes) -> None:
            if self._closed:
                return
            ns = stamp_ns()
            try:
                if sim_time and ns == 0:
                    # Sim time has not started here: the first block's messages can come before
                    # the /clock that began it. They are logged when the clock has begun.
                    self._early.append((name, data))
                else:
                    if self._early:
                        self._write_early(ns)
                    write(name, ns, data)
            except BagError as exc:
                self._failed(exc)
                return
            received(name)
        return record

    def _write_early(self, ns: int) -> None:
        early, self._early = self._early, []
        for name, data in early:
            self.writer.write(name, ns, data)

    def _check_writer(self) -> None:
        """A failure of the writer thread said within a second, messages coming or not; the
        queue's depth on /diagnostics."""
        if self.writer.failure is not None and not self._closed:
            self._failed(self.writer.failure)
        if self.writer.background:
            self.diagnostics.set_value('queue_high_water', self.writer.queue_high_water)

    def _failed(self, exc: BagError) -> None:
        """Stop recording for good; say it once in the log and on /diagnostics for as long as
        the node runs. The node does not raise: the graph it records (in this process on the
        machine PC) goes on regulating, without a recording."""
        self._closed = True
        self.failure = exc
        self.diagnostics.error(str(exc), log=True)
        self.create_timer(1.0, lambda: self.diagnostics.error(str(exc)))

    def add_custom_data(self, key: str, value: str) -> None:
        self.writer.set_custom_data(key, value)
        self._parameters_given |= key == CUSTOM_PARAMETERS
        self._publish_settings()

    def _publish_settings(self) -> None:
        """The settings, latched, for live views: the session's custom data, with the graph's
        parameters captured so far where no one gave them (the recording takes them at close)."""
        custom = self.writer.custom_data
        if self._captured and not self._parameters_given:
            custom = {**custom, CUSTOM_PARAMETERS: dumps(self._captured)}
        self._settings_publisher.publish(String(data=settings_text(custom)))

    def end(self, stopped_by: str | None) -> None:
        """Say, before :meth:`close`, what stopped the run before its planned end (None: it
        ran to it); the session records it with the blocks it holds."""
        if not self._closed:
            self.writer.end(stopped_by)

    def close(self) -> None:
        """Finish the session (summary, index, metadata.yaml). Idempotent. Raises the
        :class:`BagError` of a write that fails."""
        if not self._closed:
            self._closed = True
            if self._captured and not self._parameters_given:
                self.writer.set_custom_data(CUSTOM_PARAMETERS, dumps(self._captured))
            try:
                if self._early:   # sim time never began: logged where it stands
                    self._write_early(0)
                self.writer.close()
            except BagError as exc:   # the disk filled: the summary could not be written
                self.failure = exc
                self.get_logger().error(str(exc))
                raise
            self.get_logger().info(f'session closed: {self.writer.path}')

    def destroy_node(self) -> None:
        with contextlib.suppress(BagError):   # logged by close(); the node goes all the same
            self.close()
        node_time = getattr(self, '_time', None)   # absent when the parameters were refused
        if node_time is not None:
            node_time.close()
        super().destroy_node()


main = node_main(SessionRecorderNode)


if __name__ == '__main__':
    sys.exit(main())
