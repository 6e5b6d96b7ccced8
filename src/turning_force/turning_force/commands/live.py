"""``turning-force view`` and ``turning-force watch``: a running graph, live.

``view`` serves the graph's topics to Foxglove or Lichtblick over the Foxglove WebSocket
protocol (:class:`turning_force.nodes.live_view.LiveViewNode`); its first line says where.
``watch`` draws them in the terminal with rich, for a machine PC without a desktop: force vs
reference and the band, the override requested and applied, the gate's state, the alarms, the
last cut and the nodes' health. Both join the graph in ``namespace`` on this process's
``ROS_DOMAIN_ID``; neither publishes anything to it but its own ``/diagnostics``.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from typing import Any

import rclpy
from diagnostic_msgs.msg import DiagnosticStatus
from rclpy.context import Context
from rclpy.parameter import Parameter
from rich.console import Console, Group
from rich.live import Live
from rich.table import Table
from rich.text import Text
from turning_force_msgs.msg import FeedOverride, ForceEstimate

from turning_force.nodes.live_view import LiveViewNode
from turning_force.nodes.spin import check_domain_id, make_executor, run_nodes
from turning_force.nodes.watch import LiveState, WatchNode

__all__ = ['render', 'view', 'watch']

# The names of the reasons and statuses the messages carry as numbers.
REASONS = {getattr(FeedOverride, n): n.removeprefix('REASON_') for n in dir(FeedOverride)
           if n.startswith('REASON_')}
STATUSES = {getattr(ForceEstimate, n): n.removeprefix('STATUS_') for n in dir(ForceEstimate)
            if n.startswith('STATUS_')}
LEVELS = {DiagnosticStatus.OK: 'OK', DiagnosticStatus.WARN: 'WARN',
          DiagnosticStatus.ERROR: 'ERROR', DiagnosticStatus.STALE: 'STALE'}
BARS = '▁▂▃▄▅▆▇█'
TRACE_WIDTH = 50
REFRESH_S = 0.25   # the terminal view's redraw period [s]


def view(namespace: str, settings: dict[str, Any]) -> int:
    """Run the live view node until SIGINT or SIGTERM; print where it serves."""
    def make() -> list[Any]:
        node = LiveViewNode(namespace=namespace, parameter_overrides=[
            Parameter(name, value=value) for name, value in settings.items()])
        print(f'turning-force view: serving {node.url} (the graph in {node.get_namespace()}); '
              'in Foxglove or Lichtblick: Open connection, Foxglove WebSocket, this address; '
              'layout: config/foxglove/turning_force.json', flush=True)
        return [node]
    return run_nodes(make, [])


def watch(namespace: str, duration_s: float | None, band_n: float,
          console: Console | None = None) -> int:
    """Draw the graph's state in the terminal until ``duration_s`` passes (None: until
    SIGINT); with a console that is not a terminal, the last frame only, at the end."""
    check_domain_id()
    console = console or Console()
    context = Context()
    rclpy.init(args=[], context=context)
    executor = make_executor(context, 'events')
    node = WatchNode(namespace=namespace, context=context)
    executor.add_node(node)
    where = node.get_namespace()
    end = None if duration_s is None else time.monotonic() + duration_s
    try:
        with Live(render(node.state, where, band_n), console=console,
                  refresh_per_second=1 / REFRESH_S) as live:
            next_draw = time.monotonic()
            while end is None or time.monotonic() < end:
                executor.spin_once(timeout_sec=0.05)
                if time.monotonic() >= next_draw:
                    live.update(render(node.state, where, band_n))
                    next_draw += REFRESH_S
            live.update(render(node.state, where, band_n))
    except KeyboardInterrupt:   # the operator's Ctrl-C: the last frame stays on the screen
        pass
    finally:
        executor.remove_node(node)
        node.destroy_node()
        executor.shutdown()
        rclpy.try_shutdown(context=context)
    return 0


def _trace(forces_n: Sequence[float], low_n: float, high_n: float) -> Text:
    """The recent forces as bars between ``low_n`` and ``high_n`` (the band's edges at the
    middle bars)."""
    text = Text()
    picked = list(forces_n)[-TRACE_WIDTH:]
    span = max(high_n - low_n, 1e-9)
    for force in picked:
        level = min(max(int((force - low_n) / span * len(BARS)), 0), len(BARS) - 1)
        text.append(BARS[level], style='green' if 2 <= level <= 5 else 'red')
    return text


def _age(state: LiveState, topic: str) -> str:
    last = state.last_s.get(topic)
    return 'never' if last is None else f'{time.monotonic() - last:.1f} s ago'


def render(state: LiveState, namespace: str, band_n: float) -> Group:
    """One frame of the terminal view of ``state``."""
    table = Table.grid(padding=(0, 2))
    table.add_column(style='bold')
    table.add_column()
    estimate, reference = state.estimate, state.reference_in_force_n
    if estimate is None:
        table.add_row('force', f'no force/estimate yet ({namespace})')
    else:
        status = STATUSES.get(estimate.status, str(estimate.status))
        line = Text(f'{estimate.force_n:8.1f} N  status {status}')
        if estimate.detail:
            line.append(f' ({estimate.detail})')
        table.add_row('force', line)
    if reference is None:
        table.add_row('reference', 'no feed command or force/reference yet')
    else:
        row = Text(f'{reference:8.1f} N  band ±{band_n:g} N')
        if estimate is not None:
            error = estimate.force_n - reference
            inside = abs(error) <= band_n
            row.append(f'  error {error:+.1f} N ')
            row.append('inside the band' if inside else 'OUTSIDE the band',
                       style='green' if inside else 'bold red')
        table.add_row('reference', row)
        table.add_row('trace', _trace(state.forces_n, reference - 2 * band_n,
                                      reference + 2 * band_n))
    if state.truth is not None:
        table.add_row('true force', f'{state.truth.force_n:8.1f} N  depth '
                      f'{state.truth.depth_of_cut_mm:g} mm (simulator)')
    command, override = state.command, state.override
    requested = 'none yet' if command is None else \
        f'{command.override_pct:6.1f} %  ({command.controller})'
    table.add_row('override requested', requested)
    if override is None:
        table.add_row('override applied', 'none yet')
        table.add_row('gate', 'no pmc/feed_override yet')
    else:
        table.add_row('override applied', f'{override.applied_pct:6.1f} %  code '
                      f'{override.pmc_code}  table {override.table}')
        gate = Text('armed' if override.armed else 'DISARMED',
                    style='green' if override.armed else 'yellow')
        gate.append(f'  reason {REASONS.get(override.reason, str(override.reason))}')
        gate.append('  in the cut' if override.engaged else '  out of the cut')
        if override.detail:
            gate.append(f'  ({override.detail})')
        table.add_row('gate', gate)
    table.add_row('alarms', _alarms(state))
    cut = state.cut
    table.add_row('last cut', 'none ended yet' if cut is None else
                  f'#{cut.index} {cut.duration_s:.2f} s, max {cut.max_force_n:.0f} N, mean '
                  f'{cut.mean_force_n:.0f} N, min override {cut.min_override_pct:.0f} %'
                  + ('' if cut.complete else ' (incomplete)'))
    nodes = Text()
    for name, status in sorted(state.statuses.items()):
        level = LEVELS.get(status.level, str(status.level))
        nodes.append(f'{name} {level}  ', style='green' if level == 'OK' else 'red')
    table.add_row('nodes', nodes if state.statuses else Text('no /diagnostics yet'))
    table.add_row('messages', '  '.join(f'{topic} {count}' for topic, count
                                        in state.counts.items() if count))
    table.add_row('last estimate', _age(state, 'force/estimate'))
    return Group(Text(f'turning_force {namespace}', style='bold'), table)


def _alarms(state: LiveState) -> Text:
    """The alarm and stop outputs, a bad estimate, and each node's warnings and errors."""
    text = Text()
    override, estimate = state.override, state.estimate
    if override is not None and override.alarm:
        text.append('ALARM output set  ', style='bold red')
    if override is not None and override.stop_request:
        text.append('STOP requested  ', style='bold red')
    if estimate is not None and estimate.status != ForceEstimate.STATUS_OK:
        text.append(f'estimate {STATUSES.get(estimate.status, estimate.status)}  ',
                    style='red')
    for name, status in sorted(state.statuses.items()):
        if status.level >= DiagnosticStatus.WARN:
            text.append(f'{name}: {status.message}  ', style='red')
    return text if text.plain else Text('none', style='green')
