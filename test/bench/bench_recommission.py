"""Re-commissioning from yesterday's parts (issue 16 item 2): Park's Fig. 8 machine with Kim's
80 ms PMC dead time is commissioned (the commissioning experiment, ``identify --job``), then
drifts (dead time +50 %, process gain +40 %, feed friction +25 %, servo tau x1.8). The job is
cut on the drifted machine with the commissioned settings (a production session), ``identify``
runs on that session (closed loop, the friction kept from the settings it ran with), and the
job is cut again with what it wrote. Printed per drift: steady error and ripple of the three
cuts and whether the last is in band (steady <= 5 N, ripple <= 25 N p-p)::

    .venv/bin/python test/bench/bench_recommission.py [--plants 50]
"""

from __future__ import annotations

import argparse

from turning_force.commands.population import commission, park_drifts, run_job
from turning_force.core.verification import BAND_RIPPLE_N, BAND_STEADY_N


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--plants', type=int, default=50)
    args = parser.parse_args()
    held = 0
    for machine in park_drifts():
        before = commission(machine, plants=args.plants).chosen.sets
        drifted = run_job(machine, before)
        again = commission(machine, plants=args.plants, production=before)
        after = run_job(machine, again.chosen.sets)
        band = (after['steady_mean_abs_error_n'] <= BAND_STEADY_N
                and after['ripple_p2p_n'] <= BAND_RIPPLE_N)
        held += band
        print(f'{machine.drift:22s} commissioned file on the drifted machine: steady '
              f'{drifted["steady_mean_abs_error_n"]:6.2f} N, ripple {drifted["ripple_p2p_n"]:6.1f}'
              f' N; re-identified from that cut ({again.chosen.name}): steady '
              f'{after["steady_mean_abs_error_n"]:6.2f} N, ripple {after["ripple_p2p_n"]:6.1f} N'
              + ('' if band else '  [out of band]'))
    print(f'in band after re-identification: {held} of {len(park_drifts())}')


if __name__ == '__main__':
    main()
