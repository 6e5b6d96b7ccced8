"""The closed loop in one function, no ROS: plant -> control chain (estimator, controller, PMC
gate, :class:`turning_force.core.loop.ControlChain`) -> plant.

Each control period the plant delivers one block of currents at the override the PMC applied in
the period before; the chain runs on it and its gate (quantiser, watchdog, overload hold)
decides what is applied for the next block. That one-period delay and that gate
are the same the node graph has, so both give the same numbers.

The loop runs on the compiled kernel (:mod:`turning_force.core.kernel`) wherever it covers the
experiment's settings, else on the plain Python reference, which gives the same numbers bit for
bit. While the kernel is still loading (numba's import takes about as long as a short run), the
first blocks run in Python and the rest in the kernel, from the Python objects' state as it is
then: the start-up never waits for numba, and the result does not depend on when it arrived.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np
import numpy.typing as npt

from turning_force.core import kernel
from turning_force.core.control import ControlOutput
from turning_force.core.errors import ConfigError, NoCutError
from turning_force.core.experiment import Experiment
from turning_force.core.loop import ChainStep, ControlChain
from turning_force.core.metrics import compute_metrics
from turning_force.core.overrides import get_table
from turning_force.core.plant import LathePlant, PlantBlock

__all__ = ['Keeper', 'SimulationResult', 'simulate']

FloatArray = npt.NDArray[np.float64]

TRACE_NAMES = (
    't_s',                  # end of the block [s]
    'force_n',              # true cutting force at the end of the block [N]
    'estimated_force_n',
    'estimated_force_rate_n_s',
    'reference_n',
    'depth_mm',
    'feed_mm_rev',          # actual feed at the end of the block
    'requested_override_pct',
    'applied_override_pct',  # what the PMC applied during the block
    'sliding_variable',
    'reference_reachable',  # 1 while the controller can reach the reference, else 0
)


@dataclass
class SimulationResult:
    """Traces sampled at the control period, and the metrics of the run."""

    trace: dict[str, FloatArray]
    metrics: dict[str, float] = field(default_factory=dict)
    compiled_from: int | None = None   # the first block the kernel ran; None: all Python
    python_reason: str = ''            # why the kernel did not run it ('' where it did)

    @property
    def kernel(self) -> str:
        """Which path ran the loop, in a few words."""
        if self.compiled_from is None:
            return f'python ({self.python_reason})'
        if self.compiled_from == 0:
            return 'compiled'
        return f'python for {self.compiled_from} blocks while the kernel loaded, then compiled'


class Keeper(Protocol):
    """What a run keeps beside its trace, block by block
    (:func:`turning_force.core.batch.run_core`: every DAQ sample, the estimate, the command and
    the decision)."""

    def python_block(self, k: int, block: PlantBlock, step: ChainStep,
                     reference_n: float) -> None:
        """Block ``k`` as the Python loop ran it; ``reference_n``, the controller's reference
        when its command was made."""

    def kernel_arrays(self) -> tuple[FloatArray, ...]:
        """Where the kernel writes (``jit.run_core_kept``): the blocks' first stamps (n,), the
        samples u, v, angle, feed rate (n, m each) and the chain's rows
        (n, ``jit.CHAIN_COLUMNS``)."""
        ...

    def kernel_done(self, first: int) -> None:
        """The kernel has written blocks ``first`` .. n - 1."""

    def python_done(self, chain: ControlChain, blocks: int) -> None:
        """The Python loop has run blocks 0 .. ``blocks`` - 1 on ``chain`` (its gate's cut
        log among what it holds); the kernel runs the rest, if any."""


# Blocks per call of the kernel: the plant's noise for them is drawn in advance.
CHUNK_BLOCKS = 4096


def simulate(experiment: Experiment, compiled: bool | None = None,
             python_blocks: int = 0) -> SimulationResult:
    """Run an experiment through the core loop; deterministic for a given file and seed.

    The plant, the estimator and the controller are compiled on every path (their code is
    loaded before the first block). What ``compiled`` chooses is the loop and its gate:
    None, the kernel's loop where its gate covers the settings, else the bridge's gate block by
    block (:func:`turning_force.core.kernel.why_python` says why); True: the kernel's loop (a
    :class:`ConfigError` naming the setting where it cannot); False: block by block.
    ``TURNING_FORCE_KERNEL=on`` in the environment makes None True, ``off`` False.
    ``python_blocks``: at least this many blocks block by block before the kernel's loop takes
    over (the hand-over, which the tests hold to the other gate).
    """
    return run_loop(experiment, compiled, python_blocks)


def run_loop(experiment: Experiment, compiled: bool | None = None, python_blocks: int = 0,
             keeper: Keeper | None = None) -> SimulationResult:
    """:func:`simulate`, handing every block to ``keeper`` as well where one is given."""
    wall_start = time.perf_counter()
    table = get_table(experiment.bridge.override_table)
    chain = ControlChain(experiment.estimator, experiment.controller, experiment.bridge)
    applied = table.quantise(experiment.controller.initial_override_pct)
    plant = LathePlant(experiment.plant, initial_override_pct=applied)
    steps = round(experiment.run.duration_s / experiment.run.control_period_s)
    rows = np.empty((steps, len(TRACE_NAMES)))
    reference = experiment.controller.reference_force_n
    out = ControlOutput(applied, 0.0, 0.0)
    if compiled is None and kernel.forced():
        compiled = True
    reason = 'compiled=False' if compiled is False else kernel.why_python(
        experiment.estimator, experiment.controller, experiment.bridge, experiment.plant,
        sections=('lathe_sim',))
    if compiled and reason:
        raise ConfigError(f'{experiment.run.name}: compiled core loop: {reason}')
    k = 0
    while k < steps and (reason or k < python_blocks):
        reference_now = chain.controller.settings.reference_force_n   # before a teach-in
        block = plant.step(applied)
        step = chain.step(block.currents, inputs=block.inputs)
        if keeper is not None:
            keeper.python_block(k, block, step, reference_now)
        out = step.command or out   # the last command stands while the controller is silent
        rows[k] = (
            block.currents.t0_s + len(block.currents) * block.currents.sample_period_s,
            block.force_n[-1], step.estimate.force_n, step.estimate.force_rate_n_s, reference,
            block.depth_mm[-1], block.feed_mm_rev[-1], out.override_pct, applied,
            out.sliding_variable, float(out.reachable),
        )
        applied = step.decision.applied_pct
        k += 1
    if keeper is not None:
        keeper.python_done(chain, k)
    compiled_from = None
    if k < steps:
        compiled_from = k
        _run_compiled(plant, chain, applied, out, rows, k, steps, keeper)
    trace = {name: rows[:, i].copy() for i, name in enumerate(TRACE_NAMES)}
    try:
        metrics = compute_metrics(
            trace['t_s'], trace['force_n'], trace['reference_n'], trace['depth_mm'],
            trace['applied_override_pct'], experiment.plant.depth_profile.change_times_s(),
            experiment.metric_settings, reachable=trace['reference_reachable'] > 0.5,
        )
    except NoCutError:
        metrics = {}
    metrics['realtime_factor'] = experiment.run.duration_s / (time.perf_counter() - wall_start)
    return SimulationResult(trace, metrics, compiled_from,
                            '' if compiled_from == 0 else reason)


def _run_compiled(plant: LathePlant, chain: ControlChain, applied: float, out: ControlOutput,
                  rows: FloatArray, first: int, steps: int, keeper: Keeper | None = None) -> None:
    """Blocks ``first`` .. ``steps - 1`` on the kernel, from the Python objects' state now."""
    jit = kernel.load()
    pp, ps, times, depths = plant.arrays
    ep, es = chain.estimator.arrays_for(float(pp[jit.P_DT]))
    cp, cs, clevels = chain.controller.arrays
    gp, gs, glevels = chain.gate.arrays()
    last = np.array([out.override_pct, out.sliding_variable, float(out.reachable)])
    for start in range(first, steps, CHUNK_BLOCKS):
        end = min(start + CHUNK_BLOCKS, steps)
        noise_u, noise_v, noise_f, noise_fr = plant.draw_noise(end - start)
        if keeper is None:
            applied = jit.run_core(pp, ps, times, depths, noise_u, noise_v, noise_f, noise_fr,
                                   ep, es, cp, cs, clevels, gp, gs, glevels, start, end, applied,
                                   last, rows)
        else:
            t0, u, v, angle, feed, chain_rows = keeper.kernel_arrays()
            applied = jit.run_core_kept(pp, ps, times, depths, noise_u, noise_v, noise_f,
                                        noise_fr, ep, es, cp, cs, clevels, gp, gs, glevels,
                                        start, end, applied, last, rows, t0, u, v, angle, feed,
                                        chain_rows)
    if keeper is not None:
        keeper.kernel_done(first)
