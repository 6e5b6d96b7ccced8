"""The control chain over whole runs of blocks at once: replay (open loop, recorded currents)
and the closed core loop keeping everything a session records.

A run of DAQ blocks is held as arrays (:class:`CurrentArrays`, n blocks of m samples), and what the
chain did as one row per block (:class:`ChainTrace`). :func:`replay_chain` is replay's loop and
:func:`run_core` is :func:`turning_force.core.kernel.simulate.simulate` keeping every sample,
estimate, command and decision; both run compiled (:mod:`turning_force.core.kernel.loops`). Blocks
of differing lengths or sample periods go through
:class:`turning_force.core.kernel.chain.ControlChain` one block at a time: the same functions
again. """

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, overload

import numpy as np
import numpy.typing as npt

from turning_force.core import kernel
from turning_force.core.estimation.settings import EstimatorSettings
from turning_force.core.experiment import Experiment
from turning_force.core.plant.drive import CurrentBlock
from turning_force.core.pmc.overrides import OverrideTable, get_table
from turning_force.core.pmc.settings import BridgeSettings
from turning_force.core.pmc.shopfloor import CutRecord, InputValues

if TYPE_CHECKING:   # the compiled chain, imported where it runs: reading a session needs none
    from turning_force.core.kernel.chain import ChainStep, ControlChain
    from turning_force.core.kernel.simulate import SimulationResult

__all__ = ['ChainTrace', 'CoreRun', 'CurrentArrays', 'InputArrays', 'replay_chain', 'run_core']

FloatArray = npt.NDArray[np.float64]
Int8Array = npt.NDArray[np.int8]
BoolArray = npt.NDArray[np.bool_]

# Blocks per call of the kernel where replay reports its progress (about 10 ms of work).
REPLAY_CHUNK_BLOCKS = 20000


@dataclass(frozen=True)
class CurrentArrays(Sequence[CurrentBlock]):
    """A run of DAQ blocks as arrays: ``n`` blocks of ``m`` samples, sample ``j`` of block ``k``
    taken at ``t0_s[k] + j * sample_period_s`` (the core side of ``servo/currents``); as a
    sequence, its blocks one by one (:meth:`block`'s views, made on access)."""

    t0_s: FloatArray                 # (n,) time of each block's first sample [s]
    sample_period_s: float           # [s]
    phase_u_a: FloatArray            # (n, m) [A]
    phase_v_a: FloatArray            # (n, m) [A]
    rotor_angle_rad: FloatArray      # (n, m) electrical angle [rad]
    feed_rate_mm_min: FloatArray     # (n, m) [mm/min]

    def __len__(self) -> int:
        return int(self.t0_s.size)

    @overload
    def __getitem__(self, k: int) -> CurrentBlock: ...

    @overload
    def __getitem__(self, k: slice) -> list[CurrentBlock]: ...

    def __getitem__(self, k: int | slice) -> CurrentBlock | list[CurrentBlock]:
        if isinstance(k, slice):
            return [self.block(i) for i in range(*k.indices(len(self)))]
        return self.block(range(len(self))[k])   # a range raises IndexError beyond the blocks

    @property
    def samples_per_block(self) -> int:
        return int(self.phase_u_a.shape[1]) if self.phase_u_a.ndim == 2 else 0

    @property
    def t_end_s(self) -> FloatArray:
        """The end of each block (one sample after its last): when its decision is made [s]."""
        return self.t0_s + self.samples_per_block * self.sample_period_s

    def block(self, k: int) -> CurrentBlock:
        """Block ``k`` as a :class:`CurrentBlock` of views (the Python path's input)."""
        return CurrentBlock(float(self.t0_s[k]), self.sample_period_s, self.phase_u_a[k],
                            self.phase_v_a[k], self.rotor_angle_rad[k], self.feed_rate_mm_min[k])

    @classmethod
    def empty(cls, n: int, m: int, sample_period_s: float) -> CurrentArrays:
        """Arrays for ``n`` blocks of ``m`` samples, to be filled."""
        return cls(np.empty(n), sample_period_s, np.empty((n, m)), np.empty((n, m)),
                   np.empty((n, m)), np.empty((n, m)))

    @classmethod
    def from_blocks(cls, blocks: Sequence[CurrentBlock]) -> CurrentArrays:
        """Blocks of one length and one sample period as arrays (a :class:`ValueError` saying
        which block differs where they do not)."""
        if not blocks:
            raise ValueError('no blocks')
        n, m, dt = len(blocks), len(blocks[0]), blocks[0].sample_period_s
        periods = np.fromiter((b.sample_period_s for b in blocks), np.float64, n)
        same = (periods == dt) | (np.isnan(periods) & math.isnan(dt))
        try:
            if not same.all():
                raise ValueError('sample periods differ')
            arrays = [np.stack([np.asarray(getattr(b, name), dtype=np.float64) for b in blocks])
                      for name in ('phase_u_a', 'phase_v_a', 'rotor_angle_rad',
                                   'feed_rate_mm_min')]
            if arrays[0].shape != (n, m):
                raise ValueError('not one-dimensional')
        except ValueError:   # say which block (a slow look, on the way to an error only)
            for k, b in enumerate(blocks):
                if not _same(b.sample_period_s, dt) or any(
                        np.shape(x) != (m,) for x in (b.phase_u_a, b.phase_v_a,
                                                      b.rotor_angle_rad, b.feed_rate_mm_min)):
                    raise ValueError(f'block {k}: {len(b)} samples at {b.sample_period_s!r} s, '
                                     f'not {m} at {dt!r} s as block 0') from None
            raise
        t0 = np.fromiter((b.t0_s for b in blocks), np.float64, n)
        return cls(t0, float(dt), *arrays)


