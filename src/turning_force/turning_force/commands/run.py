"""``turning-force run``: the node graph on the simulator, in lock-step, recorded.

One process, one executor (rclpy's EventsExecutor). ``lathe_sim`` owns ``/clock``: each step it
advances sim time one control period and publishes a block of currents; the runner then spins
the graph until the override answering that block (matched by stamp) has reached the simulator,
and only then steps again. The nodes share one subscription to ``/clock`` (lathe_sim's time
source sets every node's clock), not one each, and the recorder writes on its own thread. The
graph's order of work is therefore fixed, and a run is deterministic for a given file and seed,
and as fast as the CPU allows.

``pmc_bridge`` is a lifecycle node: the runner configures and activates it once the graph
exists, and deactivates and cleans it up at the end. A machine file whose module is on
127.0.0.1 (``pmc_bridge.machine_file``) runs through a simulated PMC on Modbus/TCP: the bridge
writes the coils, the simulator reads them, with the metrics of the simulated backend.

A run is a world of its own: its context's DDS participant is made with automatic discovery
``OFF`` (``ROS_AUTOMATIC_DISCOVERY_RANGE``, no static peers), so it discovers no other process
and no other process discovers it, on any ``ROS_DOMAIN_ID``; the nodes inside it talk through
the one participant they share. Simulated currents can never reach a machine's graph, and
another run's overrides never reach this simulator. As a second line, the run looks at who is on
its topics, before the first step and every ``FOREIGN_CHECK_STEPS`` steps, and stops with the
topic and the node when anyone but its own nodes is there (an RMW that ignores the setting).
"""

from __future__ import annotations

import gc
import os
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import rclpy
from rclpy.context import Context
from rclpy.node import Node
from rclpy.parameter import Parameter

from turning_force.core.errors import TurningForceError
from turning_force.core.experiment import Experiment
from turning_force.io.pmc_server import simulated_parameters
from turning_force.nodes.force_controller import ForceControllerNode
from turning_force.nodes.force_estimator import ForceEstimatorNode
from turning_force.nodes.lathe_sim import LatheSimNode
from turning_force.nodes.pmc_bridge import PmcBridgeNode
from turning_force.nodes.session_recorder import GRAPH_TOPICS, SessionRecorderNode
from turning_force.nodes.spin import check_domain_id, freeze_heap, make_executor
from turning_force.session.bag import CUSTOM_PARAMETERS, CUSTOM_PLANNED, dumps, stopped_by

__all__ = ['RunError', 'RunOutcome', 'foreign_endpoints', 'isolated_context', 'run_lockstep',
           'share_clock']

# How long the graph may take to answer one block before the run is declared broken [wall s].
ANSWER_TIMEOUT_S = 5.0
# Steps between two looks for endpoints of other processes on the run's topics.
FOREIGN_CHECK_STEPS = 100
# What rcl reads at init to set up discovery; the run sets its own and restores these after.
DISCOVERY_VARIABLES = ('ROS_AUTOMATIC_DISCOVERY_RANGE', 'ROS_STATIC_PEERS', 'ROS_LOCALHOST_ONLY')


class RunError(TurningForceError):
    """The graph stopped answering during a lock-step run."""


@dataclass(frozen=True)
class RunOutcome:
    """What a lock-step run did: the session, how many steps, how fast."""

    bag: Path
    steps: int
    sim_s: float
    wall_s: float
    executor: str

    @property
    def realtime_factor(self) -> float:
        """Simulated seconds per wall second (the graph's steps only, not its start-up)."""
        return 0.0 if self.wall_s <= 0 else self.sim_s / self.wall_s


def isolated_context() -> Context:
    """An initialised context whose participant neither discovers nor is discovered.

    rcl reads the discovery settings from the environment once, in ``rclpy.init``; they are
    set to ``OFF`` without static peers for that call only, so that whatever this process does
    afterwards (``replay --publish`` into a live graph) keeps the user's settings.
    """
    check_domain_id()
    saved = {name: os.environ.get(name) for name in DISCOVERY_VARIABLES}
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'OFF'
    os.environ.pop('ROS_STATIC_PEERS', None)
    os.environ.pop('ROS_LOCALHOST_ONLY', None)
    context = Context()
    try:
        rclpy.init(context=context)
    finally:
        for name, value in saved.items():
            if value is None:
                os.environ.pop(name, None)
            else:
                os.environ[name] = value
    return context


def foreign_endpoints(node: Node, own: set[str], topics: list[str]) -> list[str]:
    """Publishers and subscriptions on ``topics`` of nodes not in ``own`` (fully qualified
    names), as ``'topic: publisher /ns/node'`` lines; empty when only ``own`` is there."""
    found = []
    for topic in topics:
        name = node.resolve_topic_name(topic)
        for role, infos in (('publisher', node.get_publishers_info_by_topic(name)),
                            ('subscription', node.get_subscriptions_info_by_topic(name))):
            for info in infos:
                who = f'{info.node_namespace.rstrip("/")}/{info.node_name}'
                if who not in own:
                    found.append(f'{name}: {role} {who}')
    return found


def _refuse_foreign(node: Node, own: set[str], topics: list[str]) -> None:
    found = foreign_endpoints(node, own, topics)
    if found:
        raise RunError(f'{found[0]} is not part of this run: another graph is on '
                       f'ROS_DOMAIN_ID {node.context.get_domain_id()}; refusing to run')


def _overrides(params: dict[str, Any], **extra: Any) -> list[Parameter[Any]]:
    values = {**params, **extra, 'use_sim_time': True}
    return [Parameter(name, value=value) for name, value in values.items()]


