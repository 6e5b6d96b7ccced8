"""``turning-force run --core --out BAG``: the core loop's run recorded as the graph records it.

:func:`turning_force.core.kernel.batch.run_core` keeps every block of a closed-loop run; this
writes them as the lock-step graph's session holds them (:data:`TOPICS`): each message with the
stamps and fields the node that publishes it gives it, in the graph's order per block
(:data:`PER_BLOCK`, after the override the bridge writes when it is configured), logged at the end
of its block, with the same custom data. The messages are serialised as arrays
(:func:`turning_force.session.codec.encode`) and written a chunk at a time: an hour of fig8 takes
seconds, not the minutes a message at a time would.

Not recorded (:data:`NOT_RECORDED`): ``/diagnostics`` (there are no nodes),
``force/reference`` (the core run learns none), ``force/measured`` (a dynamometer the node draws
from its own random stream), and the text of ``detail`` in ``pmc/feed_override``. The signals
the reader and replay take are equal.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, fields, replace
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from turning_force.core.experiment import Experiment
from turning_force.core.kernel.batch import CoreRun, run_core
from turning_force.core.pmc.overrides import get_table
from turning_force.core.pmc.shopfloor import CutRecord
from turning_force.session import codec
from turning_force.session.bag import (
    CUSTOM_EXPERIMENT,
    CUSTOM_PARAMETERS,
    CUSTOM_PLANNED,
    CUSTOM_VERSIONS,
    GRAPH_TYPES,
    SessionWriter,
    dumps,
    software_versions,
    stopped_by,
    typestore,
)

__all__ = ['NOT_RECORDED', 'RECORDER', 'TOPICS', 'CoreSession', 'record_core']

IntArray = npt.NDArray[np.int64]
FloatArray = npt.NDArray[np.float64]

# The graph's topics (session/bag.py's GRAPH_TYPES), as the lock-step graph's names them.
TOPICS: dict[str, str] = {f'/{t.lstrip("/")}': msgtype for t, msgtype in GRAPH_TYPES.items()}
# Per block, in the order the graph's messages reach the recorder (a cut that ended is
# published by the bridge as it answers the block, before the override).
PER_BLOCK = ('/machine/inputs', '/machine/spindle_speed', '/servo/currents', '/servo/joint_state',
             '/sim/cutting_state', '/force/estimate', '/control/feed_command', '/pmc/cuts',
             '/pmc/feed_override')
NOT_RECORDED = ('/diagnostics', '/force/reference', '/force/measured')
# Custom data saying who recorded the session.
RECORDER = 'turning_force.recorder'
FRAME = 'z_axis'   # lathe_sim's frame
# Blocks serialised at once (about 1 MiB of messages for fig8's 10-sample blocks: one chunk).
BATCH_BLOCKS = 2048


@dataclass(frozen=True)
class CoreSession:
    """What ``run --core --out`` did: the session and the core run it recorded."""

    bag: Path
    run: CoreRun
    steps: int


def record_core(experiment: Experiment, out: Path,
                progress: Callable[[int, int], None] | None = None) -> CoreSession:
    """Run ``experiment`` on the core loop and record it to ``out`` (see the module's text).

    The session is opened first, with its settings and the planned count of blocks, so that
    a run stopped at any point leaves a session that says so: whatever ``progress`` raises
    (a signal, between two batches) or the run raises closes it as ended early, with the
    blocks written; a kill leaves it unclosed (read back as killed)."""
    writer = _open_session(experiment, out)
    try:
        run = run_core(experiment)
        _write(writer, experiment, run, progress)
    except BaseException as exc:
        writer.end(stopped_by(exc))
        writer.close()
        raise
    writer.close()
    return CoreSession(out, run, len(run.currents))


def _open_session(experiment: Experiment, out: Path) -> SessionWriter:
    """The session folder ``out`` opened: custom data (the settings topic too), the topics."""
    from turning_force.io.pmc_server import simulated_parameters

    custom = {CUSTOM_VERSIONS: dumps(software_versions())}
    if experiment.source and Path(experiment.source).is_file():
        custom[CUSTOM_EXPERIMENT] = Path(experiment.source).read_text()
    custom[CUSTOM_PARAMETERS] = dumps(simulated_parameters(experiment)[0])
    custom[RECORDER] = 'run --core: ' + ', '.join(NOT_RECORDED) + ' not recorded'
    custom[CUSTOM_PLANNED] = str(round(experiment.run.duration_s
                                       / experiment.run.control_period_s))
    writer = SessionWriter(out, custom_data=custom)
    try:
        for topic, msgtype in TOPICS.items():
            writer.add_topic(topic, msgtype)
        writer.record_settings()
    except BaseException:
        writer.close()
        raise
    return writer


def _stamp(ns: IntArray) -> dict[str, IntArray]:
    return {'header.stamp.sec': ns // 1_000_000_000, 'header.stamp.nanosec': ns % 1_000_000_000}


def _write(writer: SessionWriter, experiment: Experiment, run: CoreRun,
           progress: Callable[[int, int], None] | None) -> None:
    c, chain, plant = run.currents, run.chain, run.plant
    n, m = len(c), c.samples_per_block
    period_ns = round(c.sample_period_s * 1e9)
    first_ns = np.round(c.t0_s * 1e9).astype(np.int64)
    last_ns = first_ns + round((m - 1) * c.sample_period_s * 1e9)
    end_ns = last_ns + period_ns   # the clock the recorder logs the block's messages at
    table = get_table(experiment.bridge.override_table)
    levels = np.unique(chain.applied_pct[np.isfinite(chain.applied_pct)])
    bits_of = {float(p): table.encode(float(p))[1] for p in levels}
    width = max((len(b) for b in bits_of.values()), default=0)
    bits = np.zeros((n, width), dtype=bool)
    for pct, pattern in bits_of.items():
        bits[chain.applied_pct == pct] = pattern
    # Where the PMC's position is (lathe_sim's joint state): the plant's sum of its feed.
    feed = c.feed_rate_mm_min
    position_m = np.cumsum(np.cumsum(feed, axis=1)[:, -1] * c.sample_period_s / 60.0) / 1000.0
    acted = np.isfinite(chain.requested_override_pct)
    topics = list(PER_BLOCK)
    order = {t: k for k, t in enumerate(topics)}
    # The override the bridge writes when it is configured (the programmed feed, disarmed),
    # before the first block; logged with it.
    code, hand_back = table.encode(100.0)
    initial = _encode('/pmc/feed_override', {
        **_stamp(np.zeros(1, dtype=np.int64)), 'applied_pct': 100.0, 'requested_pct': np.nan,
        'pmc_code': code, 'pmc_bits': np.array([hand_back], dtype=bool),
        'table': table.name, 'armed': False, 'reason': 1,
        'detail': 'inactive: programmed feed', 'program_enable': -1, 'threading': -1,
        'operator_dial_pct': np.nan, 'tool_number': -1}, 1)
    # The tool each decision saw (FeedOverride's tool_number: -1 where none is given).
    seen_tool = experiment.plant.inputs_array(c.t_end_s)[:, 4]
    tool_number = np.where(np.isnan(seen_tool), -1, seen_tool).astype(np.int32)
    cuts, cut_blocks = _cuts(run, experiment, end_ns)
    details = _Details(chain.estimate_detail)
    for start in range(0, n, BATCH_BLOCKS):
        k = slice(start, min(start + BATCH_BLOCKS, n))
        count = k.stop - k.start
        last = last_ns[k]
        header = {**_stamp(last), 'header.frame_id': FRAME}   # the block's answers' header
        messages: dict[str, tuple[dict[str, Any], Any]] = {
            '/machine/inputs': ({**_stamp(last), 'program_enable': chain.program_enable[k],
                                 'threading': chain.threading[k],
                                 'operator_dial_pct': chain.operator_dial_pct[k]}, None),
            '/machine/spindle_speed': ({'data': plant['spindle_speed_rpm'][k]},
                                       np.full(count, experiment.plant.spindle_speed_wired)),
            '/servo/currents': ({**_stamp(first_ns[k]), 'header.frame_id': FRAME,
                                 'sample_period_s': c.sample_period_s,
                                 'phase_u_a': c.phase_u_a[k], 'phase_v_a': c.phase_v_a[k],
                                 'rotor_angle_rad': c.rotor_angle_rad[k],
                                 'feed_rate_mm_min': feed[k]}, None),
            '/servo/joint_state': ({**header, 'name': np.array([b'z']),
                                    'position': position_m[k, None],
                                    'velocity': feed[k, -1:] / 60000.0,
                                    'effort': plant['force_n'][k, None]}, None),
            '/sim/cutting_state': ({**header, 'force_n': plant['force_n'][k],
                                    'depth_of_cut_mm': plant['depth_mm'][k],
                                    'spindle_speed_rpm': plant['spindle_speed_rpm'][k],
                                    'feed_mm_rev': plant['feed_mm_rev'][k],
                                    'feed_rate_mm_min': plant['feed_rate_mm_min'][k],
                                    'specific_cutting_force_n_mm2':
                                        plant['specific_cutting_force_n_mm2'][k],
                                    'override_pct': plant['override_pct'][k]}, None),
            '/force/estimate': ({**header, 'force_n': chain.estimated_force_n[k],
                                 'force_rate_n_s': chain.estimated_force_rate_n_s[k],
                                 'current_q_a': chain.current_q_a[k],
                                 'friction_current_a': chain.friction_current_a[k],
                                 'status': chain.estimate_status[k],
                                 'detail': details.column(k),
                                 'feed_rate_mm_min': chain.estimated_feed_rate_mm_min[k]}, None),
            '/control/feed_command': ({
                **header, 'override_pct': chain.requested_override_pct[k],
                'tracking_error_n': chain.tracking_error_n[k],
                'sliding_variable': chain.sliding_variable[k],
                'reference_force_n': chain.reference_n[k],
                'controller': experiment.controller.controller,
                'reference_reachable': chain.reference_reachable[k]}, acted[k]),
            '/pmc/feed_override': ({
                **header, 'applied_pct': chain.applied_pct[k],
                'requested_pct': chain.gate_requested_pct[k], 'pmc_code': chain.pmc_code[k],
                'pmc_bits': bits[k], 'table': table.name, 'armed': chain.armed[k],
                'reason': chain.reason[k], 'program_enable': chain.program_enable[k],
                'threading': chain.threading[k],
                'operator_dial_pct': chain.operator_dial_pct[k], 'engaged': chain.engaged[k],
                'alarm': chain.alarm[k], 'stop_request': chain.stop_request[k],
                'tool_number': tool_number[k]}, None),
        }
        pieces: list[tuple[bytes, IntArray, IntArray, int]] = []   # bytes, offsets, block, topic
        for topic, (columns, keep) in messages.items():
            if keep is not None:
                columns = {name: (v[keep] if isinstance(v, np.ndarray) and v.shape[:1] ==
                                  (count,) else v) for name, v in columns.items()}
            blocks = np.arange(count) if keep is None else np.flatnonzero(keep)
            data, offsets = _encode(topic, columns, int(blocks.size))
            pieces.append((data, offsets, blocks, order[topic]))
        ended = (cut_blocks >= k.start) & (cut_blocks < k.stop)
        if ended.any():
            data, offsets = cuts
            chosen = np.flatnonzero(ended)
            sizes = np.diff(offsets)[chosen]
            gathered = b''.join(data[offsets[i]:offsets[i + 1]] for i in chosen)
            pieces.append((gathered, np.concatenate(([0], np.cumsum(sizes))),
                           cut_blocks[chosen] - k.start, order['/pmc/cuts']))
        if start == 0:
            pieces.insert(0, (initial[0], initial[1], np.full(1, -1), order['/pmc/feed_override']))
        _write_batch(writer, topics, pieces, end_ns[k])
        if progress is not None:
            progress(k.stop, n)


def _cuts(run: CoreRun, experiment: Experiment, end_ns: IntArray
          ) -> tuple[tuple[bytes, IntArray], IntArray]:
    """The cut log's messages (bytes, offsets) and the block whose answer ended each cut: the
    block ``debounce`` blocks after its last (:class:`turning_force.core.pmc.shopfloor.CutLog`).
    The times are the bridge's: its clock's nanoseconds x 1e-9 at the blocks' ends (``end_ns``),
    where the core loop's ``t0 + m dt`` may differ in the last bit."""
    if not run.cuts:
        return (b'', np.zeros(1, dtype=np.int64)), np.zeros(0, dtype=np.int64)
    bridge = experiment.bridge
    period_s = bridge.control_period_s
    # The blocks a cut's times name (t_end_s, increasing): each time is a block's end to the
    # last bit, half a period from the next.
    t_end = run.currents.t_end_s
    firsts = np.searchsorted(t_end, [r.start_s + 0.5 * period_s for r in run.cuts])
    last = np.searchsorted(t_end, [r.end_s - 0.5 * period_s for r in run.cuts])
    records = [replace(r, start_s=int(end_ns[first]) * 1e-9 - period_s,
                       end_s=int(end_ns[end]) * 1e-9)
               for r, first, end in zip(run.cuts, firsts.tolist(), last.tolist(), strict=True)]
    stamps = np.array([round(r.end_s * 1e9) for r in records], dtype=np.int64)
    columns: dict[str, Any] = {**_stamp(stamps), 'tool': bridge.tool}
    for name in (*(f.name for f in fields(CutRecord) if f.name != 'tool'), 'duration_s'):
        columns[name] = np.array([getattr(r, name) for r in records])
    return (_encode('/pmc/cuts', columns, len(records)),
            last.astype(np.int64) + bridge.debounce_blocks(period_s))


class _Details:
    """The estimate's details (by block, where not empty) as a column per batch of blocks, in
    time linear in the details (in air, the friction re-zero's line is on nearly every block)."""

    def __init__(self, details: dict[int, str]) -> None:
        self.blocks = np.array(sorted(details), dtype=np.int64)
        self.text = [details[b].encode() for b in self.blocks.tolist()]

    def column(self, k: slice) -> Any:
        lo, hi = np.searchsorted(self.blocks, (k.start, k.stop))
        if lo == hi:
            return ''
        inside = self.text[lo:hi]
        column = np.zeros(k.stop - k.start, dtype=f'S{max(len(t) for t in inside)}')
        column[self.blocks[lo:hi] - k.start] = inside
        return column


def _encode(topic: str, columns: dict[str, Any], count: int) -> tuple[bytes, IntArray]:
    return codec.encode(typestore(), TOPICS[topic], columns, count)


def _write_batch(writer: SessionWriter, topics: list[str],
                 pieces: list[tuple[bytes, IntArray, IntArray, int]], end_ns: IntArray) -> None:
    """The messages of a batch of blocks, block by block in the graph's order (a block's
    messages in ``topics`` order; block -1, the configured override, first)."""
    block = np.concatenate([p[2] for p in pieces])
    topic = np.concatenate([np.full(p[2].size, p[3]) for p in pieces])
    sizes = np.concatenate([np.diff(p[1]) for p in pieces])
    starts = np.concatenate([p[1][:-1] + base for p, base in zip(
        pieces, np.cumsum([0] + [len(p[0]) for p in pieces[:-1]]), strict=True)])
    data = np.frombuffer(b''.join(p[0] for p in pieces), dtype=np.uint8)
    order = np.lexsort((topic, block))
    sizes, starts = sizes[order], starts[order]
    ordered = data[codec.ranges(starts, sizes)]
    offsets = np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64)
    stamps = end_ns[np.maximum(block[order], 0)]
    writer.write_indexed(topics, topic[order].astype(np.int64), stamps, ordered, offsets)