def _same(a: float, b: float) -> bool:
    return a == b or (math.isnan(a) and math.isnan(b))


@dataclass(frozen=True)
class InputArrays:
    """The machine's inputs each decision saw, as arrays (n,): ``given`` False where a block
    carries none (the last given stand); ``program_enable`` and ``threading`` 1 set, 0 clear,
    -1 not wired (``FeedOverride``'s tristate); ``operator_dial_pct`` and
    ``spindle_speed_rpm`` NaN where not read.

    Callable as ``inputs(k)``, so it goes wherever a function of the block does; replay hands
    it to the kernel without a Python call per block."""

    given: BoolArray
    program_enable: Int8Array
    threading: Int8Array
    operator_dial_pct: FloatArray
    spindle_speed_rpm: FloatArray | None = None   # None: never given
    tool_number: FloatArray | None = None         # the tool in use; NaN or None: not given

    def __post_init__(self) -> None:
        for name in ('spindle_speed_rpm', 'tool_number'):
            if getattr(self, name) is None:
                object.__setattr__(self, name, np.full(self.given.size, np.nan))

    @property
    def _speeds(self) -> FloatArray:
        assert self.spindle_speed_rpm is not None   # __post_init__
        return self.spindle_speed_rpm

    @property
    def _tools(self) -> FloatArray:
        assert self.tool_number is not None   # __post_init__
        return self.tool_number

    def __len__(self) -> int:
        return int(self.given.size)

    def __call__(self, k: int) -> InputValues | None:
        if not self.given[k]:
            return None
        enable, threading, dial = (int(self.program_enable[k]), int(self.threading[k]),
                                   float(self.operator_dial_pct[k]))
        speed, tool = float(self._speeds[k]), float(self._tools[k])
        return InputValues(None if enable < 0 else bool(enable),
                           None if threading < 0 else bool(threading),
                           None if math.isnan(dial) else dial,
                           None if math.isnan(speed) else speed,
                           None if math.isnan(tool) else int(tool))

    @classmethod
    def collect(cls, inputs: Callable[[int], InputValues | None], n: int) -> InputArrays:
        """``inputs(k)`` for every block."""
        out = cls(np.zeros(n, dtype=np.bool_), np.full(n, -1, dtype=np.int8),
                  np.full(n, -1, dtype=np.int8), np.full(n, np.nan), np.full(n, np.nan))
        for k in range(n):
            values = inputs(k)
            if values is not None:
                out.given[k] = True
                out.program_enable[k] = _tristate(values.program_enable)
                out.threading[k] = _tristate(values.threading)
                if values.operator_dial_pct is not None:
                    out.operator_dial_pct[k] = values.operator_dial_pct
                if values.spindle_speed_rpm is not None:
                    out._speeds[k] = values.spindle_speed_rpm
                if values.tool_number is not None:
                    out._tools[k] = values.tool_number
        return out

    def _last_given(self) -> tuple[BoolArray, npt.NDArray[np.intp]]:
        """Per block, whether inputs were given up to it, and the last block that gave them."""
        index = np.where(self.given, np.arange(len(self)), -1)
        np.maximum.accumulate(index, out=index)
        known = index >= 0
        return known, np.where(known, index, 0)

    def seen_tool(self) -> FloatArray:
        """The tool number each decision saw (NaN: none given up to its block)."""
        known, at = self._last_given()
        return np.where(known, self._tools[at], np.nan)

    def seen(self) -> tuple[Int8Array, Int8Array, FloatArray, FloatArray]:
        """What each decision saw: the last inputs given up to its block (none before the
        first), as (program_enable, threading, operator_dial_pct, spindle_speed_rpm)."""
        known, at = self._last_given()
        enable = np.where(known, self.program_enable[at], -1).astype(np.int8)
        threading = np.where(known, self.threading[at], -1).astype(np.int8)
        dial = np.where(known, self.operator_dial_pct[at], np.nan)
        speed = np.where(known, self._speeds[at], np.nan)
        return enable, threading, dial, speed


