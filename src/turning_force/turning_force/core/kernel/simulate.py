"""The closed loop in one function, no ROS: plant -> control chain (estimator, controller, PMC
gate) -> plant.

Each control period the plant delivers one block of currents at the override the PMC applied in
the period before, and the chain's gate decides what is applied for the next block: the same
one-period delay and the same gate as the node graph, so both give the same numbers. The loop is
compiled (``run_core`` of :mod:`turning_force.core.kernel.loops`), over stretches of blocks whose
noise is drawn in advance from the plant's own generator.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from turning_force.core import kernel
from turning_force.core.errors import NoCutError
from turning_force.core.experiment import Experiment
from turning_force.core.kernel.chain import ControlChain
from turning_force.core.metrics import compute_metrics
from turning_force.core.plant.lathe import LathePlant
from turning_force.core.plant.settings import PlantSettings
from turning_force.core.pmc.gate import CUT_FIELDS

__all__ = ['SimulationResult', 'simulate']

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
    'oscillation_alarm',    # 1 while the controller's oscillation alarm holds, else 0
    'spindle_speed_rpm',    # the spindle's true speed at the end of the block
    'override_reason',      # why the override answering the block is what it is (Reason)
    'drift_alarm',          # what the drift monitor found drifted (control.drift.CAUSES), 0 none
    'drift_size',           # by how much (relative; seconds for the dead time)
    'drift_adopted',        # the lag drift the law predicts with (drift.CAUSES), 0 commissioned
    'drift_adopted_size',   # the member of the monitor's bank (relative; seconds added)
)


@dataclass
class SimulationResult:
    """Traces sampled at the control period, and the metrics of the run."""

    trace: dict[str, FloatArray]
    metrics: dict[str, float] = field(default_factory=dict)
    # The cuts that ended during the run (the gate's cut log, CUT_* rows of the kernel).
    cut_rows: FloatArray = field(default_factory=lambda: np.empty((0, 0)))
    # The drift monitor's alarm at the end, in words ('' none: control.drift.drift_text).
    drift: str = ''


# Blocks per call of the kernel: the plant's noise for them is drawn in advance.
CHUNK_BLOCKS = 4096

# The noise of the last run of one stretch: a function of the plant's settings (its seed among
# them), its samples per block and the stretch's length alone, and only read by the kernel.
# The commissioning's verification runs each plant under a dozen candidates one after the
# other, and drawing it block by block is a tenth of such a run.
Noise = tuple[FloatArray, FloatArray, FloatArray, FloatArray]
_last_noise: dict[tuple[PlantSettings, int, int], Noise] = {}
_noise_lock = threading.Lock()


def _noise(plant: LathePlant, blocks: int) -> Noise:
    """``plant.draw_noise(blocks)`` for a run of one stretch (``blocks`` <= CHUNK_BLOCKS),
    the last run's arrays again where its plant and length were the same."""
    key = (plant.settings, plant.samples_per_block, blocks)
    with _noise_lock:
        kept = _last_noise.get(key)
    if kept is None:
        kept = plant.draw_noise(blocks)
        with _noise_lock:
            _last_noise.clear()
            _last_noise[key] = kept
    return kept


def simulate(experiment: Experiment) -> SimulationResult:
    """Run an experiment through the core loop; deterministic for a given file and seed."""
    return run_loop(experiment)


def run_loop(experiment: Experiment, kept: tuple[FloatArray, ...] = ()) -> SimulationResult:
    """:func:`simulate`, keeping every block as well where ``kept`` gives the arrays to keep it
    in (``jit.run_core_kept``): the blocks' first stamps (n,), the samples u, v, angle and feed
    rate (n, m each) and the chain's rows (n, ``jit.CHAIN_COLUMNS``)."""
    wall_start = time.perf_counter()
    jit = kernel.load()
    steps = round(experiment.run.duration_s / experiment.run.control_period_s)
    dt = 1.0 / experiment.plant.sample_rate_hz
    # The chain in its order: the estimator, the controller, the PMC gate (and the level the
    # PMC starts at) ...
    chain = ControlChain(experiment.estimator, experiment.controller, experiment.bridge)
    ep, es, cp, cs, clevels, gp, gs, glevels, ctools, gtools = chain.arrays(dt)
    applied = experiment.plant.approach_override_pct
    # ... and the lathe it acts on: its arrays, the machine's inputs at each block's end, and
    # when the depth changes (for the metrics).
    plant = LathePlant(experiment.plant, initial_override_pct=applied)
    pp, ps, times, depths = plant.arrays
    n = plant.samples_per_block
    t_end = (np.arange(steps) * n).astype(np.float64) * dt + n * dt
    inputs = np.ascontiguousarray(experiment.plant.inputs_array(t_end))
    depth_changes_s = experiment.plant.depth_profile.change_times_s()
    rows = np.empty((steps, len(TRACE_NAMES)))
    cuts = np.zeros((steps // 2 + 1, CUT_FIELDS))
    ncuts = np.zeros(1)
    last = np.array([applied, 0.0, 1.0, 0.0, 0.0, 0.0])
    for start in range(0, steps, CHUNK_BLOCKS):
        end = min(start + CHUNK_BLOCKS, steps)
        noise_u, noise_v, noise_f, noise_fr = (_noise(plant, steps)
                                               if steps <= CHUNK_BLOCKS
                                               else plant.draw_noise(end - start))
        if not kept:
            applied = jit.run_core(pp, ps, times, depths, noise_u, noise_v, noise_f, noise_fr,
                                   ep, es, cp, cs, clevels, gp, gs, glevels, ctools, gtools,
                                   start, end, applied, last, rows, inputs, cuts, ncuts)
        else:
            applied = jit.run_core_kept(pp, ps, times, depths, noise_u, noise_v, noise_f,
                                        noise_fr, ep, es, cp, cs, clevels, gp, gs, glevels,
                                        ctools, gtools, start, end, applied, last, rows,
                                        inputs, cuts, ncuts, *kept)
    trace = {name: rows[:, i].copy() for i, name in enumerate(TRACE_NAMES)}
    # The metrics' reference is the experiment's, also where a learning cut sets another; with
    # a tools file, each tool's (the controller's, block by block).
    if not experiment.controller.tools_file:
        trace['reference_n'] = np.full(steps, experiment.controller.reference_force_n)
    try:
        metrics = compute_metrics(
            trace['t_s'], trace['force_n'], trace['reference_n'], trace['depth_mm'],
            trace['applied_override_pct'], depth_changes_s,
            experiment.metric_settings, reachable=trace['reference_reachable'] > 0.5,
            estimate_n=trace['estimated_force_n'], oscillation_alarm=trace['oscillation_alarm'],
            drift_alarm=trace['drift_alarm'] if experiment.controller.drift_monitor else None)
    except NoCutError:
        metrics = {}
    metrics['realtime_factor'] = experiment.run.duration_s / (time.perf_counter() - wall_start)
    return SimulationResult(trace, metrics, cuts[:min(int(ncuts[0]), len(cuts))].copy(),
                            chain.controller.drift)
