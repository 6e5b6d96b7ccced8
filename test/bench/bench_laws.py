"""The control laws side by side: what each costs a control period, compiled, and how each
regulates Park's Fig. 8 and the same cut on machines with a PMC dead time, a noisy drive, a
Kienzle exponent and a second-order servo (the model each law assumes is the machine's: the
laws, not the commissioning, are compared).

Printed per law: the median time of one control period from Python (``Controller.update``,
which the nodes call) and inside the core loop (the whole loop's wall time per period, plant and
estimator included, beside the same loop with the SMC), then steady / mean / ripple and level
changes per second per machine. Measures; asserts nothing.

Run: ``.venv/bin/python test/bench/bench_laws.py`` (``make bench-all`` runs it too).
"""

from __future__ import annotations

import statistics
import time
from pathlib import Path

from turning_force.core import kernel
from turning_force.core.control import CONTROLLERS, ControllerSettings, make_controller
from turning_force.core.experiment import load_experiment
from turning_force.core.kernel.simulate import simulate

FIG8 = Path(__file__).resolve().parents[2] / 'config' / 'experiments' / 'park1998_fig8.yaml'
LAWS = ('smc', 'mpc', 'pi', 'adaptive', 'adaptive_smc', 'adaptive_pp')
PRODUCT = ['force_controller.quantiser=error_feedback', 'force_controller.smc_epsilon_n=0.0']
MACHINES = {
    'fig8': [],
    'dead time 100 ms': ['lathe_sim.pmc_dead_time_s=0.1',
                         'force_controller.model_dead_time_s=0.1'],
    'noisy drive': ['lathe_sim.current_noise_a=0.1', 'lathe_sim.force_noise_fraction=0.05'],
    'Kienzle g = 0.8': ['lathe_sim.cutting_exponent=0.8',
                        'lathe_sim.specific_cutting_force_n_mm2=1600.0',
                        'force_controller.model_cutting_exponent=0.8'],
    'second-order servo': ['lathe_sim.servo_model=second_order',
                           'lathe_sim.servo_natural_freq_rad_s=12.0',
                           'lathe_sim.servo_damping=0.5',
                           'force_controller.model_servo_model=second_order',
                           'force_controller.model_servo_natural_freq_rad_s=12.0',
                           'force_controller.model_servo_damping=0.5'],
}


def period_from_python_us(name: str, calls: int = 20000) -> float:
    law = make_controller(ControllerSettings(controller=name))
    for _ in range(100):
        law.update(480.0, 0.0)
    start = time.perf_counter()
    for k in range(calls):
        law.update(480.0 + (k % 7), 0.0)
    return (time.perf_counter() - start) / calls * 1e6


def period_in_loop_us(name: str, runs: int = 5) -> float:
    experiment = load_experiment(FIG8).with_sets([*PRODUCT, f'force_controller.controller={name}'])
    steps = experiment.run.duration_s / experiment.run.control_period_s
    walls = []
    for _ in range(runs):
        start = time.perf_counter()
        simulate(experiment)
        walls.append(time.perf_counter() - start)
    return statistics.median(walls) / steps * 1e6


def main() -> None:
    kernel.load()
    print(f'laws installed: {", ".join(CONTROLLERS)}\n')
    print(f'{"law":14s} {"period from Python [us]":>24s} {"period in the core loop [us]":>29s}')
    for name in LAWS:
        print(f'{name:14s} {period_from_python_us(name):24.2f} {period_in_loop_us(name):29.2f}')
    print('\n(the control period is 10,000 us)\n')
    print(f'{"machine":20s} {"law":14s} {"steady N":>9s} {"mean N":>8s} {"ripple N":>9s} '
          f'{"changes/s":>10s}')
    for machine, sets in MACHINES.items():
        for name in LAWS:
            experiment = load_experiment(FIG8).with_sets(
                [*PRODUCT, *sets, f'force_controller.controller={name}'])
            m = simulate(experiment).metrics
            steady, mean, ripple, changes = (m.get(key, float('nan')) for key in (
                'steady_mean_abs_error_n', 'mean_abs_error_n', 'ripple_p2p_n',
                'override_changes_per_s'))
            print(f'{machine:20s} {name:14s} {steady:9.2f} {mean:8.2f} {ripple:9.1f} '
                  f'{changes:10.1f}')


if __name__ == '__main__':
    main()