def _tristate(value: bool | None) -> int:
    return -1 if value is None else int(value)


@dataclass(frozen=True)
class ChainTrace:
    """What the control chain did, one row per block (length n).

    The estimate (``force/estimate``), the command (``control/feed_command``: NaN, and
    reachable, where the controller was silent) and the gate's decision answering the block
    (``pmc/feed_override``: the override applied from the next block on, its reason, the PMC
    code written, the machine's inputs the decision saw and the shop-floor outputs)."""

    estimated_force_n: FloatArray
    estimated_force_rate_n_s: FloatArray
    current_q_a: FloatArray
    friction_current_a: FloatArray
    estimated_feed_rate_mm_min: FloatArray     # ForceEstimate.feed_rate_mm_min
    estimate_status: Int8Array                 # EstimateStatus
    requested_override_pct: FloatArray         # NaN where the controller was silent
    reference_n: FloatArray                    # the command's reference; NaN where silent
    sliding_variable: FloatArray               # NaN where silent
    reference_reachable: BoolArray             # True where silent
    applied_pct: FloatArray                    # the decision answering the block
    reason: Int8Array                          # Reason
    armed: BoolArray
    pmc_code: npt.NDArray[np.int16]            # the table's code for applied_pct (0: continuous)
    gate_requested_pct: FloatArray             # FeedOverride.requested_pct: the standing request
    program_enable: Int8Array                  # 1 set, 0 clear, -1 not wired
    threading: Int8Array                       # 1 yes, 0 no, -1 not wired
    operator_dial_pct: FloatArray              # NaN: not wired or not read
    engaged: BoolArray                         # the tool in the cut
    alarm: BoolArray
    stop_request: BoolArray
    tracking_error_n: FloatArray               # FeedCommand's F - F_ref; NaN where silent
    # ForceEstimate.detail where it is not empty (why a block was refused, a note), by block
    estimate_detail: dict[int, str] = field(default_factory=dict)

    def __len__(self) -> int:
        return int(self.applied_pct.size)

    @classmethod
    def _empty(cls, n: int) -> ChainTrace:
        def floats() -> FloatArray:
            return np.full(n, np.nan)

        def flags(value: bool = False) -> BoolArray:
            return np.full(n, value, dtype=np.bool_)

        return cls(
            estimated_force_n=floats(), estimated_force_rate_n_s=floats(),
            current_q_a=floats(), friction_current_a=floats(),
            estimated_feed_rate_mm_min=floats(), estimate_status=np.zeros(n, dtype=np.int8),
            requested_override_pct=floats(),
            reference_n=floats(), sliding_variable=floats(), reference_reachable=flags(True),
            applied_pct=floats(), reason=np.zeros(n, dtype=np.int8), armed=flags(),
            pmc_code=np.zeros(n, dtype=np.int16), gate_requested_pct=floats(),
            program_enable=np.full(n, -1, dtype=np.int8),
            threading=np.full(n, -1, dtype=np.int8), operator_dial_pct=floats(),
            engaged=flags(), alarm=flags(), stop_request=flags(), tracking_error_n=floats())

    def _put(self, k: int, step: ChainStep, reference_n: float) -> None:
        """Row ``k`` from one step of the Python chain."""
        e, command, d = step.estimate, step.command, step.decision
        self.estimated_force_n[k], self.estimated_force_rate_n_s[k] = e.force_n, e.force_rate_n_s
        self.current_q_a[k], self.friction_current_a[k] = e.current_q_a, e.friction_current_a
        self.estimated_feed_rate_mm_min[k] = e.feed_rate_mm_min
        self.estimate_status[k] = int(e.status)
        if e.detail:
            self.estimate_detail[k] = e.detail
        if command is not None:
            self.tracking_error_n[k] = command.error_n
            self.requested_override_pct[k] = command.override_pct
            self.reference_n[k] = reference_n
            self.sliding_variable[k] = command.sliding_variable
            self.reference_reachable[k] = command.reachable
        self.applied_pct[k], self.reason[k], self.armed[k] = (d.applied_pct, int(d.reason),
                                                              d.armed)
        self.pmc_code[k], self.gate_requested_pct[k] = d.code, d.requested_pct
        self.program_enable[k] = _tristate(d.inputs.program_enable)
        self.threading[k] = _tristate(d.inputs.threading)
        dial = d.inputs.operator_dial_pct
        self.operator_dial_pct[k] = math.nan if dial is None else dial
        self.engaged[k], self.alarm[k], self.stop_request[k] = d.engaged, d.alarm, d.stop_request


