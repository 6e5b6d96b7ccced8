"""``live_view``: the graph's topics on a Foxglove WebSocket server (``turning-force view``).

Subscribes, without deserialising, to every topic the session recorder records
(:data:`~turning_force.nodes.session_recorder.GRAPH_TOPICS`) and forwards each message's bytes
unchanged on a Foxglove WebSocket channel, as Foxglove's own ROS 2 bridge does: message encoding
``cdr``, schema encoding ``ros2msg``, the schema text the session's MCAP file carries for that
topic (:func:`turning_force.session.bag.schema`), so that Foxglove and Lichtblick decode the live
view and a recorded session alike, with one layout (``config/foxglove/turning_force.json``).
Channels are named like the graph's topics, from this node's namespace: ``/force/estimate``
whatever namespace the graph of one machine runs in.

The server (foxglove-sdk) binds to ``host`` (127.0.0.1 unless told: the protocol has no
authentication) and ``port`` (0: any free one, logged). ``rate_hz`` bounds what each streaming
topic forwards (the latest message once ``1 / rate_hz`` has passed since the last forwarded);
the latched reference, the cut log and ``/diagnostics`` always pass. A latched topic's last
message is sent again when a client subscribes to it, so that a viewer started after the
reference was set still shows it (what transient-local durability does in ROS).

One more channel, ``/view/band`` (JSON), carries the reference the controller regulates to (the
feed command's ``reference_force_n``: a graph need not publish ``force/reference``) and the band
about it (``allowed_error_n``), with each forwarded feed command, for the plot of force vs
reference.

Parameters: :class:`turning_force.core.experiment.ViewSettings` (``live_view`` section).
"""

from __future__ import annotations

import sys
import threading
from collections.abc import Callable
from typing import Any

import foxglove
from foxglove.websocket import ChannelView, Client, ServerListener
from rclpy.node import Node
from rclpy.serialization import deserialize_message
from std_msgs.msg import String
from turning_force_msgs.msg import FeedCommand

from turning_force.core.errors import ConfigError
from turning_force.core.experiment import ViewSettings
from turning_force.nodes.diagnostics import Diagnostics
from turning_force.nodes.parameters import SettingsParameters
from turning_force.nodes.session_recorder import GRAPH_TOPICS, LATCHED_TOPICS, msgtype, topic_qos
from turning_force.nodes.spin import NodeTime, node_main, timer_callback
from turning_force.session.bag import SETTINGS_TOPIC, schema

__all__ = ['BAND_TOPIC', 'EVENT_TOPICS', 'LiveViewNode', 'Throttle', 'main', 'view_topic']

# Topics forwarded whatever rate_hz says: they come once, once a cut, or once a second per node.
EVENT_TOPICS = frozenset({*LATCHED_TOPICS, 'pmc/cuts', '/diagnostics'})
# The graph's topics, and the session's settings the recorder publishes (latched).
VIEW_TOPICS: dict[str, type] = {**GRAPH_TOPICS, SETTINGS_TOPIC: String}
BAND_TOPIC = '/view/band'
BAND_SCHEMA = {
    'title': 'turning_force.view.Band', 'type': 'object',
    'properties': {'reference_n': {'type': 'number'}, 'low_n': {'type': 'number'},
                   'high_n': {'type': 'number'}}}
# How often the re-sends of latched messages asked for by new subscribers go out [s].
RESEND_PERIOD_S = 0.1
# Messages the server keeps for a client that is slow to read, before it drops its oldest: the
# SDK's 1,024 is about a second of the graph's streams (nine topics at 100 Hz and the band),
# which a client on a busy 2-core PC can outlast (the live-view test lost six overrides so);
# 16,384 is 18 s of them, a few MB.
BACKLOG_MESSAGES = 16384


def view_topic(topic: str) -> str:
    """The channel of a graph topic: relative names from the root (``/force/estimate``)."""
    return topic if topic.startswith('/') else f'/{topic}'


class Throttle:
    """At most ``rate_hz`` passes a second (0: every one): :meth:`passes` is true when
    ``1 / rate_hz`` has gone by since the last pass."""

    def __init__(self, rate_hz: float) -> None:
        self.interval_ns = 0 if rate_hz <= 0 else round(1e9 / rate_hz)
        self._last_ns: int | None = None

    def passes(self, now_ns: int) -> bool:
        if self._last_ns is not None and now_ns - self._last_ns < self.interval_ns:
            return False
        self._last_ns = now_ns
        return True


