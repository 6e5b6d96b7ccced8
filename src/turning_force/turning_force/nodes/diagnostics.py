"""``/diagnostics`` for every node: message rates, staleness and errors, once a second; and
:class:`AnswerLatency`, the real-time loop's block-to-override latency."""

from __future__ import annotations

import math
from collections import defaultdict, deque
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.node import Node

from turning_force.nodes.spin import timer_callback

__all__ = ['LATENCY_KEYS', 'AnswerLatency', 'Diagnostics']

# The keys :class:`AnswerLatency` reports on /diagnostics (lathe_sim's status).
LATENCY_KEYS = ('answer_latency_p50_ms', 'answer_latency_p99_ms', 'answer_latency_max_ms',
                'answered_blocks', 'missed_periods', 'missed_periods_total', 'latency_window_s')


@dataclass
class _Topic:
    count: int = 0
    total: int = 0     # count when last_s was taken
    reported: int = 0  # count at the last report
    last_s: float | None = None
    stale_after_s: float = 0.0  # 0: staleness not judged


class Diagnostics:
    """Counts what a node receives and publishes, remembers its errors, reports on a timer.

    The level is ERROR after an error in the last period, WARN when a watched input is stale
    or a warning was noted, OK otherwise. Times are the node's clock (sim time in lock-step).
    Counting is on every message's path, so it only counts: the time of the last message is
    taken when the report or a staleness check sees the count has moved, which makes ages
    exact to one report period at worst, and costs no clock read per message.
    """

    def __init__(self, node: Node, period_s: float = 1.0) -> None:
        self._node = node
        self._period_s = period_s
        self._publisher = node.create_publisher(DiagnosticArray, '/diagnostics', 10)
        # By topic; a topic not watched is counted from its first message.
        self._inputs: defaultdict[str, _Topic] = defaultdict(_Topic)
        self._outputs: defaultdict[str, _Topic] = defaultdict(_Topic)
        self._errors = 0
        self._warnings: list[str] = []
        self._error_texts: list[str] = []
        self._values: dict[str, str] = {}
        self._last_report_s: float | None = None  # the clock may not run yet (lock-step)
        self._providers: list[Callable[[], dict[str, str]]] = []
        self._timer = node.create_timer(period_s, timer_callback(self.report))

    def add_provider(self, values: Callable[[], dict[str, str]]) -> None:
        """``values()`` is asked for key/value pairs at each report (it may :meth:`warn`)."""
        self._providers.append(values)

    def _now(self) -> float:
        return self._node.get_clock().now().nanoseconds * 1e-9

    def watch(self, topic: str, stale_after_s: float = 0.0) -> None:
        """Report ``topic``'s rate, and WARN when nothing came for ``stale_after_s``."""
        self._inputs[topic] = _Topic(stale_after_s=stale_after_s)

    def received(self, topic: str) -> None:
        self._inputs[topic].count += 1

    def published(self, topic: str) -> None:
        self._outputs[topic].count += 1

    def received_count(self, topic: str) -> int:
        """Messages received on ``topic`` so far."""
        entry = self._inputs.get(topic)
        return 0 if entry is None else entry.count

    def published_count(self, topic: str) -> int:
        """Messages published on ``topic`` so far."""
        entry = self._outputs.get(topic)
        return 0 if entry is None else entry.count

    def _touch(self, entry: _Topic, now: float) -> None:
        if entry.count != entry.total:
            entry.total = entry.count
            entry.last_s = now

    def warn(self, text: str, log: bool = False) -> None:
        """A warning for the next report (``log``: in the node's log too)."""
        if log:
            self._node.get_logger().warning(text)
        self._warnings.append(text)

    def error(self, text: str, log: bool = False) -> None:
        """An error for the next report (``log``: in the node's log too)."""
        if log:
            self._node.get_logger().error(text)
        self._errors += 1
        self._error_texts.append(text)

    def set_value(self, key: str, value: object) -> None:
        self._values[key] = str(value)

    def stale(self, topic: str) -> bool:
        entry = self._inputs.get(topic)
        if entry is None or entry.stale_after_s <= 0:
            return False
        now = self._now()
        self._touch(entry, now)
        return entry.last_s is None or now - entry.last_s > entry.stale_after_s

    def report(self) -> None:
        for provider in self._providers:
            self._values.update(provider())
        now = self._now()
        if self._last_report_s is None:
            self._last_report_s = now - self._period_s
        elapsed = max(now - self._last_report_s, 1e-9)
        values = [KeyValue(key='errors_total', value=str(self._errors))]
        messages = []
        for direction, table in (('in', self._inputs), ('out', self._outputs)):
            for topic, entry in table.items():
                rate = (entry.count - entry.reported) / elapsed
                entry.reported = entry.count
                self._touch(entry, now)
                values.append(KeyValue(key=f'{direction} {topic} rate_hz', value=f'{rate:.1f}'))
                age = 'never' if entry.last_s is None else f'{now - entry.last_s:.3f}'
                values.append(KeyValue(key=f'{direction} {topic} age_s', value=age))
                if direction == 'in' and self.stale(topic):
                    messages.append(f'{topic} stale ({age} s)')
        values += [KeyValue(key=k, value=v) for k, v in self._values.items()]
        level = DiagnosticStatus.OK
        if messages or self._warnings:
            level = DiagnosticStatus.WARN
        if self._error_texts:
            level = DiagnosticStatus.ERROR
        messages += self._error_texts[-3:] + self._warnings[-3:]
        status = DiagnosticStatus(
            level=level, name=self._node.get_fully_qualified_name(),
            message='; '.join(messages) or 'ok', hardware_id='turning_force', values=values)
        array = DiagnosticArray(status=[status])
        array.header.stamp = self._node.get_clock().now().to_msg()
        self._publisher.publish(array)
        self._error_texts.clear()
        self._warnings.clear()
        self._last_report_s = now


