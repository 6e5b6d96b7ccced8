"""The robustness matrix: Fig. 8's cut on machines the controller was not tuned on.

A stock FANUC brings a PMC dead time (Kim measured 0.08 s), a servo that is not Park's, a
process gain that differs from the shop's guess, noisy current sensors, a fluctuating force,
or an eight-bit override. Each row runs Fig. 8 (500 N, depth 1-2-3 mm) on one such machine
through the core loop, for the sliding mode controller tuned from the machine's model (what
``turning-force identify`` finds), the commercial-style PI and the conventional adaptive
controller, and sets each beside the floor no causal controller can beat (:func:`mean_floor_n`).

``make bench`` prints it (``test/bench/bench_matrix.py``); ``test/core/test_matrix.py`` holds
the SMC's bands.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from turning_force.core.experiment import Experiment, assignments, load_experiment
from turning_force.core.identify import identify
from turning_force.core.kernel.record import record
from turning_force.core.kernel.simulate import simulate
from turning_force.core.plant.lathe import LathePlant

__all__ = ['CONTROLLERS', 'MATRIX', 'Scenario', 'identified_sets', 'mean_floor_n', 'run_scenario',
           'scenario_experiment']

FIG8 = 'park1998_fig8.yaml'


@dataclass(frozen=True)
class Scenario:
    """One machine: the ``lathe_sim`` (and table) changes from Fig. 8's, and the bands the
    identified SMC must keep there (``None``: the reference is not reachable throughout)."""

    name: str
    sets: tuple[str, ...]
    max_mean_n: float | None = 15.0
    max_ripple_n: float = 20.0


MATRIX: tuple[Scenario, ...] = (
    Scenario('dead time 0 ms', ()),
    Scenario('dead time 40 ms', ('lathe_sim.pmc_dead_time_s=0.04',)),
    Scenario('dead time 80 ms', ('lathe_sim.pmc_dead_time_s=0.08',)),
    Scenario('dead time 120 ms', ('lathe_sim.pmc_dead_time_s=0.12',), max_mean_n=20.0),
    Scenario('servo tau 0.1 s', ('lathe_sim.servo_time_constant_s=0.1',)),
    Scenario('servo tau 0.17 s', ('lathe_sim.servo_time_constant_s=0.17',)),
    Scenario('servo tau 0.3 s', ('lathe_sim.servo_time_constant_s=0.3',)),
    Scenario('servo 2nd order w_n 8', ('lathe_sim.servo_model=second_order',
                                       'lathe_sim.servo_natural_freq_rad_s=8.0',
                                       'lathe_sim.servo_damping=0.7')),
    Scenario('servo 2nd order w_n 60', ('lathe_sim.servo_model=second_order',
                                        'lathe_sim.servo_natural_freq_rad_s=60.0',
                                        'lathe_sim.servo_damping=0.7')),
    # At 1 mm and K_s x 0.7 even 150 % gives only 462 N: the first third is unreachable.
    Scenario('K_s x 0.7', ('lathe_sim.specific_cutting_force_n_mm2=1540.0',), max_mean_n=None),
    Scenario('K_s x 1.4', ('lathe_sim.specific_cutting_force_n_mm2=3080.0',)),
    Scenario('current noise 0.02 A', ('lathe_sim.current_noise_a=0.02',)),
    Scenario('current noise 0.1 A', ('lathe_sim.current_noise_a=0.1',), max_ripple_n=35.0),
    Scenario('force fluctuation 5 %', ('lathe_sim.force_noise_fraction=0.05',)),
    Scenario('8-bit override', ('/**.override_table=fanuc_8bit',)),
)

# The product's regulation settings (what a shop runs), on top of the Fig. 8 file.
PRODUCT = ('force_controller.quantiser=error_feedback', 'force_controller.smc_epsilon_n=0.0')

CONTROLLERS: dict[str, tuple[str, ...]] = {
    'smc': ('force_controller.controller=smc', 'force_controller.smc_surface=integral'),
    'pi': ('force_controller.controller=pi',),
    'adaptive': ('force_controller.controller=adaptive',),
}


COMMISSIONING = 'commissioning.yaml'


def identified_sets(directory: Path, scenario: Scenario) -> tuple[str, ...]:
    """The SMC's machine model as ``turning-force identify`` finds it on this machine: the
    commissioning experiment (an override staircase in air, then in a 1 mm cut) run on the
    scenario's plant, identified, and the K_s d bounds scaled to Fig. 8's depths (1-3 mm).
    The estimator keeps its settings: the friction is the machine's own here, and a force
    filter set to the measured noise regulates worse than the default (it lags)."""
    commissioning = load_experiment(directory / COMMISSIONING).with_sets(scenario.sets)
    fig8_depths = load_experiment(directory / FIG8).plant.depth_mm
    key = repr((commissioning.resolved_params(), fig8_depths))
    if key not in _IDENTIFIED:   # scenarios that differ only in a default share one machine
        _IDENTIFIED[key] = _identified(commissioning, fig8_depths)
    return _IDENTIFIED[key]


_IDENTIFIED: dict[str, tuple[str, ...]] = {}


def _identified(commissioning: Experiment, fig8_depths: tuple[float, ...]) -> tuple[str, ...]:
    ident = identify([record(commissioning).recording])
    cut_depth = max(commissioning.plant.depth_mm)
    low, high = ident.ksd_bounds_n_mm(depth_scale=(min(fig8_depths) / cut_depth,
                                                   max(fig8_depths) / cut_depth))
    return tuple(assignments('force_controller', ident.controller_parameters(low, high)))


def scenario_experiment(directory: Path, scenario: Scenario, controller: str,
                        tuning: Callable[[Experiment], tuple[str, ...]] | None = None
                        ) -> Experiment:
    """Fig. 8 on the scenario's machine, with the product's settings and ``controller``; the
    SMC gets the machine model ``tuning`` gives, by default what ``turning-force identify``
    finds from the commissioning experiment on the same machine (:func:`identified_sets`)."""
    machine = load_experiment(directory / FIG8).with_sets([*scenario.sets, *PRODUCT,
                                                           *CONTROLLERS[controller]])
    if controller != 'smc':
        return machine
    model = (tuning(machine) if tuning is not None else identified_sets(directory, scenario))
    return machine.with_sets(model)


def run_scenario(experiment: Experiment) -> dict[str, float]:
    """One row's metrics."""
    return simulate(experiment).metrics


