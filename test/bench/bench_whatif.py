"""Closed-loop what-if replay on generated machines (issue 18 item 2): for each machine of the
commissioning issue's generator, its job's session is recorded (the uncommissioned defaults
cutting the job on the machine as it is then, drifted where it drifts), then two candidates are
tried on that session in closed loop (``replay --closed-loop``: the plant identified from the
session itself, on the controller's own override steps; the most typical of the noise draws,
with their range) and against a real run of each on the true machine. Printed: the prediction
within 20 % or 1 N of the real run, and the two candidates ranked as their real runs rank::

    .venv/bin/python test/bench/bench_whatif.py --machines 20 --seed 15
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

from turning_force.commands.core_session import record_core
from turning_force.commands.population import draw, job_experiment
from turning_force.core.kernel.simulate import simulate
from turning_force.session.whatif import what_if

CANDIDATES = (('force_controller.controller=mpc',),
              ('force_controller.quantiser=error_feedback',))
STEADY = 'steady_mean_abs_error_n'


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--machines', type=int, default=20)
    parser.add_argument('--seed', type=int, default=15)
    args = parser.parse_args()
    within = ranked = 0
    for machine in draw(args.machines, args.seed):
        with tempfile.TemporaryDirectory() as folder:
            base = Path(folder)
            job = job_experiment(machine)
            record_core(job, base / 'job')
            pairs = []
            spreads = []
            for candidate in CANDIDATES:
                result = what_if(base / 'job', candidate)
                real = simulate(job.with_sets(list(candidate))).metrics[STEADY]
                pairs.append((result.predicted[STEADY], real))
                spreads.append(result.spread)
        close = all(abs(p - r) <= max(0.2 * r, 1.0) for p, r in pairs)
        order = (pairs[0][0] < pairs[1][0]) == (pairs[0][1] < pairs[1][1])
        within += close
        ranked += order
        print(f'{machine.describe()}: ' + '; '.join(
            f'{c[0].split(".")[1]} predicted {p:.2f} N (draws {lo:.1f}-{hi:.1f}), real {r:.2f} N'
            for c, (p, r), (lo, hi) in zip(CANDIDATES, pairs, spreads, strict=True))
            + ('' if close else '  [outside 20 % / 1 N]') + ('' if order else '  [ranked wrong]'))
    print(f'within 20 % or 1 N: {within} of {args.machines}; ranked right: {ranked} of '
          f'{args.machines}')


if __name__ == '__main__':
    main()
