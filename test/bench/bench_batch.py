"""The batch API (core/batch.py) on the kernel beside the Python paths, in one run.

Prints, side by side so that the ratios hold on a noisy machine (min / median of several runs):

- replay of Fig. 8's committed reference session (bags/reference/park1998_fig8, 1200 blocks):
  reading it, then the chain through ``replay_chain`` two ways: the per-block loop
  (ControlChain, one call of the compiled estimator, controller and gate per block: what the
  nodes do) and the compiled loop (``jit.replay_blocks``); then ``replay()`` whole;
- replay of a synthetic one-hour run (``run_core`` of Fig. 8 with ``duration_s`` 3600:
  360,000 blocks): the compiled loop on all of it, the per-block loop on its first minute
  (6,000 blocks; its hour extrapolated, marked ``~``);
- ``run_core`` (every sample, estimate, command and decision kept) beside ``simulate`` on the
  kernel: microseconds per 10 ms period, for Fig. 8 (12 s) and for the hour.

Run: ``.venv/bin/python test/bench/bench_batch.py`` (or ``make bench``). Measures; asserts
nothing (``test/core/test_batch.py`` holds the compiled loops to the per-block one).
"""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from turning_force.core import kernel
from turning_force.core.experiment import load_experiment
from turning_force.core.kernel import batch
from turning_force.core.kernel.simulate import simulate
from turning_force.session.reader import Session, read_session
from turning_force.session.replay import _currents, _inputs, _recorded_reference, replay

ROOT = Path(__file__).resolve().parents[2]
FIG8 = ROOT / 'config' / 'experiments' / 'park1998_fig8.yaml'
REFERENCE = ROOT / 'bags' / 'reference' / 'park1998_fig8'
HOUR_S = 3600.0
SLICE_BLOCKS = 6000


def timed(function: Callable[[], Any], runs: int) -> tuple[list[float], Any]:
    times, result = [], None
    for _ in range(runs):
        start = time.perf_counter()
        result = function()
        times.append(time.perf_counter() - start)
    return times, result


def row(label: str, blocks: int, times: list[float], total_blocks: int | None = None) -> str:
    """us per block (min, median) and the total for ``total_blocks`` (measured, or
    extrapolated with ``~`` where fewer blocks ran)."""
    best, median = min(times), statistics.median(times)
    total_blocks = total_blocks or blocks
    mark = '~' if total_blocks != blocks else ' '
    return (f'{label:44s} {best / blocks * 1e6:10.2f} {median / blocks * 1e6:10.2f} '
            f'{mark}{median / blocks * total_blocks:9.2f} {len(times):5d}')


HEADER = f'{"":44s} {"us/blk min":>10s} {"us/blk med":>10s} {"total s":>10s} {"runs":>5s}'


def per_block_loop(experiment: Any, currents: batch.CurrentArrays, changes: Any,
                   inputs: Any, reference: float | None) -> batch.ChainTrace:
    """Today's replay loop: ControlChain block by block, its estimator and controller on the
    kernel (one call each per block)."""
    return batch._replay_python(experiment, currents.block, len(currents), changes, inputs,
                                reference, None)


def session_of(run: batch.CoreRun, experiment: Any) -> Session:
    """A Session of a core run, as the reader would give it for its recording (no bag)."""
    c, chain = run.currents, run.chain
    signals = {
        'estimated_force_n': chain.estimated_force_n,
        'estimated_force_rate_n_s': chain.estimated_force_rate_n_s,
        'estimate_status': chain.estimate_status.astype(float),
        'requested_override_pct': chain.requested_override_pct,
        'reference_n': chain.reference_n, 'sliding_variable': chain.sliding_variable,
        'reference_reachable': chain.reference_reachable.astype(float),
        'answered_override_pct': chain.applied_pct, 'override_reason': chain.reason.astype(float),
        'program_enable': chain.program_enable.astype(float),
        'threading': chain.threading.astype(float), 'operator_dial_pct': chain.operator_dial_pct,
        'engaged': chain.engaged.astype(float), 'alarm': chain.alarm.astype(float),
        'stop_request': chain.stop_request.astype(float),
        'force_n': run.plant['force_n'], 'depth_mm': run.plant['depth_mm'],
        'feed_mm_rev': run.plant['feed_mm_rev'], 'applied_override_pct': run.plant['override_pct'],
    }
    stamps = np.round((c.t_end_s - c.sample_period_s) * 1e9).astype(np.int64)
    return Session(Path('synthetic'), {}, experiment, c, c.t_end_s, stamps, signals,
                   has_truth=True, arm_changes=[(0.0, experiment.bridge.armed)])