def mean_floor_n(experiment: Experiment, horizon_s: float = 0.8) -> float:
    """The full-run mean |F - F_ref| that no causal controller beats on this machine.

    A depth step changes the force at once, and nothing can act on it before it happens. The
    floor is the mean error of a clairvoyant-from-the-step controller on the noise-free plant
    with a continuous override and the machine's own dead time and servo: at engagement and
    at each depth change it knows the new process gain exactly and at once, drives the feed
    to the table's end that moves the force the right way (150 % or 0 %) for the best switch
    time, then holds the override that gives F_ref (bang-bang then hold: the time-optimal
    shape for a first-order lag behind a dead time). Quantisation, noise and the need to
    estimate the gain are all left out, so real controllers sit above it.
    """
    plant_settings = experiment.plant.replace(current_noise_a=0.0, force_noise_fraction=0.0,
                                              sensor_fault_duration_s=0.0)
    c = experiment.controller
    profile = plant_settings.depth_profile
    period = experiment.run.control_period_s
    steps = round(experiment.run.duration_s / period)
    starts = [0.0, *profile.change_times_s()]
    reference = c.reference_force_n
    low, high = 0.0, 150.0

    def holding_pct(t_s: float) -> float:
        depth = float(profile.at(np.array([t_s + 1e-9]))[0])
        per_pct = (plant_settings.specific_cutting_force_n_mm2 * depth
                   * (plant_settings.programmed_feed_mm_rev / 100.0)
                   ** plant_settings.cutting_exponent)
        if per_pct <= 0:
            return high
        # F = K_s d (f_prog pct / 100)^g  =>  pct = (F / (K_s d (f_prog / 100)^g))^(1/g)
        pct = float((reference / per_pct) ** (1.0 / plant_settings.cutting_exponent))
        return min(max(pct, low), high)

    plant = LathePlant(plant_settings, initial_override_pct=holding_pct(0.0))
    errors = np.empty(steps)
    k = 0
    for index, start in enumerate(starts):
        end_step = steps if index + 1 == len(starts) else round(starts[index + 1] / period)
        hold = holding_pct(start)
        # The best bang-bang switch time over the first horizon_s of the segment.
        horizon = min(end_step - k, round(horizon_s / period))
        # Which way to push: where the force goes from here if the feed is simply held.
        drift = float(copy.deepcopy(plant).step(hold).force_n[-1])
        push = low if drift > reference else high
        plant, err = _best_switch(plant, push, hold, horizon, reference)
        errors[k:k + horizon] = err
        k += horizon
        for _ in range(k, end_step):
            errors[k] = abs(float(plant.step(hold).force_n[-1]) - reference)
            k += 1
    return float(np.mean(errors)) if steps else math.nan


def _best_switch(plant: LathePlant, push: float, hold: float, horizon: int,
                 reference_n: float) -> tuple[LathePlant, list[float]]:
    """Push at ``push`` % then hold ``hold`` %: the switch time (to the control period, a coarse
    grid then every period around its best) that minimises the error over ``horizon``
    periods; the plant after it and the errors."""
    tried: dict[int, tuple[float, LathePlant, list[float]]] = {}

    def attempt(switch: int) -> tuple[float, LathePlant, list[float]]:
        if switch not in tried:
            trial = copy.deepcopy(plant)
            err = [abs(float(trial.step(push if j < switch else hold).force_n[-1])
                       - reference_n) for j in range(horizon)]
            tried[switch] = (float(np.sum(err)), trial, err)
        return tried[switch]

    coarse = min(range(0, horizon + 1, 4), key=lambda n: attempt(n)[0])
    switch = min(range(max(0, coarse - 3), min(horizon, coarse + 3) + 1),
                 key=lambda n: attempt(n)[0])
    _, after, err = attempt(switch)
    return after, err