@dataclass(frozen=True)
class CoreRun:
    """A closed-loop run keeping what a session records."""

    result: SimulationResult            # the trace and metrics simulate() gives, bit for bit
    currents: CurrentArrays             # every DAQ sample the plant produced
    chain: ChainTrace
    # Per block, at its end (lathe_sim's sim/cutting_state): force_n, depth_mm, feed_mm_rev,
    # feed_rate_mm_min, override_pct (what the PMC applied during the block),
    # spindle_speed_rpm, specific_cutting_force_n_mm2.
    plant: dict[str, FloatArray] = field(default_factory=dict)
    # The cuts that ended during the run, as the gate's cut log has them (pmc/cuts).
    cuts: list[CutRecord] = field(default_factory=list)


# --- replay ---------------------------------------------------------------------------------

def open_loop(experiment: Experiment) -> BridgeSettings:
    """The bridge's settings for an open-loop replay: the feed-follow check off. The recorded
    axis feed followed the overrides the session applied, not the ones the replay decides, so
    the check cannot be judged on it (a replay with other settings would find the feed
    "not following" wherever its decisions differ)."""
    return experiment.bridge.replace(feed_follow_time_s=0.0)


def replay_chain(experiment: Experiment, currents: CurrentArrays | Sequence[CurrentBlock],
                 arm_changes: Sequence[tuple[float, bool]] = (),
                 inputs: Callable[[int], InputValues | None] | None = None,
                 reference_force_n: float | None = None,
                 progress: Callable[[int, int], None] | None = None) -> ChainTrace:
    """The control chain (estimator, controller, gate) open loop over recorded currents:
    exactly the loop of :func:`turning_force.session.replay.replay`.

    Before each block the gate is armed (at the change's time) or disarmed for every change in
    ``arm_changes`` (time [s], armed) at or before the block's end; each decision is made at
    the block's end. ``inputs(k)``: the machine's inputs the decision answering block ``k``
    saw (None: the last given stand); an :class:`InputArrays` goes to the kernel whole.
    ``reference_force_n``: the reference to start from (:class:`ControlChain`'s).
    ``currents`` may also be a list of blocks; blocks of differing lengths or sample periods
    go one at a time. ``progress(done, n)`` is called as blocks are done.
    """
    arrays: CurrentArrays | None = None
    blocks: Callable[[int], CurrentBlock]
    if isinstance(currents, CurrentArrays):
        arrays, blocks = currents, currents.block
    else:
        blocks = currents.__getitem__
        try:
            arrays = CurrentArrays.from_blocks(currents)
        except ValueError:
            arrays = None
    n = len(currents)
    if arrays is None:
        return _replay_blocks(experiment, blocks, n, arm_changes, inputs, reference_force_n,
                              progress)
    seen = (None if inputs is None else
            inputs if isinstance(inputs, InputArrays) else InputArrays.collect(inputs, n))
    from turning_force.core.kernel.chain import ControlChain

    chain = ControlChain(experiment.estimator, experiment.controller, open_loop(experiment),
                         reference_force_n=reference_force_n)
    trace = _replay_compiled(chain, arrays, arm_changes, seen, progress)
    if seen is not None:
        trace.program_enable[:], trace.threading[:], trace.operator_dial_pct[:], _ = seen.seen()
    return trace


