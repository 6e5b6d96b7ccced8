"""Closed-loop verification of identified settings before they are written (issue 15).

The identified model is a plant the simulator can run (:func:`plant_sets`: the PMC dead time, the
servo, Kienzle's ``K_s`` and exponent, ``tau_c``, the friction curve, the sensor's noise measured
in air and the cut's own fluctuation), and so are plants drawn about it (:func:`draw_plants`): each
parameter normal about its estimate, its spread the larger of three standard deviations and a floor
for what a session cannot see (the sim-to-lathe gap, a drift by the next job: 10 ms of dead time,
10 % on gains and time constants, 0.03 on the exponent, 20 % on the noise). Every candidate
(:data:`CANDIDATES`: the sliding mode law and the predictive law with the identified model, PI, and
the uncommissioned defaults) cuts the job on every plant; the candidate with the largest fraction
of plants in band wins (ties: the lower worst steady error), and the defaults win over any
candidate that holds fewer plants than they do: identification never writes settings predicted
worse than none. """

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from turning_force.core.experiment import Experiment
from turning_force.core.identify import Identification
from turning_force.core.kernel.simulate import simulate

__all__ = ['BAND_RIPPLE_N', 'BAND_STEADY_N', 'CANDIDATES', 'Prediction', 'draw_plants',
           'plant_sets', 'verify']

BAND_STEADY_N, BAND_RIPPLE_N = 5.0, 25.0
# What the identified model leaves open, at least (see the module's text).
FLOORS = {'dead_time_s': 0.01, 'relative': 0.10, 'exponent': 0.03, 'noise': 0.20}
# The candidates: sets laid over the job after the identified ones (None: none of them).
# The sliding mode law with integral action (Slotine & Li Sec. 7.1.3, as Park's Fig. 8 file):
# its boundary layer from the balance condition, or Park's 200 N.
CANDIDATES: Mapping[str, tuple[str, ...] | None] = {
    'smc': ('force_controller.controller=smc', 'force_controller.smc_surface=integral',
            'force_controller.smc_epsilon_n=0.0'),
    'smc, epsilon 200 N': ('force_controller.controller=smc',
                           'force_controller.smc_surface=integral',
                           'force_controller.smc_epsilon_n=200.0'),
    'mpc': ('force_controller.controller=mpc',),
    'mpc, rho 2': ('force_controller.controller=mpc', 'force_controller.mpc_switch_penalty=2.0'),
    'pi': ('force_controller.controller=pi',),
    'defaults': None,
}


@dataclass(frozen=True)
class Prediction:
    """One candidate on the identified plant and the plants drawn about it."""

    name: str
    sets: tuple[str, ...]
    steady_n: float        # on the identified plant
    mean_n: float
    ripple_n: float
    in_band: int           # plants in band, of ``plants``
    plants: int
    worst_steady_n: float

    @property
    def fraction(self) -> float:
        return self.in_band / self.plants

    def line(self) -> str:
        return (f'{self.name:18s} in band on {self.in_band:3d} / {self.plants:<3d} plants; '
                f'identified plant: steady {self.steady_n:6.2f} N, mean {self.mean_n:6.2f} N, '
                f'ripple {self.ripple_n:6.1f} N; worst steady {self.worst_steady_n:7.2f} N')


def plant_sets(ident: Identification, cut_depth_mm: float, per_force_a_n: float,
               values: Mapping[str, float] | None = None) -> list[str]:
    """``lathe_sim`` assignments of the identified machine (``values`` replace estimates)."""
    v = {**estimates(ident), **(values or {})}
    g, speed = v['exponent'], ident.spindle_speed_rpm
    # F = G v^g with v = f N: K_s d = G N^g.
    ks = v['gain'] * speed ** g / cut_depth_mm
    # The sensor's noise through the d-q transform (over the rotor's angles the q current's
    # variance is 4/3 of a phase's), and the cut's own fluctuation.
    current_noise = v['noise'] * per_force_a_n / math.sqrt(4.0 / 3.0)
    friction = ident.friction_model.parameters()
    sets = [f'lathe_sim.pmc_dead_time_s={max(v["dead_time_s"], 0.0)!r}',
            f'lathe_sim.servo_model={ident.servo.model}',
            f'lathe_sim.cutting_exponent={min(max(g, 0.1), 1.5)!r}',
            f'lathe_sim.specific_cutting_force_n_mm2={ks!r}',
            f'lathe_sim.cutting_time_constant_s={v["tau_c_s"]!r}',
            f'lathe_sim.current_noise_a={current_noise!r}',
            f'lathe_sim.force_noise_fraction={min(max(v["fluctuation"], 0.0), 0.5)!r}',
            *(f'lathe_sim.{key}={value!r}' for key, value in friction.items())]
    if ident.servo.model == 'first_order':
        sets.append(f'lathe_sim.servo_time_constant_s={v["servo_a"]!r}')
    else:
        sets += [f'lathe_sim.servo_natural_freq_rad_s={v["servo_a"]!r}',
                 f'lathe_sim.servo_damping={v["servo_b"]!r}']
    return sets


