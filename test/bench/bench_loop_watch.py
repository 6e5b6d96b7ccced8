"""The oscillation alarm on the generated population (issue 16): how many runs oscillate by the
issue's criterion, how many of those the controller alarms within 2 s of the onset, the alarms
on runs that do not oscillate (none may come on a run in the band), and how many the reaction
brings back under 25 N peak to peak.

Each machine's job (commands/population.py) is cut with the uncommissioned defaults and the
product's error-feedback quantiser, twice: with ``oscillation_reaction: none`` (the oscillation
and the alarm, left alone) and with the product's reaction. The oscillation is judged on the
simulator's true force, independent of the detector: peak to peak over a 1 s window in the cut
above 50 N for at least 2 s (test/core/test_loop_watch.py). The reaction's ripple is the
product's own ``ripple_p2p_n`` (the 1 s before each depth change and before the end, settle
windows left out) over the run from RECOVERY_S after its alarm: a reaction needs a few of the
cycle's periods to bring the loop back (the oscillation itself, before the alarm, is in the
whole run's figure beside it). A run the reaction leaves over the bound is shown with the
window that holds its ripple (the 1 s before which depth change, or before the end): a depth
step's transient under the reaction shows in the window before the next change. A run whose
feed the gate held on overload after the alarm (``overload_force_n``: the cut stopped, 0 N of
ripple from then on) is not calmed, and says so::

    .venv/bin/python test/bench/bench_loop_watch.py --machines 60 --seed 15
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / 'core'))

from test_loop_watch import first_alarm_s, oscillation_onset_s, ripple_after

from turning_force.commands.population import draw, job_experiment
from turning_force.core.experiment import Experiment
from turning_force.core.kernel.simulate import SimulationResult, simulate
from turning_force.core.pmc.settings import Reason

BAND_STEADY_N, BAND_RIPPLE_N = 5.0, 25.0
RECOVERY_S = 3.0


def worst_window_s(result: SimulationResult, job: Experiment, from_s: float) -> float:
    """The end of the ripple window (a depth change, or the run's end) that holds the run's
    ``ripple_p2p_n`` from ``from_s`` on: the first end up to which the run's ripple is all of
    it."""
    whole = ripple_after(result, job, from_s)
    t = result.trace['t_s']
    ends = [c for c in job.plant.depth_profile.change_times_s() if c > from_s]
    for end in ends:
        keep = t < end
        upto = SimulationResult(trace={k: v[keep] for k, v in result.trace.items()},
                                metrics=result.metrics)
        if ripple_after(upto, job, from_s) >= whole:
            return float(end)
    return float(t[-1])


def held_after(result: SimulationResult, alarm_s: float | None) -> bool:
    """Whether the gate held the feed on overload (``overload_force_n``) after the alarm: the
    cut stopped, whatever its ripple says (0 N without a cut)."""
    if alarm_s is None:
        return False
    trace = result.trace
    after = trace['t_s'] >= alarm_s
    return bool(np.any(trace['override_reason'][after] == int(Reason.OVERLOAD_HOLD)))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--machines', type=int, default=60)
    parser.add_argument('--seed', type=int, default=15)
    args = parser.parse_args()
    rows = []
    for machine in draw(args.machines, args.seed):
        job = job_experiment(machine).with_sets(['force_controller.quantiser=error_feedback'])
        left = simulate(job.with_sets(['force_controller.oscillation_reaction=none']))
        reacting = simulate(job)
        reacted, alarm_s = reacting.metrics, first_alarm_s(reacting)
        metrics = left.metrics
        rows.append({
            'machine': machine.describe(), 'onset_s': oscillation_onset_s(left),
            'alarm_s': first_alarm_s(left),
            'in_band': (metrics['steady_mean_abs_error_n'] <= BAND_STEADY_N
                        and metrics['ripple_p2p_n'] <= BAND_RIPPLE_N),
            'ripple_n': metrics['ripple_p2p_n'], 'reacted_ripple_n': reacted['ripple_p2p_n'],
            'recovered_ripple_n': ripple_after(reacting, job, (alarm_s or 0.0) + RECOVERY_S),
            'held': held_after(reacting, alarm_s),
            'worst_s': worst_window_s(reacting, job, (alarm_s or 0.0) + RECOVERY_S),
            'steady_n': metrics['steady_mean_abs_error_n'],
            'reacted_steady_n': reacted['steady_mean_abs_error_n']})
    oscillating = [r for r in rows if r['onset_s'] is not None]
    caught = [r for r in oscillating
              if r['alarm_s'] is not None and r['alarm_s'] <= r['onset_s'] + 2.0]
    in_band = [r for r in rows if r['in_band']]
    false = [r for r in rows if r['onset_s'] is None and r['alarm_s'] is not None]
    calmed = [r for r in oscillating
              if r['recovered_ripple_n'] < BAND_RIPPLE_N and not r['held']]
    print(f'{args.machines} machines (seed {args.seed}), uncommissioned defaults, '
          'error-feedback quantiser')
    print(f"  oscillating (true force, the issue's criterion)  {len(oscillating):4d}")
    print(f'  alarmed within 2 s of the onset                   {len(caught):4d}')
    print(f'  in band                                            {len(in_band):4d}')
    print(f'  alarmed in band                                    '
          f'{sum(r["alarm_s"] is not None for r in in_band):4d}')
    print(f'  alarmed, not oscillating                           {len(false):4d}')
    print(f'  under {BAND_RIPPLE_N:g} N ripple after the reaction            {len(calmed):4d}')
    print(f'  held on overload after the alarm (not calmed)      '
          f'{sum(r["held"] for r in oscillating):4d}')
    for title, group in (('missed or late', [r for r in oscillating if r not in caught]),
                         ('alarmed, not oscillating', false),
                         ('reaction left it over the ripple bound',
                          [r for r in oscillating if r not in calmed])):
        print(f'{title}:')
        for r in group:
            alarm = 'none' if r['alarm_s'] is None else f'{r["alarm_s"]:.2f}'
            held = ', held on overload' if r['held'] else ''
            print(f'  {r["machine"]}{held}: onset {r["onset_s"]}, alarm {alarm}, ripple '
                  f'{r["ripple_n"]:.0f} -> {r["reacted_ripple_n"]:.0f} N (from '
                  f'{RECOVERY_S:g} s after the alarm: {r["recovered_ripple_n"]:.0f} N, '
                  f'the 1 s before {r["worst_s"]:.1f} s), steady '
                  f'{r["steady_n"]:.1f} -> {r["reacted_steady_n"]:.1f} N')


if __name__ == '__main__':
    main()
