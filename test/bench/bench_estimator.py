"""Force-rate estimators side by side: Butterworth + filtered derivative vs steady-state Kalman.

On the fig8 cut with noisy currents, open loop (fixed 100 % override) and closed loop (SMC), it
prints the force and force-rate errors against the simulator's truth, and the closed-loop
metrics with each filter. Run: ``.venv/bin/python test/bench/bench_estimator.py`` (or
``make bench``). It measures; it asserts nothing.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from turning_force.core.estimation.estimator import ForceEstimator
from turning_force.core.estimation.settings import EstimatorSettings
from turning_force.core.experiment import load_experiment
from turning_force.core.kernel.simulate import simulate
from turning_force.core.plant.lathe import LathePlant

FIG8 = Path(__file__).resolve().parents[2] / 'config' / 'experiments' / 'park1998_fig8.yaml'


def open_loop(experiment, force_filter: str, noise_a: float) -> dict[str, float]:
    plant_settings = experiment.plant.replace(current_noise_a=noise_a)
    plant = LathePlant(plant_settings, initial_override_pct=60.0)
    estimator = ForceEstimator(experiment.estimator.replace(force_filter=force_filter))
    truth, rate_truth, est, rate = [], [], [], []
    for _ in range(round(experiment.run.duration_s / experiment.run.control_period_s)):
        block = plant.step(60.0)
        e = estimator.update(block.currents)
        dt = block.currents.sample_period_s
        truth.append(block.force_n[-1])
        rate_truth.append((block.force_n[-1] - block.force_n[-2]) / dt)
        est.append(e.force_n)
        rate.append(e.force_rate_n_s)
    truth_a, est_a = np.array(truth), np.array(est)
    rate_truth_a, rate_a = np.array(rate_truth), np.array(rate)
    steady = np.ones(truth_a.size, dtype=bool)
    for change in (0.0, *experiment.plant.depth_profile.change_times_s()):
        k = round(change / experiment.run.control_period_s)
        steady[k:k + 50] = False   # 0.5 s after each change
    after_step = slice(401, 441)  # the 0.4 s after the 4 s depth step
    return {
        'force_rms_n': float(np.sqrt(np.mean((est_a - truth_a)[steady] ** 2))),
        'rate_rms_n_s': float(np.sqrt(np.mean((rate_a - rate_truth_a)[steady] ** 2))),
        'step_force_rms_n': float(np.sqrt(np.mean((est_a - truth_a)[after_step] ** 2))),
        'step_rate_rms_n_s': float(np.sqrt(np.mean((rate_a - rate_truth_a)[after_step] ** 2))),
    }


def main() -> int:
    experiment = load_experiment(FIG8)
    print(f'{"filter":8s} {"noise A":>8s} {"F rms N":>9s} {"dF rms N/s":>11s} '
          f'{"F rms step":>11s} {"dF rms step":>12s} | {"closed loop: steady N":>22s} '
          f'{"overshoot N":>12s} {"ripple N":>9s} {"override chg/s":>15s}')
    for noise in (0.0, 0.02, 0.05):
        for force_filter in ('lowpass', 'kalman'):
            o = open_loop(experiment, force_filter, noise)
            closed = simulate(experiment.with_sets([
                f'force_estimator.force_filter={force_filter}',
                f'lathe_sim.current_noise_a={noise}']))
            m = closed.metrics
            print(f'{force_filter:8s} {noise:8.2f} {o["force_rms_n"]:9.2f} '
                  f'{o["rate_rms_n_s"]:11.1f} {o["step_force_rms_n"]:11.1f} '
                  f'{o["step_rate_rms_n_s"]:12.0f} | {m["steady_mean_abs_error_n"]:22.2f} '
                  f'{m["overshoot_n"]:12.1f} {m["ripple_p2p_n"]:9.1f} '
                  f'{m["override_changes_per_s"]:15.1f}')
    print('F / dF rms: estimate against the true force and rate, open loop at 60 %, steady '
          'spans;')
    print('"step": the 0.4 s after the 4 s depth step.')
    print(f'defaults: {EstimatorSettings().force_filter}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
