"""The graph's executables started as the machine PC starts them (``ros2 run``'s executables
from the venv), stopped with SIGINT as an operator does, and the all-in-one graph recorded
while it regulates: for the wall-clock tests (test/nodes/test_graph_realtime.py,
test/session/test_report_handover.py) and the live views that join the graph
(test/nodes/test_live_view.py)."""

from __future__ import annotations

import signal
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

from rclpy.node import Node
from turning_force_msgs.msg import FeedOverride

BIN = Path(sys.prefix) / 'bin'


def start(executable: str, namespace: str, params: Path, *extra: str) -> subprocess.Popen[str]:
    """``executable --ros-args --params-file params -r __ns:=namespace extra...``, its output
    (stdout and stderr) on one pipe."""
    return subprocess.Popen(
        [str(BIN / executable), '--ros-args', '--params-file', str(params),
         '-r', f'__ns:={namespace}', *extra],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)


def stop(process: subprocess.Popen[str]) -> str:
    """SIGINT, as Ctrl-C does; its output once it has exited, cleanly (asserted)."""
    process.send_signal(signal.SIGINT)
    output, _ = process.communicate(timeout=30)
    assert process.returncode == 0, output
    return output


def session_params(path: Path, bag: Path, recorder: str = '', arm: bool = True) -> Path:
    """A params file that records to ``bag`` and, with ``arm``, arms the bridge (node-scoped
    values, as on the lathe PC; ``recorder``: more entries of the recorder's section), written
    to ``path``."""
    path.write_text(('/**/pmc_bridge:\n  ros__parameters: {armed: true}\n' if arm else '')
                    + f'/**/session_recorder:\n  ros__parameters: {{output_dir: {bag}'
                    f'{", " + recorder if recorder else ""}}}\n')
    return path


def record_regulated(context: Any, executor: Any, spin_until: Callable[..., bool],
                     experiment: Path, bag: Path, namespace: str, blocks: int,
                     recorder: str = '', arm: bool = True) -> None:
    """``turning_force_graph`` on ``experiment``, recording to ``bag`` (plus the
    ``recorder`` entries of its section, e.g. ``experiment_file: ...``), until ``blocks``
    overrides were written for the regulated reason; then stopped. ``arm``: armed by the params
    file (else as the experiment file says)."""
    params = session_params(bag.parent / f'{bag.name}_session.yaml', bag, recorder, arm)
    graph = start('turning_force_graph', namespace, experiment, '--params-file', str(params))
    try:
        probe = Node('probe', context=context)
        executor.add_node(probe)
        normal: list[FeedOverride] = []
        probe.create_subscription(
            FeedOverride, f'{namespace}/pmc/feed_override',
            lambda m: normal.append(m) if m.reason == FeedOverride.REASON_NORMAL else None, 10)
        assert spin_until(lambda: len(normal) >= blocks, 60.0)
    finally:
        stop(graph)
