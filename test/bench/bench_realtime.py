"""The real-time graph's block-to-override latency, as lathe_sim publishes it on /diagnostics.

Runs Park 1998 Fig. 8's graph on the wall clock at 100 Hz for a set time, and reads lathe_sim's
status (``answer_latency_p50_ms``, ``answer_latency_p99_ms``, ``answer_latency_max_ms``,
``missed_periods``, ``missed_periods_total``; a 10 s window) once a second:

- one process: ``turning_force_graph`` (simulator, estimator, controller, PMC bridge, recorder
  on one EventsExecutor), and the same on the SingleThreadedExecutor (the old path,
  ``TURNING_FORCE_EXECUTOR=single``);
- across processes: ``lathe_sim``, ``force_estimator``, ``force_controller``, ``pmc_bridge``
  and ``session_recorder`` each in its own process, as ``ros2 run`` starts them;
- the same two under SCHED_FIFO priority 50 (``TURNING_FORCE_RT_PRIORITY``), where this
  machine grants it (CAP_SYS_NICE).

The first ``--warmup`` seconds (discovery, the kernel loading) are left out. Printed per graph:
the median of the windows' p50, the worst window's p99, the largest latency, the periods
missed after the warm-up, and the blocks the simulator's wall timer put out per second.
Measures; asserts nothing.
Run: ``.venv/bin/python test/bench/bench_realtime.py [--seconds 60 | --minutes 10]
[--only one|single|split|one-rt|split-rt]``.
"""

from __future__ import annotations

import argparse
import os
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.context import Context
from rclpy.node import Node

from turning_force.nodes.spin import EXECUTOR_ENV, RT_PRIORITY_ENV, make_executor

FIG8 = Path(__file__).resolve().parents[2] / 'config' / 'experiments' / 'park1998_fig8.yaml'
BIN = Path(sys.prefix) / 'bin'
# Fig. 8's cut (its depth steps at 4 and 8 s, then 3 mm), for as long as the bench runs.
SESSION = """/**/pmc_bridge:
  ros__parameters: {{armed: true}}
/**/session_recorder:
  ros__parameters: {{output_dir: {bag}}}
"""
SPLIT = ('lathe_sim', 'force_estimator', 'force_controller', 'pmc_bridge', 'session_recorder')


def start(executable: str, namespace: str, params: list[Path],
          env: dict[str, str]) -> subprocess.Popen[bytes]:
    files = [a for p in params for a in ('--params-file', str(p))]
    return subprocess.Popen([str(BIN / executable), '--ros-args', *files,
                             '-r', f'__ns:={namespace}'],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=env)


def stop(process: subprocess.Popen[bytes]) -> None:
    process.send_signal(signal.SIGINT)
    try:
        process.wait(timeout=30)
    except subprocess.TimeoutExpired:
        process.kill()
        process.wait()