def estimates(ident: Identification) -> dict[str, float]:
    first = ident.servo.model == 'first_order'
    servo = ident.servo
    return {
        'dead_time_s': ident.dead_time_s.value,
        'gain': ident.process['gain_n_per_mm_min'].value,
        'exponent': ident.process['cutting_exponent'].value,
        'tau_c_s': ident.process['cutting_time_constant_s'].value,
        'noise': ident.air_noise_n.value,
        'fluctuation': ident.force_fluctuation.value,
        'servo_a': servo['time_constant_s' if first else 'natural_freq_rad_s'].value,
        'servo_b': 1.0 if first else servo['damping'].value,
    }


def draw_plants(ident: Identification, count: int, seed: int) -> list[dict[str, float]]:
    """``count`` sets of parameters about the estimates (see the module's text)."""
    rng = np.random.default_rng(seed)
    first = ident.servo.model == 'first_order'
    servo = ident.servo
    stds = {
        'dead_time_s': max(3 * ident.dead_time_s.std, FLOORS['dead_time_s']),
        'gain': 3 * ident.process['gain_n_per_mm_min'].std,
        'exponent': max(3 * ident.process['cutting_exponent'].std, FLOORS['exponent']),
        'tau_c_s': 3 * ident.process['cutting_time_constant_s'].std,
        'noise': 3 * ident.air_noise_n.std,
        'fluctuation': 3 * ident.force_fluctuation.std,
        'servo_a': 3 * servo['time_constant_s' if first else 'natural_freq_rad_s'].std,
        'servo_b': 0.0 if first else 3 * servo['damping'].std,
    }
    centre = estimates(ident)
    relative_floor = {'gain': FLOORS['relative'], 'tau_c_s': FLOORS['relative'],
                      'servo_a': FLOORS['relative'], 'servo_b': FLOORS['relative'],
                      'noise': FLOORS['noise'], 'fluctuation': FLOORS['noise']}
    for key, floor in relative_floor.items():
        stds[key] = max(stds[key], floor * abs(centre[key]))
    plants = []
    for _ in range(count):
        drawn = {key: float(rng.normal(centre[key], stds[key])) for key in centre}
        drawn['fluctuation'] = max(drawn['fluctuation'], 0.0)
        for key in ('gain', 'tau_c_s', 'noise', 'servo_a', 'servo_b'):
            drawn[key] = max(drawn[key], 0.2 * centre[key])   # a physical value
        drawn['exponent'] = min(max(drawn['exponent'], 0.3), 1.5)
        plants.append(drawn)
    return plants


def verify(job: Experiment, ident: Identification, identified: Sequence[str],
           cut_depth_mm: float, plants: int = 50, seed: int = 0) -> list[Prediction]:
    """Every candidate on the identified plant and ``plants`` drawn about it, best first (the
    module's text): ``identified`` are the identification's own ``--set`` assignments."""
    per_force = job.plant.current_per_force_a_n
    machines = [plant_sets(ident, cut_depth_mm, per_force)] + [
        plant_sets(ident, cut_depth_mm, per_force, drawn)
        for drawn in draw_plants(ident, plants, seed)]
    machines = [[*sets, f'lathe_sim.seed={seed + k + 1}'] for k, sets in enumerate(machines)]
    predictions = []
    for name, extra in CANDIDATES.items():
        sets = () if extra is None else (*identified, *extra)
        results = []
        for machine in machines:
            metrics = simulate(job.with_sets([*machine, *sets])).metrics
            results.append((metrics.get('steady_mean_abs_error_n', math.inf),
                            metrics.get('mean_abs_error_n', math.inf),
                            metrics.get('ripple_p2p_n', math.inf)))
        steady = [r[0] for r in results]
        in_band = sum(s <= BAND_STEADY_N and r <= BAND_RIPPLE_N for s, _, r in results)
        predictions.append(Prediction(name, sets, *results[0], in_band, len(results),
                                      max(steady)))
    defaults = next(p for p in predictions if p.name == 'defaults')
    allowed = [p for p in predictions if p.in_band >= defaults.in_band]
    return sorted(allowed, key=lambda p: (-p.in_band, p.worst_steady_n)) + [
        p for p in predictions if p not in allowed]
