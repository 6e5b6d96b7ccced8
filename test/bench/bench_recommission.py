"""Re-commissioning from yesterday's parts (issue 16 item 2): a machine is commissioned (the
commissioning experiment, ``identify --job``), then drifts (dead time +50 %, process gain +40 %,
feed friction +25 %, servo tau x1.8). The job is cut on the drifted machine with the
commissioned settings (a production session), ``identify`` runs on that session (closed loop,
the friction kept from the settings it ran with), and the job is cut again with what it wrote.
Printed per drift: steady error and ripple of the two cuts and whether the last is in band
(steady <= 5 N, ripple <= 25 N p-p). The machine is Park's Fig. 8 lathe with Kim's 80 ms PMC
dead time, or with ``--machines N`` the first N of the commissioning issue's generator (seed
``--seed``), each with the four drifts of ``bench_drift.py``::

    .venv/bin/python test/bench/bench_recommission.py [--plants 50]
    .venv/bin/python test/bench/bench_recommission.py --machines 6 --seed 16
"""

from __future__ import annotations

import argparse
from collections import Counter
from dataclasses import replace

from bench_drift import drifted

from turning_force.commands.population import commission, draw, park_drifts, run_job
from turning_force.core.verification import BAND_RIPPLE_N, BAND_STEADY_N


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--plants', type=int, default=50)
    parser.add_argument('--machines', type=int, default=0,
                        help="the generator's first N machines (default: Park's lathe)")
    parser.add_argument('--seed', type=int, default=16)
    args = parser.parse_args()
    if args.machines:
        machines = [replace(base, drift=cause, drifted=change)
                    for base in draw(args.machines, args.seed)
                    for cause, change in drifted(replace(base, drift='', drifted={})).items()]
    else:
        machines = park_drifts()
    held: Counter[str] = Counter()
    commissioned: dict[int, list[str]] = {}
    for machine in machines:
        if machine.index not in commissioned:
            if args.machines:
                print(replace(machine, drift='', drifted={}).describe())
            commissioned[machine.index] = commission(machine, plants=args.plants).written
        before = commissioned[machine.index]
        cut = run_job(machine, before)
        again = commission(machine, plants=args.plants, production=before)
        after = run_job(machine, again.written)
        band = (after['steady_mean_abs_error_n'] <= BAND_STEADY_N
                and after['ripple_p2p_n'] <= BAND_RIPPLE_N)
        held[machine.drift] += band
        print(f'  {machine.drift:22s} commissioned file on the drifted machine: steady '
              f'{cut["steady_mean_abs_error_n"]:6.2f} N, ripple {cut["ripple_p2p_n"]:6.1f}'
              f' N; re-identified from that cut ({again.chosen.name}): steady '
              f'{after["steady_mean_abs_error_n"]:6.2f} N, ripple {after["ripple_p2p_n"]:6.1f} N'
              + ('' if band else '  [out of band]'))
    each = len(machines) // len(held)
    print(f'in band after re-identification, of {each}: '
          + ', '.join(f'{drift} {n}' for drift, n in held.items()))


if __name__ == '__main__':
    main()
