"""Fixtures for every test: the repository's files (experiments, the reference session), and
in-process ROS for test/nodes, test/session and test/cli: an own Context per test, spun with
deadlines, torn down in order. rclpy is imported inside the fixtures, so that test/core, which
never touches ROS, does not load it."""

from __future__ import annotations

import os
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

ROOT = Path(__file__).resolve().parents[1]

# pytest-xdist runs the suite in several processes: each gets a DDS domain of its own (set before
# any test imports rclpy), so that one worker's graph never hears another's. Two suites run at
# once on one machine (two checkouts) keep apart with TURNING_FORCE_TEST_DOMAIN (default 40).
_WORKER = os.environ.get('PYTEST_XDIST_WORKER', '')
if _WORKER.startswith('gw'):
    _BASE = int(os.environ.get('TURNING_FORCE_TEST_DOMAIN', '40'))
    os.environ['ROS_DOMAIN_ID'] = str(_BASE + int(_WORKER[2:]))


@pytest.fixture(scope='session')
def root() -> Path:
    """The repository (msgs/, src/, config/, bags/)."""
    return ROOT


@pytest.fixture(scope='session')
def experiments_dir() -> Path:
    return ROOT / 'config' / 'experiments'


@pytest.fixture(scope='session')
def fig8(experiments_dir: Path) -> Path:
    """Park 1998 Fig. 8's experiment file, the one most tests run."""
    return experiments_dir / 'park1998_fig8.yaml'


@pytest.fixture(scope='session')
def reference_bag() -> Path:
    """The committed reference session of Fig. 8 (1200 blocks)."""
    return ROOT / 'bags' / 'reference' / 'park1998_fig8'


@pytest.fixture(scope='session')
def reference(reference_bag: Path) -> Any:
    """The reference session read once (the session tests compare what they do to it; none
    changes it)."""
    from turning_force.session.reader import read_session

    return read_session(reference_bag)


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


def closing_executor(ex: Any) -> Iterator[Any]:
    """Yield ``ex``; then destroy the nodes added to it and shut it down."""
    try:
        yield ex
    finally:
        for node in list(ex.get_nodes()):
            ex.remove_node(node)
            node.destroy_node()
        ex.shutdown()


@pytest.fixture
def executor(context: Any) -> Iterator[Any]:
    from rclpy.executors import SingleThreadedExecutor

    yield from closing_executor(SingleThreadedExecutor(context=context))


@pytest.fixture
def events(context: Any) -> Iterator[Any]:
    """rclpy's EventsExecutor (as the nodes run) on the test's context."""
    from turning_force.nodes.spin import make_executor

    yield from closing_executor(make_executor(context, 'events'))


def spinner(executor: Any) -> Callable[..., bool]:
    """``spin(condition, timeout_s=10)``: spin ``executor`` until ``condition()`` holds or the
    deadline passes; returns whether it held. No sleeps: the executor waits on its own events."""

    def spin(condition: Callable[[], bool], timeout_s: float = 10.0) -> bool:
        deadline = time.monotonic() + timeout_s
        while not condition():
            if time.monotonic() > deadline:
                return False
            executor.spin_once(timeout_sec=0.05)
        return True

    return spin


@pytest.fixture
def spin_until(executor: Any) -> Callable[..., bool]:
    """:func:`spinner` on the SingleThreadedExecutor fixture."""
    return spinner(executor)


@pytest.fixture
def spin_events_until(events: Any) -> Callable[..., bool]:
    """:func:`spinner` on the EventsExecutor fixture."""
    return spinner(events)


@pytest.fixture(scope='session')
def dask_cluster() -> Iterator[Any]:
    """A Dask cluster of two worker processes on 127.0.0.1 (test/core/test_sweep.py and
    test/cli/test_sweep_cli.py run the sweep and the replay of many sessions on it against the
    local run), started once and closed at the end of the session."""
    from distributed import LocalCluster

    with LocalCluster(host='127.0.0.1', n_workers=2, threads_per_worker=1, processes=True,
                      dashboard_address=None) as cluster:
        yield cluster
