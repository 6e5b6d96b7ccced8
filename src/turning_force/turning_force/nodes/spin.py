"""The few lines every node's ``main`` shares: init, spin, and a clean stop on SIGINT/SIGTERM.

rclpy's own signal handler shuts the context down under the executor's feet (which then raises
from inside ``spin``); here the signal only asks the loop to stop, and the nodes are destroyed
while the context is still valid, so that a recorder closes its session properly.
"""

from __future__ import annotations

import gc
import inspect
import os
import signal
import sys
import time
from collections.abc import Callable, Sequence
from types import FrameType
from typing import Any

import rclpy
from rclpy.clock import JumpHandle, JumpThreshold, ROSClock
from rclpy.context import Context
from rclpy.duration import Duration
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.signals import SignalHandlerOptions

from turning_force.core import kernel
from turning_force.core.errors import ConfigError, TurningForceError

# The history of every streaming topic, publishers' and subscribers' alike: a second of blocks at
# 10 ms. Fast DDS's reliable KEEP_LAST writer drops its oldest sample, acknowledged or not, once
# `depth` newer ones are out: at 10 a reader in another process (the live view on a busy 2-core
# PC) that falls 100 ms behind lost messages the recorder got.
STREAM_DEPTH = 100

__all__ = ['EXECUTOR_ENV', 'MAX_DOMAIN_ID', 'RT_PRIORITY_ENV', 'STREAM_DEPTH', 'NodeTime',
           'check_domain_id', 'freeze_heap', 'make_executor', 'node_main', 'real_time_priority',
           'run_nodes', 'timer_callback']

# ``TURNING_FORCE_EXECUTOR=single`` runs ``ros2 run`` nodes on rclpy's SingleThreadedExecutor
# instead of its EventsExecutor (ten times the message rate here; see ROS2_FROM_PYPI.md).
EXECUTOR_ENV = 'TURNING_FORCE_EXECUTOR'
# ``TURNING_FORCE_RT_PRIORITY=N`` (1-99) runs a node's process under the SCHED_FIFO real-time
# policy at priority N, DDS threads included: on a machine PC that also does other work, the
# control loop is then not queued behind it. (The recorder's writer thread inherits it: at a
# lower priority it would hold the interpreter lock while preempted, and stall the loop.)
RT_PRIORITY_ENV = 'TURNING_FORCE_RT_PRIORITY'

# The largest domain Fast DDS can map to UDP ports (port base 7400, domain gain 250).
MAX_DOMAIN_ID = 232


def check_domain_id() -> None:
    """Refuse a ``ROS_DOMAIN_ID`` that rcl or the middleware would die on, in one line."""
    text = os.environ.get('ROS_DOMAIN_ID', '').strip()
    if not text:
        return
    if not (text.isdigit() and int(text) <= MAX_DOMAIN_ID):
        raise ConfigError(f'ROS_DOMAIN_ID={text!r}: expected an integer from 0 to '
                          f'{MAX_DOMAIN_ID}')


class NodeTime:
    """A node's clock, read without a clock call per message.

    In sim time the clock moves only when ``/clock`` sets it: its jump callback marks the time
    out of date and the next read takes it once. Otherwise the ROS clock is the system clock,
    which ``time.time_ns`` reads for a fraction of ``Clock.now``'s cost. The same values as
    ``node.get_clock().now().nanoseconds``, switching over when sim time is turned on or off.

    ``steady``: off sim time, the monotonic clock instead, anchored once to the system clock
    (so stamps still read as dates) and never stepped with it: a watchdog, timeout or rate
    limit on this clock cannot be blinded or tripped by NTP or an operator setting the date.
    """

    def __init__(self, node: Node, steady: bool = False) -> None:
        self._steady = steady
        self._anchor_ns = time.time_ns() - time.monotonic_ns() if steady else 0
        self._clock = node.get_clock()
        self._moved = True
        self._wall = True
        self._ns = 0
        self._handle: JumpHandle | None = self._clock.create_jump_callback(
            JumpThreshold(min_forward=Duration(nanoseconds=1),
                          min_backward=Duration(nanoseconds=-1), on_clock_change=True),
            pre_callback=self._on_jump)

    def _on_jump(self) -> None:
        self._moved = True

    def ns(self) -> int:
        """Now, on the node's clock [ns]."""
        if self._moved:
            self._moved = False
            self._wall = not (isinstance(self._clock, ROSClock) and self._clock.ros_time_is_active)
            self._ns = self._clock.now().nanoseconds
        if not self._wall:
            return self._ns
        return time.monotonic_ns() + self._anchor_ns if self._steady else time.time_ns()

    def close(self) -> None:
        if self._handle is not None:
            self._handle.unregister()
            self._handle = None


