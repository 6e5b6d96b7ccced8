"""The robustness matrix (issue: regulation that holds on a real machine), printed.

Fig. 8 on fifteen machines, each for the SMC tuned from the machine's model, the fixed-gain PI
and the conventional adaptive controller, with the floor no causal controller beats on that
machine (:func:`turning_force.commands.robustness.mean_floor_n`: a clairvoyant-from-the-step
bang-bang controller on the noise-free plant with a continuous override). Then, side by side on
the same machines, the SMC with the PMC's nearest level against the error-feedback quantiser,
and the integral surface against El Khalick's nonlinear one. Run: ``.venv/bin/python
test/bench/bench_matrix.py`` (or ``make bench``). It measures; it asserts nothing
(``test/core/test_matrix.py`` holds the bands).
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

from turning_force.commands.robustness import (
    CONTROLLERS,
    MATRIX,
    mean_floor_n,
    run_scenario,
    scenario_experiment,
)

EXPERIMENTS = Path(__file__).resolve().parents[2] / 'config' / 'experiments'


def main() -> int:
    start = time.perf_counter()
    header = (f'{"scenario":24s} {"law":9s} {"steady":>7s} {"mean":>7s} {"max":>7s} '
              f'{"ripple":>7s} {"chg/s":>6s} {"reach":>6s} {"floor":>6s} {"mean/floor":>10s}')
    print('Robustness matrix: Fig. 8 (500 N, depth 1-2-3 mm), core loop; forces in N')
    print(header)
    print('-' * len(header))
    variants: list[tuple[str, dict[str, float], dict[str, float], dict[str, float]]] = []
    for scenario in MATRIX:
        floor = mean_floor_n(scenario_experiment(EXPERIMENTS, scenario, 'smc'))
        for law in CONTROLLERS:
            m = run_scenario(scenario_experiment(EXPERIMENTS, scenario, law))
            print(f'{scenario.name if law == "smc" else "":24s} {law:9s} '
                  f'{m["steady_mean_abs_error_n"]:7.2f} {m["mean_abs_error_n"]:7.2f} '
                  f'{m["max_abs_error_n"]:7.1f} {m["ripple_p2p_n"]:7.1f} '
                  f'{m["override_changes_per_s"]:6.1f} {m["reachable_fraction"]:6.2f} '
                  f'{floor:6.2f} {m["mean_abs_error_n"] / floor:10.2f}', flush=True)
        smc = scenario_experiment(EXPERIMENTS, scenario, 'smc')
        variants.append((
            scenario.name,
            run_scenario(smc.with_sets(['force_controller.quantiser=nearest'])),
            run_scenario(smc),
            run_scenario(smc.with_sets(['force_controller.smc_surface=nonlinear'])),
        ))
    print()
    print('SMC variants: steady / mean / ripple p-p [N]')
    print(f'{"scenario":24s} {"nearest level":>22s} {"error feedback":>22s} '
          f'{"nonlinear surface":>22s}')

    def cell(m: dict[str, float]) -> str:
        return (f'{m["steady_mean_abs_error_n"]:6.2f} {m["mean_abs_error_n"]:6.2f} '
                f'{m["ripple_p2p_n"]:7.1f}')

    for name, nearest, feedback, nonlinear in variants:
        print(f'{name:24s} {cell(nearest):>22s} {cell(feedback):>22s} {cell(nonlinear):>22s}')
    print()
    print('steady: mean |F - F_ref| leaving out 1 s after each change and where the reference '
          'was out of reach (reach: the share where it was not); mean: from engagement, '
          'transients included; ripple: largest peak-to-peak in the last steady second before '
          'each depth change and the end; chg/s: override changes per second. floor: the '
          'full-run mean of a controller that knows each depth step the instant it happens '
          '(bang-bang then hold, continuous override, no noise).')
    print(f'({time.perf_counter() - start:.0f} s)')
    return 0


if __name__ == '__main__':
    sys.exit(main())