def _inputs_matrix(seen: InputArrays | None, n: int) -> FloatArray:
    """The inputs each decision saw as the kernel takes them: (n, 5) program enable,
    threading (1 set, 0 clear), the operator's dial, the spindle speed, the tool; NaN where not
    wired or not given yet."""
    out = np.full((n, 5), np.nan)
    if seen is not None:
        enable, threading, dial, speed = seen.seen()
        out[:, 0] = np.where(enable < 0, np.nan, enable)
        out[:, 1] = np.where(threading < 0, np.nan, threading)
        out[:, 2], out[:, 3] = dial, speed
        out[:, 4] = seen.seen_tool()
    return out


def _replay_blocks(experiment: Experiment, blocks: Callable[[int], CurrentBlock], n: int,
                   arm_changes: Sequence[tuple[float, bool]],
                   inputs: Callable[[int], InputValues | None] | None,
                   reference_force_n: float | None,
                   progress: Callable[[int, int], None] | None = None) -> ChainTrace:
    """:class:`ControlChain` block by block, for blocks no one array holds."""
    from turning_force.core.kernel.chain import ControlChain

    chain = ControlChain(experiment.estimator, experiment.controller, open_loop(experiment),
                         reference_force_n=reference_force_n)
    trace = ChainTrace._empty(n)
    changes = list(arm_changes)
    next_change = 0
    for k in range(n):
        block = blocks(k)
        t_s = block.t0_s + len(block) * block.sample_period_s
        while next_change < len(changes) and changes[next_change][0] <= t_s:
            t_change, armed = changes[next_change]
            next_change += 1
            if armed and not chain.gate.armed:
                chain.gate.arm(t_change)
            elif not armed and chain.gate.armed:
                chain.gate.disarm()
        step = chain.step(block, t_s, None if inputs is None else inputs(k))
        trace._put(k, step, chain.controller.reference_force_n)
        if progress is not None:
            progress(k + 1, n)
    return trace


