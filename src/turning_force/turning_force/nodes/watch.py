"""``watch``: the latest of the graph's topics, kept for a terminal view (``turning-force
watch``, :mod:`turning_force.commands.live`).

Subscribes to the force estimate, the reference (latched), the feed command, the override
applied, the simulator's true force where there is one, the cut log and ``/diagnostics``, and
keeps the last of each, the recent forces and how many came, in :class:`LiveState`. It holds no
algorithm and publishes nothing but its own ``/diagnostics``.
"""

from __future__ import annotations

import time
from collections import deque
from dataclasses import dataclass, field
from typing import Any

from diagnostic_msgs.msg import DiagnosticStatus
from rclpy.node import Node
from std_msgs.msg import Float64
from turning_force_msgs.msg import (
    CutRecord,
    CuttingState,
    FeedCommand,
    FeedOverride,
    ForceEstimate,
)

from turning_force.nodes.session_recorder import GRAPH_TOPICS, topic_qos

__all__ = ['HISTORY', 'WATCHED_TOPICS', 'LiveState', 'WatchNode']

WATCHED_TOPICS: dict[str, type] = {topic: GRAPH_TOPICS[topic] for topic in (
    'force/estimate', 'force/reference', 'control/feed_command', 'pmc/feed_override',
    'sim/cutting_state', 'pmc/cuts', '/diagnostics')}
HISTORY = 200   # force estimates kept for the trace (2 s at 10 ms)


@dataclass
class LiveState:
    """The last message of each watched topic (None: none yet), the recent forces [N], the
    number of messages per topic, the last status of each node on ``/diagnostics`` and the
    monotonic time [s] of the last message of each topic."""

    estimate: ForceEstimate | None = None
    reference_n: float | None = None   # the last on force/reference, where one is published
    command: FeedCommand | None = None
    override: FeedOverride | None = None
    truth: CuttingState | None = None
    cut: CutRecord | None = None
    statuses: dict[str, DiagnosticStatus] = field(default_factory=dict)
    forces_n: deque[float] = field(default_factory=lambda: deque(maxlen=HISTORY))
    counts: dict[str, int] = field(default_factory=lambda: dict.fromkeys(WATCHED_TOPICS, 0))
    last_s: dict[str, float] = field(default_factory=dict)

    @property
    def reference_in_force_n(self) -> float | None:
        """The reference the controller regulates to (its feed command says), else the last
        one on ``force/reference``."""
        return self.command.reference_force_n if self.command is not None else self.reference_n


class WatchNode(Node):
    """Keeps :attr:`state` up to date with the graph's topics (see the module's text)."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__('watch', **kwargs)
        self.state = LiveState()
        for topic, cls in WATCHED_TOPICS.items():
            self.create_subscription(cls, topic, self._keeper(topic), topic_qos(topic))

    def _keeper(self, topic: str) -> Any:
        state = self.state
        prefix = self.get_namespace().rstrip('/') + '/'

        def keep(msg: Any) -> None:
            state.counts[topic] += 1
            state.last_s[topic] = time.monotonic()
            if isinstance(msg, ForceEstimate):
                state.estimate = msg
                state.forces_n.append(msg.force_n)
            elif isinstance(msg, Float64):
                state.reference_n = msg.data
            elif isinstance(msg, FeedCommand):
                state.command = msg
            elif isinstance(msg, FeedOverride):
                state.override = msg
            elif isinstance(msg, CuttingState):
                state.truth = msg
            elif isinstance(msg, CutRecord):
                state.cut = msg
            else:   # /diagnostics is global: the statuses of this graph's nodes only
                for status in msg.status:
                    if status.name.startswith(prefix):
                        state.statuses[status.name] = status
        return keep