def make_executor(context: Context | None = None, kind: str = 'events') -> Any:
    """rclpy's EventsExecutor (``events``), or the SingleThreadedExecutor (``single``, and
    where this rclpy has no EventsExecutor)."""
    if kind == 'events':
        try:
            from rclpy.experimental import EventsExecutor  # type: ignore[attr-defined]
        except ImportError:  # an rclpy without it: the standard executor, slower
            return SingleThreadedExecutor(context=context)
        return EventsExecutor(context=context)
    if kind != 'single':
        raise ConfigError(f'executor {kind!r}: expected events or single')
    return SingleThreadedExecutor(context=context)


def real_time_priority() -> str:
    """Put this thread (and the threads it starts after) under SCHED_FIFO at the priority
    ``TURNING_FORCE_RT_PRIORITY`` gives; '' when done or not asked, else why not."""
    text = os.environ.get(RT_PRIORITY_ENV, '').strip()
    if not text:
        return ''
    if not (text.isdigit() and 1 <= int(text) <= 99):
        raise ConfigError(f'{RT_PRIORITY_ENV}={text!r}: expected a priority from 1 to 99')
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(int(text)))
    except (OSError, AttributeError) as exc:   # no CAP_SYS_NICE, or not Linux
        return f'{RT_PRIORITY_ENV}={text}: not granted ({exc}); running at normal priority'
    return ''


def timer_callback(callback: Callable[[], object]) -> Callable[[], None]:
    """``callback`` for ``create_timer``, its signature given in advance: rclpy's
    EventsExecutor looks for a ``TimerInfo`` parameter with ``inspect.signature`` at every
    call of a timer (tens of microseconds; a bound method cannot carry the answer)."""
    def call() -> None:
        callback()
    call.__signature__ = inspect.Signature()  # type: ignore[attr-defined]
    return call


def freeze_heap() -> None:
    """Collect once, then keep what start-up made out of the garbage collector's scans.

    Start-up (numpy, scipy, rclpy, numba's kernel) leaves hundreds of thousands of objects
    that live as long as the process; a full collection walks them all (hundreds of ms seen
    here, inside a control period). Frozen, they are never walked again; what the nodes make
    while running is collected as before.
    """
    gc.collect()
    gc.freeze()


def node_main(node: Callable[[], Node]) -> Callable[..., int]:
    """A node's console entry point: ``main(args)`` spins the one node ``node()`` makes."""
    def main(args: Sequence[str] | None = None) -> int:
        return run_nodes(lambda: [node()], args)
    return main


def run_nodes(make: Callable[[], list[Node]], args: Sequence[str] | None = None) -> int:
    """Create the nodes ``make`` returns and spin them on one executor until signalled."""
    try:
        check_domain_id()
        refused = real_time_priority()   # before rclpy.init: DDS's threads inherit it
    except ConfigError as exc:
        print(f'turning_force: {exc}', file=sys.stderr)
        return 2
    if refused:
        print(f'turning_force: warning: {refused}', file=sys.stderr)
    rclpy.init(args=list(args) if args is not None else None,
               signal_handler_options=SignalHandlerOptions.NO)
    try:
        executor = make_executor(kind=os.environ.get(EXECUTOR_ENV, 'events').strip() or 'events')
    except ConfigError as exc:
        print(f'turning_force: {EXECUTOR_ENV}: {exc}', file=sys.stderr)
        rclpy.try_shutdown()
        return 2
    stop = False

    def request_stop(signum: int, frame: FrameType | None) -> None:
        nonlocal stop
        stop = True

    previous = {s: signal.signal(s, request_stop) for s in (signal.SIGINT, signal.SIGTERM)}
    nodes: list[Node] = []
    try:
        try:
            nodes = make()
        except TurningForceError as exc:   # logged by the node; no traceback for bad input
            print(f'turning_force: {exc}', file=sys.stderr)
            return 2
        for node in nodes:
            executor.add_node(node)
        freeze_heap()   # what start-up made is never scanned again
        kernel_frozen = False
        while not stop and rclpy.ok():
            executor.spin_once(timeout_sec=0.1)
            if not kernel_frozen and kernel.loaded() is not None:
                gc.freeze()   # the kernel, loaded in the background: as long-lived
                kernel_frozen = True
    finally:
        for node in nodes:
            executor.remove_node(node)
            node.destroy_node()
        executor.shutdown()
        rclpy.try_shutdown()
        for signum, handler in previous.items():
            signal.signal(signum, handler)
    return 0
