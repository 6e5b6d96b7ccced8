"""In-process ROS fixtures for test/nodes, test/session and test/cli: an own Context per test,
spun with deadlines, torn down in order. rclpy is imported inside the fixtures, so that
test/core, which never touches ROS, does not load it."""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from typing import Any

import pytest


@pytest.fixture
def context() -> Iterator[Any]:
    import rclpy
    from rclpy.context import Context

    ctx = Context()
    rclpy.init(context=ctx)
    try:
        yield ctx
    finally:
        rclpy.try_shutdown(context=ctx)


@pytest.fixture
def executor(context: Any) -> Iterator[Any]:
    from rclpy.executors import SingleThreadedExecutor

    ex = SingleThreadedExecutor(context=context)
    try:
        yield ex
    finally:
        for node in list(ex.get_nodes()):
            ex.remove_node(node)
            node.destroy_node()
        ex.shutdown()


@pytest.fixture
def spin_until(executor: Any) -> Callable[..., bool]:
    """``spin_until(condition, timeout_s=10)``: spin until ``condition()`` holds or the deadline
    passes; returns whether it held. No sleeps: the executor waits on its own events."""

    def spin(condition: Callable[[], bool], timeout_s: float = 10.0) -> bool:
        deadline = time.monotonic() + timeout_s
        while not condition():
            if time.monotonic() > deadline:
                return False
            executor.spin_once(timeout_sec=0.05)
        return True

    return spin