def measure(label: str, executables: list[str], seconds: float, warmup_s: float,
            executor: str = 'events') -> dict[str, Any]:
    """Start the graph, read lathe_sim's reports for ``seconds`` after ``warmup_s``."""
    namespace = f'/bench_rt_{os.getpid()}_{"".join(c for c in label if c.isalnum())}'
    reports: list[dict[str, str]] = []
    with tempfile.TemporaryDirectory() as tmp:
        session = Path(tmp) / 'session.yaml'
        session.write_text(SESSION.format(bag=Path(tmp) / 'bag'))
        env = {**os.environ, EXECUTOR_ENV: executor}
        if 'SCHED_FIFO' in label:
            env[RT_PRIORITY_ENV] = '50'
        processes = [start(exe, namespace, [FIG8, session], env) for exe in executables]
        context = Context()
        rclpy.init(context=context)
        spin = make_executor(context, 'events')
        try:
            node = Node('bench_realtime', context=context)
            spin.add_node(node)
            wanted = f'{namespace}/lathe_sim'

            def on(msg: DiagnosticArray) -> None:
                reports.extend({v.key: v.value for v in s.values} | {'_t': str(time.monotonic())}
                               for s in msg.status if s.name == wanted)

            node.create_subscription(DiagnosticArray, '/diagnostics', on, 50)
            deadline = time.monotonic() + 120.0   # start-up: discovery, imports
            while not any(r.get('answered_blocks', '0') != '0' for r in reports):
                if time.monotonic() > deadline or any(p.poll() is not None for p in processes):
                    raise RuntimeError(f'{label}: the graph never answered a block')
                spin.spin_once(timeout_sec=0.1)
            begin = time.monotonic() + warmup_s
            end = begin + seconds
            while time.monotonic() < end:
                spin.spin_once(timeout_sec=0.1)
        finally:
            spin.shutdown()
            rclpy.try_shutdown(context=context)
            for process in processes:
                stop(process)
    kept = [r for r in reports if float(r['_t']) >= begin and 'answer_latency_p50_ms' in r]
    first = [r for r in reports if float(r['_t']) < begin and 'missed_periods_total' in r]
    missed_before = int(first[-1]['missed_periods_total']) if first else 0
    return {
        'label': label,
        'p50': statistics.median(float(r['answer_latency_p50_ms']) for r in kept),
        'p99': max(float(r['answer_latency_p99_ms']) for r in kept),
        'max': max(float(r['answer_latency_max_ms']) for r in kept),
        'missed': int(kept[-1]['missed_periods_total']) - missed_before,
        'rate': statistics.median(float(r['out servo/currents rate_hz']) for r in kept),
        'blocks': round(seconds * 100),
    }


def fifo_granted() -> bool:
    """Whether a process here may take SCHED_FIFO (tried in a child, not in this one)."""
    probe = 'import os; os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(1))'
    return subprocess.run([sys.executable, '-c', probe], capture_output=True,
                          check=False).returncode == 0


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--seconds', type=float, default=60.0)
    parser.add_argument('--minutes', type=float, default=None, help='the soak: e.g. 10')
    parser.add_argument('--warmup', type=float, default=10.0, help='seconds left out first')
    parser.add_argument('--only', choices=('one', 'single', 'split', 'one-rt', 'split-rt'),
                        default=None)
    args = parser.parse_args()
    seconds = args.minutes * 60.0 if args.minutes is not None else args.seconds
    runs = {
        'one': ('one process, EventsExecutor', ['turning_force_graph'], 'events'),
        'single': ('one process, SingleThreaded (old)', ['turning_force_graph'], 'single'),
        'split': ('five processes, EventsExecutor', list(SPLIT), 'events'),
        'one-rt': ('one process, SCHED_FIFO 50', ['turning_force_graph'], 'events'),
        'split-rt': ('five processes, SCHED_FIFO 50', list(SPLIT), 'events'),
    }
    chosen = [args.only] if args.only else list(runs)
    if not args.only and not fifo_granted():
        chosen = [k for k in chosen if not k.endswith('-rt')]
        print('SCHED_FIFO not granted here (no CAP_SYS_NICE): the -rt graphs left out',
              file=sys.stderr)
    results = []
    for key in chosen:
        label, executables, executor = runs[key]
        results.append(measure(label, executables, seconds, args.warmup, executor))
        print(f'... {label} done', file=sys.stderr, flush=True)
    print(f'fig8 graph at 100 Hz on the wall clock, {seconds:g} s after {args.warmup:g} s of '
          'warm-up; lathe_sim /diagnostics (10 s windows)')
    print(f'{"graph":36s} {"p50 ms":>8s} {"p99 ms":>8s} {"max ms":>8s} {"missed":>12s} '
          f'{"blocks/s":>9s}')
    for r in results:
        print(f'{r["label"]:36s} {r["p50"]:8.3f} {r["p99"]:8.3f} {r["max"]:8.3f} '
              f'{r["missed"]:6d}/{r["blocks"]:<5d} {r["rate"]:9.1f}')
    print('p50: median of the windows; p99: the worst window; missed: blocks whose override '
          'had not come when the next block went out')
    return 0


if __name__ == '__main__':
    sys.exit(main())
