"""Identification against the simulator's truth, on simulated machines.

Each machine is the commissioning experiment (``config/experiments/commissioning.yaml``) with
another plant: PMC dead time 0-120 ms, first- and second-order feed servos, other steels (K_s),
process lags, current noise, force fluctuation and a noisy feed reading (2 mm/min: with a
noise-free one the servo fits are exact and their uncertainties nil), the eight-bit override.
The session is recorded through the core loop (:func:`turning_force.core.kernel.record.record`),
identified (:func:`turning_force.core.identify.identify`), and each estimate printed beside the
truth with its standard deviation and the error. Run:
``.venv/bin/python test/bench/bench_identify.py`` (or ``make bench``). It measures;
``test/core/test_identify.py`` holds the tolerances.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

from turning_force.core.experiment import load_experiment
from turning_force.core.identify import identify
from turning_force.core.kernel.record import record

COMMISSIONING = (Path(__file__).resolve().parents[2] / 'config' / 'experiments'
                 / 'commissioning.yaml')

# name -> lathe_sim changes (and the shared override table for the eight-bit machine)
MACHINES: dict[str, list[str]] = {
    'park (tau 0.17, T 0)': [],
    'kim (T 80 ms)': ['lathe_sim.pmc_dead_time_s=0.08'],
    'slow servo, T 120 ms': ['lathe_sim.servo_time_constant_s=0.3',
                             'lathe_sim.pmc_dead_time_s=0.12',
                             'lathe_sim.specific_cutting_force_n_mm2=1500.0'],
    'fast servo, noisy': ['lathe_sim.servo_time_constant_s=0.1', 'lathe_sim.pmc_dead_time_s=0.02',
                          'lathe_sim.specific_cutting_force_n_mm2=2800.0',
                          'lathe_sim.cutting_time_constant_s=0.1',
                          'lathe_sim.current_noise_a=0.1', 'lathe_sim.feed_noise_mm_min=2.0'],
    '2nd order w_n 8, T 80 ms': ['lathe_sim.servo_model=second_order',
                                 'lathe_sim.servo_natural_freq_rad_s=8.0',
                                 'lathe_sim.servo_damping=0.7', 'lathe_sim.pmc_dead_time_s=0.08',
                                 'lathe_sim.feed_noise_mm_min=2.0'],
    '2nd order w_n 60, K_s 3000': ['lathe_sim.servo_model=second_order',
                                   'lathe_sim.servo_natural_freq_rad_s=60.0',
                                   'lathe_sim.servo_damping=0.7',
                                   'lathe_sim.pmc_dead_time_s=0.04',
                                   'lathe_sim.specific_cutting_force_n_mm2=3000.0',
                                   'lathe_sim.cutting_time_constant_s=0.03',
                                   'lathe_sim.current_noise_a=0.05'],
    '2nd order overdamped, 5 %': ['lathe_sim.servo_model=second_order',
                                  'lathe_sim.servo_natural_freq_rad_s=20.0',
                                  'lathe_sim.servo_damping=1.3', 'lathe_sim.pmc_dead_time_s=0.06',
                                  'lathe_sim.specific_cutting_force_n_mm2=1800.0',
                                  'lathe_sim.force_noise_fraction=0.05'],
    'eight-bit, tau 0.2, T 100 ms': ['/**.override_table=fanuc_8bit',
                                     'lathe_sim.servo_time_constant_s=0.2',
                                     'lathe_sim.pmc_dead_time_s=0.1'],
}

ROWS = (('dead_time_s', 'ms', 1e3), ('time_constant_s', 'ms', 1e3),
        ('natural_freq_rad_s', 'rad/s', 1.0), ('damping', '', 1.0), ('ksd_n_mm', 'N/mm', 1.0),
        ('cutting_time_constant_s', 'ms', 1e3), ('force_noise_n', 'N', 1.0))


def identified(ident, name: str):
    if name == 'ksd_n_mm':
        return ident.ksd_n_mm
    if name == 'cutting_time_constant_s':
        return ident.process[name]
    if name == 'force_noise_n':
        return ident.force_noise_n
    return ident.servo.parameters.get(name)


def main() -> int:
    print(f'{"machine":30s} {"quantity":26s} {"true":>9s} {"identified":>20s} {"error":>8s}')
    for machine, sets in MACHINES.items():
        experiment = load_experiment(COMMISSIONING).with_sets(sets)
        run = record(experiment, machine)
        start = time.perf_counter()
        ident = identify([run.recording])
        took = time.perf_counter() - start
        truth = run.truth()
        chosen = ident.servo.model
        other = 'second_order' if chosen == 'first_order' else 'first_order'
        delta = ident.servo_candidates[other].bic - ident.servo.bic
        print(f'{machine:30s} {"servo model (BIC)":26s} {experiment.plant.servo_model:>9s} '
              f'{chosen:>20s} {"":>8s}  (BIC of {other} {delta:+.0f}; identify {took:.1f} s)')
        for name, unit, scale in ROWS:
            if name not in truth:
                continue
            estimate = identified(ident, name)
            true = truth[name]
            if estimate is None:
                print(f'{"":30s} {name:26s} {true * scale:9.4g} {"(other model)":>20s}')
                continue
            if name == 'dead_time_s':
                error = f'{(estimate.value - true) * 1e3:+.2f}ms'
            else:
                error = f'{(estimate.value / true - 1.0) * 100.0:+.2f}%'
            shown = f'{estimate.value * scale:.4g} +/- {estimate.std * scale:.2g}'
            print(f'{"":30s} {name + (f" [{unit}]" if unit else ""):26s} {true * scale:9.4g} '
                  f'{shown:>20s} {error:>8s}')
        friction = ident.friction_model
        for feed, key in ((friction.min_feed_mm_min, 'at_min_feed_a'),
                          (friction.max_feed_mm_min, 'at_max_feed_a')):
            true = float(experiment.plant.friction.current_a([feed])[0])
            estimate = ident.friction[key]
            shown = f'{estimate.value:.4f} +/- {estimate.std:.1g}'
            print(f'{"":30s} {f"friction at {feed:g} mm/min [A]":26s} {true:9.4f} '
                  f'{shown:>20s} {(estimate.value / true - 1.0) * 100.0:+7.2f}%')
        print(f'{"":30s} residuals: feed {ident.servo.residual_rms:.3g} mm/min, force '
              f'{ident.process.residual_rms:.3g} N, friction {ident.friction.residual_rms:.3g} A')
    return 0


if __name__ == '__main__':
    sys.exit(main())