def share_clock(source: Node, nodes: list[Node]) -> bool:
    """Drive every node's clock from ``source``'s time source: one ``/clock`` subscription
    (and one callback per step) for the graph instead of one per node. The nodes keep
    ``use_sim_time``; their own subscriptions go. False (nothing changed) with an rclpy whose
    nodes keep their time source elsewhere."""
    shared = getattr(source, '_time_source', None)   # rclpy has no public accessor for it
    others = [node for node in nodes if node is not source]
    owned = [getattr(node, '_time_source', None) for node in others]
    if shared is None or None in owned:
        return False
    for node, own in zip(others, owned, strict=True):
        assert own is not None
        own.detach_node()   # its /clock subscription goes
        shared.attach_clock(node.get_clock())
    return True


def run_lockstep(experiment: Experiment, out_dir: Path,
                 progress: Callable[[int, int], None] | None = None,
                 executor_kind: str = 'events', fast: bool = True) -> RunOutcome:
    """Run ``experiment`` through the graph in lock-step; record it to ``out_dir``.

    ``executor_kind``: ``events`` (rclpy's EventsExecutor, about ten times faster here) or
    ``single`` (the SingleThreadedExecutor, for comparison). ``fast`` false runs the graph as
    it was before issue 9 where that path still exists (every node on its own ``/clock``
    subscription, the recorder writing on the executor's thread), for the benchmark.
    """
    context = isolated_context()
    resolved, pmc = simulated_parameters(experiment)
    nodes: list[Node] = []
    executor = make_executor(context, executor_kind)
    try:
        pmc.start()
        sim = LatheSimNode(lockstep=True, context=context, parameter_overrides=_overrides(
            resolved['lathe_sim'], publish_clock=True, **pmc.parameters))
        steps = round(experiment.run.duration_s / experiment.run.control_period_s)
        recorder = SessionRecorderNode(
            background=fast, context=context, parameter_overrides=_overrides(
                {}, output_dir=str(out_dir), experiment_file=experiment.source,
                capture_parameters=False),
            custom_data={CUSTOM_PARAMETERS: dumps(resolved), CUSTOM_PLANNED: str(steps)})
        bridge = PmcBridgeNode(autostart=False, context=context, parameter_overrides=_overrides(
            resolved['pmc_bridge']))
        nodes = [
            sim,
            ForceEstimatorNode(context=context, parameter_overrides=_overrides(
                resolved['force_estimator'])),
            ForceControllerNode(context=context, parameter_overrides=_overrides(
                resolved['force_controller'])),
            bridge,
            recorder,
        ]
        if fast:
            share_clock(sim, nodes)
        for node in nodes:
            executor.add_node(node)
        bridge.start()   # configure (machine file, module) and activate
        own = {node.get_fully_qualified_name() for node in nodes}
        topics = [*GRAPH_TOPICS, '/clock']
        _refuse_foreign(sim, own, topics)
        if fast:
            freeze_heap()   # start-up's objects out of the collector's scans while stepping
        start = time.perf_counter()
        done = 0
        try:
            for k in range(steps):
                if k and k % FOREIGN_CHECK_STEPS == 0:
                    _refuse_foreign(sim, own, topics)
                block = sim.step()
                answered = sim.answer(block)
                executor.spin_until_future_complete(answered, timeout_sec=ANSWER_TIMEOUT_S)
                if recorder.failure is not None:   # the disk is full: stop, say it once
                    raise recorder.failure
                if not answered.done():
                    raise RunError(f'step {k}: no override answered the block of '
                                   f'{block.currents.t0_s:.3f} s within {ANSWER_TIMEOUT_S} s')
                done = k + 1
                if progress is not None:
                    progress(k + 1, steps)
        except BaseException as exc:   # a signal, an error: the session says it ended early
            try:
                if isinstance(exc, KeyboardInterrupt) or hasattr(exc, 'signal_name'):
                    _drain(executor, recorder, bridge, done)   # the blocks that ran, whole
            finally:
                recorder.end(stopped_by(exc))
            raise
        _drain(executor, recorder, bridge, steps)
        wall = time.perf_counter() - start
        _refuse_foreign(sim, own, topics)
        recorder.close()
        return RunOutcome(out_dir, steps, steps * experiment.run.control_period_s, wall,
                          type(executor).__name__)
    finally:
        for node in nodes:
            executor.remove_node(node)
            node.destroy_node()   # the bridge deactivates and cleans up first
        executor.shutdown()
        rclpy.try_shutdown(context=context)
        pmc.stop()
        gc.unfreeze()   # collectable again once the run is over (many runs in one process)


def _drain(executor: Any, recorder: SessionRecorderNode, bridge: PmcBridgeNode,
           blocks: int) -> None:
    """Let the recorder take the messages of the first ``blocks`` blocks (within
    ``ANSWER_TIMEOUT_S``) before the session is closed."""
    expected = {'pmc/feed_override': bridge.diagnostics.published_count('pmc/feed_override'),
                'control/feed_command': blocks, 'force/estimate': blocks,
                'servo/currents': blocks, 'sim/cutting_state': blocks}
    deadline = time.monotonic() + ANSWER_TIMEOUT_S
    while (any(recorder.writer.counts[recorder.resolve_topic_name(t)] < n
               for t, n in expected.items()) and time.monotonic() < deadline):
        executor.spin_once(timeout_sec=0.1)


def print_progress(done: int, total: int) -> None:
    """A one-line progress bar on stderr, when stderr is a terminal."""
    if not sys.stderr.isatty():
        return
    if done == total or done % max(total // 50, 1) == 0:
        filled = 40 * done // total
        sys.stderr.write(f'\r[{"#" * filled}{"." * (40 - filled)}] {done}/{total}')
        if done == total:
            sys.stderr.write('\n')
        sys.stderr.flush()