def _replay_compiled(chain: ControlChain, currents: CurrentArrays,
                     arm_changes: Sequence[tuple[float, bool]], seen: InputArrays | None,
                     progress: Callable[[int, int], None] | None = None) -> ChainTrace:
    """The compiled replay, from the (fresh) chain's state."""
    jit = kernel.load()
    ep, es, cp, cs, clevels, gp, gs, glevels, ctools, gtools = chain.arrays(
        currents.sample_period_s)
    n = len(currents)
    # The kernel's rows a chunk at a time, into the trace as each is done: an hour's replay
    # holds the trace and one chunk of rows, not a second copy of the trace.
    rows = np.empty((min(n, REPLAY_CHUNK_BLOCKS), jit.CHAIN_COLUMNS))
    trace = ChainTrace._empty(n)
    times = np.array([t for t, _ in arm_changes], dtype=np.float64)
    armed = np.array([float(a) for _, a in arm_changes], dtype=np.float64)
    t0, u, v = _c(currents.t0_s), _c(currents.phase_u_a), _c(currents.phase_v_a)
    angle, feed = _c(currents.rotor_angle_rad), _c(currents.feed_rate_mm_min)
    inputs = _inputs_matrix(seen, n)
    from turning_force.core.pmc.gate import CUT_FIELDS

    cuts, ncuts = np.zeros((n // 2 + 1, CUT_FIELDS)), np.zeros(1)
    change = 0
    for start in range(0, n, REPLAY_CHUNK_BLOCKS):
        end = min(start + REPLAY_CHUNK_BLOCKS, n)
        chunk = rows[:end - start]
        change = jit.replay_blocks(ep, es, cp, cs, clevels, gp, gs, glevels, ctools, gtools,
                                   t0[start:end],
                                   float(currents.sample_period_s), u[start:end], v[start:end],
                                   angle[start:end], feed[start:end], times, armed, change,
                                   chunk, inputs[start:end], cuts, ncuts)
        _rows_into(jit, chunk, trace, start, chain.gate.table, chain.estimator.settings,
                   currents)
        if progress is not None:
            progress(end, n)
    return trace


def _c(values: FloatArray) -> FloatArray:
    """What the kernel's signature takes: C-contiguous, writable float64."""
    out = np.ascontiguousarray(values, dtype=np.float64)
    return out if out.flags.writeable else out.copy()


def _rows_into(jit: Any, rows: FloatArray, trace: ChainTrace, first: int,
               table: OverrideTable, settings: EstimatorSettings,
               currents: CurrentArrays) -> None:
    """The kernel's chain rows of blocks ``first`` .. ``first + len(rows) - 1`` into the
    trace's arrays (the inputs the decisions saw are not the kernel's business: the caller
    fills them); the estimate's details in the reference's words."""
    from turning_force.core.estimation.estimator import (
        D_NONE,
        D_REZEROED,
        detail_text,
        rezeroed_text,
    )

    r = rows
    sl = slice(first, first + len(rows))
    acted = r[:, jit.CH_ACTED] != 0.0
    trace.estimated_force_n[sl] = r[:, jit.CH_FORCE]
    trace.estimated_force_rate_n_s[sl] = r[:, jit.CH_RATE]
    trace.current_q_a[sl] = r[:, jit.CH_IQ]
    trace.friction_current_a[sl] = r[:, jit.CH_IFR]
    trace.estimated_feed_rate_mm_min[sl] = r[:, jit.CH_FEED]
    trace.estimate_status[sl] = r[:, jit.CH_STATUS]
    trace.requested_override_pct[sl] = np.where(acted, r[:, jit.CH_REQ], np.nan)
    trace.reference_n[sl] = np.where(acted, r[:, jit.CH_REF], np.nan)
    trace.sliding_variable[sl] = np.where(acted, r[:, jit.CH_S], np.nan)
    trace.reference_reachable[sl] = ~acted | (r[:, jit.CH_REACH] != 0.0)
    applied = r[:, jit.CH_APPLIED]
    trace.applied_pct[sl] = applied
    trace.reason[sl] = r[:, jit.CH_REASON]
    trace.armed[sl] = r[:, jit.CH_ARMED] != 0.0
    trace.pmc_code[sl] = pmc_codes(table, applied)
    trace.gate_requested_pct[sl] = r[:, jit.CH_GATE_REQ]
    trace.engaged[sl] = r[:, jit.CH_ENGAGED] != 0.0
    trace.alarm[sl] = r[:, jit.CH_ALARM] != 0.0
    trace.stop_request[sl] = r[:, jit.CH_STOP] != 0.0
    trace.tracking_error_n[sl] = np.where(acted, r[:, jit.CH_ERR], np.nan)
    codes = r[:, jit.CH_DCODE]
    details = trace.estimate_detail
    # In air the friction re-zero's line is on nearly every block: its text needs no block.
    rezeroed = np.flatnonzero(codes == D_REZEROED)
    for k, scale in zip((rezeroed + first).tolist(), r[rezeroed, jit.CH_DVAL].tolist(),
                        strict=True):
        details[k] = rezeroed_text(scale)
    for k in np.flatnonzero((codes != D_NONE) & (codes != D_REZEROED)).tolist():
        row = r[k]
        details[first + k] = detail_text(
            settings, currents.block(first + k), int(row[jit.CH_DCODE]),
            float(row[jit.CH_DVAL]), float(row[jit.CH_DVAL + 1]))


def pmc_codes(table: OverrideTable, applied_pct: FloatArray) -> npt.NDArray[np.int16]:
    """:meth:`OverrideTable.encode`'s code of each applied override (each one of the table's
    levels, as the gate quantises it); 0 on a continuous table."""
    if table.continuous:
        return np.zeros(applied_pct.size, dtype=np.int16)
    levels = np.asarray(table.levels_pct, dtype=np.float64)
    index = np.minimum(np.searchsorted(levels, applied_pct), levels.size - 1)
    if not np.array_equal(levels[index], applied_pct):
        bad = applied_pct[levels[index] != applied_pct][0]
        raise ValueError(f'{table.name}: {bad!r} % is not a level; quantise it first')
    return np.asarray(table.codes, dtype=np.int16)[index]


# --- the closed loop ------------------------------------------------------------------------

def run_core(experiment: Experiment) -> CoreRun:
    """:func:`turning_force.core.kernel.simulate.simulate`, keeping what a session records: every
    DAQ sample the plant produced, the chain's estimate, command and decision for each block, and
    the plant's state at each block's end; ``result`` is what simulate gives, bit for bit (its
    ``realtime_factor`` aside)."""
    from turning_force.core.kernel.simulate import run_loop
    from turning_force.core.pmc.gate import cut_record

    jit = kernel.load()
    plant_settings = experiment.plant
    n = round(experiment.run.duration_s / experiment.run.control_period_s)
    m = plant_settings.samples_per_block
    currents = CurrentArrays.empty(n, m, 1.0 / plant_settings.sample_rate_hz)
    rows = np.zeros((n, jit.CHAIN_COLUMNS))
    result = run_loop(experiment, (currents.t0_s, currents.phase_u_a, currents.phase_v_a,
                                   currents.rotor_angle_rad, currents.feed_rate_mm_min, rows))
    chain = ChainTrace._empty(n)
    table = get_table(experiment.bridge.override_table)
    _rows_into(jit, rows, chain, 0, table, experiment.estimator, currents)
    seen = plant_settings.inputs_array(currents.t_end_s)
    chain.program_enable[:] = np.where(np.isnan(seen[:, 0]), -1, seen[:, 0])
    chain.threading[:] = np.where(np.isnan(seen[:, 1]), -1, seen[:, 1])
    chain.operator_dial_pct[:] = seen[:, 2]
    t = result.trace
    plant = {
        'force_n': t['force_n'],
        'depth_mm': t['depth_mm'],
        'feed_mm_rev': t['feed_mm_rev'],
        'feed_rate_mm_min': currents.feed_rate_mm_min[:, -1].copy() if n else np.empty(0),
        'override_pct': t['applied_override_pct'],
        'spindle_speed_rpm': t['spindle_speed_rpm'],
        'specific_cutting_force_n_mm2': plant_settings.material_at(currents.t_end_s),
    }
    cuts = [cut_record(row, experiment.bridge.tool) for row in result.cut_rows]
    return CoreRun(result, currents, chain, plant, cuts)