class AnswerLatency:
    """Block published -> the override answering it arrived, per block, over a sliding window.

    The simulator (or a DAQ driver) calls :meth:`published` with the block's answer stamp (its
    last sample's time, which the estimate, command and override answering it carry) just
    before the block goes out, and :meth:`answered` when a ``FeedOverride`` arrives: both ends
    are seen by one node, on one monotonic clock. A block whose answer has not come when the
    next block goes out is a missed period; its answer, if it comes later, still counts in the
    latencies. The window is the last ``window_blocks`` blocks whose period is over (the one
    going on is judged when the next goes out). Blocks before the first answer (the graph
    starting, discovery) are not counted. Costs a dictionary update per block; the
    percentiles are taken once per report.
    """

    # Blocks whose answer may still come late (beyond that: lost).
    LATE_BLOCKS = 8

    def __init__(self, window_blocks: int, period_s: float) -> None:
        self.period_s = period_s
        self.window_blocks = max(int(window_blocks), 1)
        # Per block: [latency ns or -1 while unanswered, missed]; the last is the current one.
        self._window: deque[list[int]] = deque(maxlen=self.window_blocks + 1)
        self._sent: dict[int, tuple[int, list[int]]] = {}   # stamp -> (published at, entry)
        self._started = False
        self.missed_total = 0

    def published(self, stamp_ns: int, now_ns: int) -> None:
        """Block ``stamp_ns`` goes out at ``now_ns`` (monotonic)."""
        if not self._started:
            self._window.clear()
        elif self._window[-1][0] < 0:   # the block before had no answer in its period
            self._window[-1][1] = 1
            self.missed_total += 1
        entry = [-1, 0]
        self._window.append(entry)
        sent = self._sent
        sent[stamp_ns] = (now_ns, entry)
        if len(sent) > self.LATE_BLOCKS:
            del sent[next(iter(sent))]   # the oldest (dicts keep insertion order)

    def answered(self, stamp_ns: int, now_ns: int) -> bool:
        """An override stamped ``stamp_ns`` arrived at ``now_ns``; whether it answers a block."""
        found = self._sent.pop(stamp_ns, None)
        if found is None:
            return False
        sent_ns, entry = found
        self._started = True
        entry[0] = now_ns - sent_ns
        return True

    def values(self) -> dict[str, str]:
        """The window's statistics, as /diagnostics values ([ms], 3 decimals: microseconds)."""
        done = list(self._window)[:-1]   # blocks whose period is over
        latencies = np.array([e[0] for e in done if e[0] >= 0], dtype=np.float64) * 1e-6
        if latencies.size:
            p50, p99 = np.percentile(latencies, (50.0, 99.0))
            peak = float(latencies.max())
        else:
            p50 = p99 = peak = math.nan
        return {'answer_latency_p50_ms': f'{p50:.3f}', 'answer_latency_p99_ms': f'{p99:.3f}',
                'answer_latency_max_ms': f'{peak:.3f}',
                'answered_blocks': str(latencies.size),
                'missed_periods': str(sum(e[1] for e in done)),
                'missed_periods_total': str(self.missed_total),
                'latency_window_s': f'{self.window_blocks * self.period_s:g}'}