def differences(a: batch.ChainTrace, b: batch.ChainTrace) -> str:
    force = float(np.nanmax(np.abs(a.estimated_force_n - b.estimated_force_n)))
    overrides = int(np.count_nonzero(a.applied_pct != b.applied_pct))
    return f'max |force difference| {force:.3g} N, {overrides} overrides differ'


def main() -> int:
    print(f'kernel: numba, cache {"warm" if kernel.cache_is_warm() else "cold"}; loading ...',
          flush=True)
    start = time.perf_counter()
    kernel.load()
    print(f'kernel loaded in {time.perf_counter() - start:.2f} s\n')

    # --- the reference session ------------------------------------------------------------
    read_times, session = timed(lambda: read_session(REFERENCE), 3)
    assert session.experiment is not None
    e = session.experiment
    currents = _currents(session)
    assert isinstance(currents, batch.CurrentArrays)
    inputs, changes = _inputs(session), list(session.arm_changes)
    reference = _recorded_reference(session, e, ())
    n = len(currents)
    print(f'replay of {REFERENCE.relative_to(ROOT)} ({n} blocks)')
    print(HEADER)
    print(row('read_session (whole)', n, read_times))
    loop_times, loop = timed(lambda: per_block_loop(e, currents, changes, inputs, reference), 3)
    print(row("per-block loop, kernel components (today's)", n, loop_times))
    kernel_times, compiled = timed(lambda: batch.replay_chain(
        e, currents, changes, inputs, reference), 20)
    print(row('replay_chain, kernel', n, kernel_times))
    replay_times, _ = timed(lambda: replay(session), 5)
    print(row('replay() whole (kernel, metrics)', n, replay_times))
    ratio = statistics.median(loop_times) / statistics.median(kernel_times)
    print(f'kernel / per-block loop: {ratio:.0f}x; kernel vs the loop: '
          f'{differences(compiled, loop)}\n')

    # --- a synthetic hour -----------------------------------------------------------------
    fig8 = load_experiment(FIG8)
    hour = fig8.with_sets([f'experiment.duration_s={HOUR_S}'])
    core_times, run = timed(lambda: batch.run_core(hour), 1)
    blocks = len(run.currents)
    armed = [(0.0, hour.bridge.armed)]
    print(f'replay of a synthetic hour (run_core of Fig. 8, {blocks} blocks; '
          f'{run.currents.phase_u_a.nbytes * 4 / 1e6:.0f} MB of currents)')
    print(HEADER)
    head = batch.CurrentArrays(run.currents.t0_s[:SLICE_BLOCKS], run.currents.sample_period_s,
                               run.currents.phase_u_a[:SLICE_BLOCKS],
                               run.currents.phase_v_a[:SLICE_BLOCKS],
                               run.currents.rotor_angle_rad[:SLICE_BLOCKS],
                               run.currents.feed_rate_mm_min[:SLICE_BLOCKS])
    loop_times, _ = timed(lambda: per_block_loop(hour, head, armed, None, None), 1)
    print(row('per-block loop, kernel components (1st min)', SLICE_BLOCKS, loop_times, blocks))
    kernel_times, compiled = timed(lambda: batch.replay_chain(hour, run.currents, armed), 3)
    print(row('replay_chain, kernel', blocks, kernel_times))
    ratio = statistics.median(loop_times) / SLICE_BLOCKS * blocks / statistics.median(kernel_times)
    print(f'kernel / per-block loop: {ratio:.0f}x; the hour replayed against its run: '
          f'{differences(compiled, run.chain)}')
    hour_session = session_of(run, hour)
    replay_times, result = timed(lambda: replay(hour_session), 2)
    print(row('replay() whole (kernel, metrics; no bag)', blocks, replay_times))
    print(f'  its differing overrides: {result.differing_overrides}\n')

    # --- run_core beside simulate ---------------------------------------------------------
    print('closed loop on the kernel: run_core (everything kept) beside simulate (its trace)')
    print(HEADER)
    periods = round(fig8.run.duration_s / fig8.run.control_period_s)
    simulate_times, _ = timed(lambda: simulate(fig8), 20)
    print(row('simulate, Fig. 8 (12 s)', periods, simulate_times))
    core12_times, _ = timed(lambda: batch.run_core(fig8), 20)
    print(row('run_core, Fig. 8 (12 s)', periods, core12_times))
    hour_sim_times, _ = timed(lambda: simulate(hour), 2)
    print(row('simulate, an hour', blocks, hour_sim_times))
    more_core, _ = timed(lambda: batch.run_core(hour), 1)
    print(row('run_core, an hour', blocks, core_times + more_core))
    print(f'run_core / simulate: Fig. 8 '
          f'{statistics.median(core12_times) / statistics.median(simulate_times):.2f}x, an hour '
          f'{statistics.median(core_times + more_core) / statistics.median(hour_sim_times):.2f}x')
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
