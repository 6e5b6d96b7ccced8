"""The papers' scenarios, run through the core loop and set beside the papers' own numbers.

``turning-force reproduce`` prints the table. Each row is an experiment file from
``config/experiments/`` (optionally with ``--set`` style changes) and what the paper reports
for it. The steady mean |error| is what the papers call the average tracking error.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from turning_force.core.experiment import load_experiment
from turning_force.core.kernel.simulate import SimulationResult, simulate

__all__ = ['ROWS', 'Row', 'RowResult', 'format_table', 'reproduce']


@dataclass(frozen=True)
class Row:
    label: str
    experiment: str
    paper: str
    sets: tuple[str, ...] = ()


ROWS: tuple[Row, ...] = (
    Row('adaptive, 8-bit', 'park1998_fig1', 'Fig. 1: zero steady-state error'),
    Row('adaptive, 4-bit', 'park1998_fig2', 'Fig. 2: 61.9 N, fluctuates'),
    Row('SMC, ideal override', 'park1998_fig7', 'Fig. 7: as Fig. 8'),
    Row('SMC, 4-bit', 'park1998_fig8', 'Fig. 8: 8.9 N, chatter ~17 N'),
    Row('SMC, 4-bit, Eq. 10 surface, eps 25 N', 'park1998_fig8', 'Fig. 8: 8.9 N',
        ('force_controller.smc_surface=park1998', 'force_controller.smc_epsilon_n=25.0')),
    Row('Kim RLS + pole placement, 8-bit', 'park1998_fig1', '(Kim: 8-bit override)',
        ('force_controller.controller=adaptive_pp',)),
    Row('Kim RLS + pole placement, 4-bit', 'park1998_fig2', '(Park: adaptive fails, 4-bit)',
        ('force_controller.controller=adaptive_pp',)),
    Row('PI (fixed gain), 4-bit', 'park1998_fig8', '(commercial baseline)',
        ('force_controller.controller=pi',)),
    Row('adaptive SMC, 4-bit', 'park1998_fig8', '(Hwang & Chen law on Fig. 8)',
        ('force_controller.controller=adaptive_smc', 'force_controller.asmc_s_t=200.0',
         'force_estimator.kalman_accel_noise_n_s2=1.0e+6')),
    Row('SMC, steel 100 N', 'park1998_fig11', 'Fig. 11: 8.3 N (allowed 10)'),
    Row('SMC, aluminium 50 N', 'park1998_fig13', 'Fig. 13: 4.4 N (allowed 5)'),
    Row('SMC, taper 1-2 mm', 'park1998_fig14', 'Fig. 14: 5.9 N (allowed 10)'),
    Row('adaptive SMC, Example 1', 'hwang1990_example1', 'H&C Fig. 4: back at 1000 N'),
    Row('adaptive SMC, 1 % force noise', 'hwang1990_example1', 'H&C Fig. 7: peaks at steps',
        ('lathe_sim.force_noise_fraction=0.01', 'force_controller.asmc_s_t=200.0')),
)


@dataclass(frozen=True)
class RowResult:
    row: Row
    metrics: dict[str, float]
    allowed_error_n: float
    settled_forces_n: tuple[float, ...]


def settled_forces(result: SimulationResult, change_times_s: Sequence[float],
                   window_s: float = 0.1) -> tuple[float, ...]:
    """Mean true force over the last ``window_s`` before each depth change and the end."""
    t, force = result.trace['t_s'], result.trace['force_n']
    ends = [*change_times_s, float(t[-1]) + 1e-9]
    return tuple(float(np.mean(force[(t >= e - window_s) & (t < e)])) for e in ends)


def reproduce(directory: Path, rows: Sequence[Row] = ROWS) -> list[RowResult]:
    out = []
    for row in rows:
        experiment = load_experiment(directory / f'{row.experiment}.yaml').with_sets(row.sets)
        result = simulate(experiment)
        out.append(RowResult(
            row, result.metrics, experiment.run.allowed_error_n,
            settled_forces(result, experiment.plant.depth_profile.change_times_s())))
    return out


def format_table(results: Sequence[RowResult]) -> str:
    header = (f'{"scenario":38s} {"experiment":19s} {"paper":32s} {"steady":>7s} {"mean":>7s}'
              f' {"ripple":>7s} {"allowed":>7s}  settled force [N]')
    lines = [header, '-' * len(header)]
    for r in results:
        m = r.metrics
        lines.append(
            f'{r.row.label:38s} {r.row.experiment:19s} {r.row.paper:32s}'
            f' {m["steady_mean_abs_error_n"]:7.1f} {m["mean_abs_error_n"]:7.1f}'
            f' {m["ripple_p2p_n"]:7.1f} {r.allowed_error_n:7.1f}  '
            + ' '.join(f'{f:.0f}' for f in r.settled_forces_n))
    lines.append('steady: mean |F - F_ref| [N] leaving out settle_window_s after each change (the '
                 "papers' average tracking error); mean: the same with transients; ripple: "
                 'largest peak-to-peak [N] in the last steady second before each change.')
    return '\n'.join(lines)
