"""Grooved shafts on generated machines (issue 16 item 4, interruptions the gate does not see):
each machine of the commissioning issue's generator (undrifted) is commissioned as the user's
flow does it for its own job (:func:`turning_force.commands.population.commission`), then cuts
a shaft 2 mm deep with a gap of air every second, after a 1 s approach in air, for each gap
length asked. The gate sees the tool leave once the force is under ``exit_force_n``; behind a
slow process lag a short gap is never seen (the force takes tau_c ln(F / exit_force_n) to get
there: 0.35 s from 500 N at tau_c 0.15 s). Printed per machine and gap: the largest excursion
above the reference after an entry (``entry_overshoot_n``), the oscillation alarms and the
in-cut mean error, commissioned and with the uncommissioned defaults; and per gap how many
machines keep every entry within the issue's 100 N and raise no alarm::

    .venv/bin/python test/bench/bench_grooves.py --machines 30 --seed 15
    .venv/bin/python test/bench/bench_grooves.py --machines 30 --seed 42 --gaps 0.15 0.25
"""

from __future__ import annotations

import argparse
from dataclasses import replace

from turning_force.commands.population import commission, draw, job_experiment
from turning_force.core.kernel.simulate import simulate

ENTRY_BOUND_N = 100.0   # issue 16: at most 100 N above the reference at any entry
APPROACH_S, PERIOD_S, PIECES, DEPTH_MM = 1.0, 1.0, 8, 2.0


def grooved(gap_s: float) -> list[str]:
    """The grooved shaft: PIECES pieces every PERIOD_S after APPROACH_S in air, the tool in
    air for the last ``gap_s`` of each but the last."""
    times, depths = [0.0, APPROACH_S], [0.0, DEPTH_MM]
    for k in range(1, PIECES):
        times += [APPROACH_S + k * PERIOD_S - gap_s, APPROACH_S + k * PERIOD_S]
        depths += [0.0, DEPTH_MM]
    return [f'lathe_sim.depth_times_s={times}', f'lathe_sim.depth_mm={depths}',
            'lathe_sim.depth_interpolation=step', 'force_controller.quantiser=error_feedback',
            f'experiment.duration_s={APPROACH_S + PIECES * PERIOD_S}']


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--machines', type=int, default=30)
    parser.add_argument('--seed', type=int, default=15)
    parser.add_argument('--plants', type=int, default=50)
    parser.add_argument('--gaps', type=float, nargs='+', default=[0.1, 0.2, 0.3, 0.5])
    args = parser.parse_args()
    clean = {gap: [0, 0] for gap in args.gaps}   # commissioned, defaults
    for base in draw(args.machines, args.seed):
        machine = replace(base, drift='', drifted={}, approach_s=APPROACH_S)
        written = commission(machine, plants=args.plants).written
        job = job_experiment(machine)
        line = [machine.describe()]
        for gap in args.gaps:
            cells = []
            for which, sets in enumerate((written, [])):
                m = simulate(job.with_sets([*sets, *grooved(gap)])).metrics
                ok = m['entry_overshoot_n'] <= ENTRY_BOUND_N and m['oscillation_alarms'] == 0
                clean[gap][which] += ok
                cells.append(f'{m["entry_overshoot_n"]:4.0f} N{"" if ok else "!"} '
                             f'{int(m["oscillation_alarms"])} {m["mean_abs_error_n"]:5.1f} N')
            line.append(f'gap {gap:g} s: {cells[0]} (defaults {cells[1]})')
        print('; '.join(line), flush=True)
    print(f'{args.machines} machines, seed {args.seed}, 2 mm with a gap every {PERIOD_S:g} s '
          f'(entry overshoot, alarms, mean error; ! over {ENTRY_BOUND_N:g} N or alarmed):')
    for gap in args.gaps:
        print(f'  gap {gap:g} s: every entry within {ENTRY_BOUND_N:g} N and no alarm on '
              f'{clean[gap][0]} commissioned, {clean[gap][1]} with the defaults')


if __name__ == '__main__':
    main()