class _Listener(ServerListener):
    """Notes the channels each client is subscribed to (called on the server's thread)."""

    def __init__(self, subscribed: Callable[[int], None]) -> None:
        self._subscribed = subscribed
        self._channels: dict[int, set[int]] = {}

    @property
    def clients(self) -> int:
        """Clients subscribed to at least one channel."""
        return sum(1 for channels in list(self._channels.values()) if channels)

    def on_subscribe(self, client: Client, channel: ChannelView) -> None:
        self._channels.setdefault(client.id, set()).add(channel.id)
        self._subscribed(channel.id)

    def on_unsubscribe(self, client: Client, channel: ChannelView) -> None:
        self._channels.get(client.id, set()).discard(channel.id)


class LiveViewNode(Node):
    """The graph's topics to Foxglove WebSocket clients (see the module's text)."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__('live_view', **kwargs)
        self.parameters = SettingsParameters(self, ViewSettings)
        settings = self.parameters.current
        self.diagnostics = Diagnostics(self)
        self._time = NodeTime(self)
        self._foxglove = foxglove.Context()   # this node's channels and server only
        self._latched: dict[int, tuple[foxglove.Channel, bytes]] = {}
        self._resend: set[int] = set()
        self._lock = threading.Lock()
        self._band = foxglove.Channel(BAND_TOPIC, schema=BAND_SCHEMA, context=self._foxglove)
        for topic, cls in VIEW_TOPICS.items():
            name = msgtype(cls)
            definition, _ = schema(name)
            channel = foxglove.Channel(
                view_topic(topic), message_encoding='cdr', context=self._foxglove,
                schema=foxglove.Schema(name=name, encoding='ros2msg', data=definition.encode()))
            self.create_subscription(cls, topic, self._forwarder(topic, channel),
                                     topic_qos(topic), raw=True)
        self._listener = _Listener(self._subscribed)
        try:
            self.server = foxglove.start_server(
                name=f'turning_force {self.get_namespace()}', host=settings.host,
                port=settings.port, context=self._foxglove, server_listener=self._listener,
                message_backlog_size=BACKLOG_MESSAGES)
        except Exception as exc:   # the SDK raises its own error types (address in use, ...)
            message = (f'{self.get_fully_qualified_name()}: cannot serve on '
                       f'{settings.host}:{settings.port}: {exc}')
            self.get_logger().fatal(message)
            raise ConfigError(message) from exc
        self.url = f'ws://{settings.host}:{self.server.port}'
        self.diagnostics.set_value('url', self.url)
        self.diagnostics.add_provider(lambda: {'clients': str(self._listener.clients)})
        self.create_timer(RESEND_PERIOD_S, timer_callback(self._send_latched))
        self.get_logger().info(f'Foxglove WebSocket server on {self.url}')

    def _forwarder(self, topic: str, channel: foxglove.Channel) -> Callable[[bytes], None]:
        throttle = Throttle(0.0 if topic in EVENT_TOPICS else self.parameters.current.rate_hz)
        latched = topic in LATCHED_TOPICS
        is_command = topic == 'control/feed_command'
        stamp_ns, received, published = (self._time.ns, self.diagnostics.received,
                                          self.diagnostics.published)

        def forward(data: bytes) -> None:
            now = stamp_ns()
            received(topic)
            if not throttle.passes(now):
                return
            if latched:
                with self._lock:
                    self._latched[channel.id()] = (channel, data)
            channel.log(data, log_time=now)
            published(topic)   # forwarded: the rates on /diagnostics
            if is_command:
                self._log_band(data, now)
        return forward

    def _log_band(self, command: bytes, now_ns: int) -> None:
        reference = float(deserialize_message(command, FeedCommand).reference_force_n)
        band = self.parameters.current.allowed_error_n
        self._band.log({'reference_n': reference, 'low_n': reference - band,
                        'high_n': reference + band}, log_time=now_ns)

    def _subscribed(self, channel_id: int) -> None:
        with self._lock:
            if channel_id in self._latched:
                self._resend.add(channel_id)

    def _send_latched(self) -> None:
        """The last message of each latched channel a client subscribed to since the last
        call, again (to every subscriber of it: the protocol has no per-client latching)."""
        with self._lock:
            due = [self._latched[c] for c in self._resend]
            self._resend.clear()
        now = self._time.ns()
        for channel, data in due:
            channel.log(data, log_time=now)

    def destroy_node(self) -> None:
        server = getattr(self, 'server', None)
        if server is not None:
            server.stop()
        node_time = getattr(self, '_time', None)
        if node_time is not None:
            node_time.close()
        super().destroy_node()


main = node_main(LiveViewNode)


if __name__ == '__main__':
    sys.exit(main())
