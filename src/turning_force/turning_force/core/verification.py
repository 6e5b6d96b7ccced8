"""Closed-loop verification of identified settings before they are written (issue 15).

The identified model is a plant the simulator can run (:func:`plant_sets`: the PMC dead time, the
servo, Kienzle's ``K_s`` and exponent, ``tau_c``, the friction curve, the sensor's noise measured
in air and the cut's own fluctuation), and so are plants drawn about it (:func:`draw_plants`): each
parameter normal about its estimate, its spread the larger of three standard deviations and a floor
for what a session cannot see (the sim-to-lathe gap, a drift by the next job: 20 ms of dead time,
15 % on gains and time constants, 0.03 on the exponent, 20 % on the noise; issue 16's drifts,
dead time +40 ms and gain +40 %, are within three of these). The cutting force ``G v^g`` is
drawn as the fit knows it: its level at the feed where the fit states G's spread (the cut's
median feed, ``gain_feed_mm_min``) from G's spread, and the exponent turning the curve about
that feed. Drawn apart, each exponent moved the force at every feed by ``v^dg``: on a
production cut (one depth, few feeds, the exponent known to 0.035) the plants' K_s ran from 605
to 10,460 N/mm^2 about 2,900, and one over the simulator's bound stopped ``identify``
(bench_recommission.py, generator seed 16 #3, process gain +40 %); on a commissioning cut the
exponent's floor alone moved the force at 300 mm/min by x1.19 for each 0.03, beside the 15 %
floor on the gain.

Two stages. First every candidate (:data:`CANDIDATES`: the predictive law's switching penalty and
horizon, the sliding mode law's lambda and boundary layer, PI, each with the identified Kalman
noise, half and a quarter of it) cuts the job on the identified plant alone: a sweep like the
oracle's, on the model instead of the machine. Then the best four of each law there and the
uncommissioned defaults cut it on every plant: the best two alone were often the same law's
settings tuned tightest to the nominal plant, and on a servo drift of 1.28 (population seed 15
machine #99) the pair held 30 and 25 of 51 plants where the third held 46. The choice scores each
candidate by how far it is from the band: per plant ``steady / 5 N + max(0, ripple / 25 N - 1)``
(below 1 in band; the steady error first, as the oracle ranks), capped at 5, half the weight on
the identified plant and half on the plants drawn about it; that for two thirds, and a third on
the identified plant drifted (:func:`drifted_plants`): issue 16's four drifts at the sizes a
machine makes them between commissioning and a job (:data:`DRIFT_SIZES`; a third of the
population's machines drift). Every cut runs with the drift monitor's settings as ``identify``
writes them: the monitor takes a lag drift into the predictive law's model, and what is
verified is what is written: without it, population seed 15 #99's identified plant slowed
x1.35 and x1.5 was predicted at 2.1-2.4 and 4.0-5.2 N steady, where the written loop adopts the
drift and holds 1.0-1.4 N. With the drifted plants, over seed 42's first 38 machines, 5
choices changed, each 0.02-0.13 N better on the machine at the job, none worse.
Two rules keep identification from writing settings predicted worse than none: a candidate that
holds fewer plants in band than the defaults, or whose steady error on the identified plant is
more than 1 N over theirs, is never chosen (the defaults then win). A count of plants in band
alone chose by the noise of ripple near 25 N: a law 33 N off on the identified plant held more
drawn plants by a hair than the defaults 5.6 N off. """

from __future__ import annotations

import itertools
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from turning_force.core.estimation.settings import FRICTION_REACH_MARGIN
from turning_force.core.experiment import Experiment
from turning_force.core.identify import Identification
from turning_force.core.kernel.simulate import simulate
from turning_force.core.plant.settings import DepthProfile

__all__ = ['BAND_RIPPLE_N', 'BAND_STEADY_N', 'CANDIDATES', 'DRIFT_SIZES', 'MAX_COST',
           'Prediction', 'cost', 'draw_plants', 'drifted_plants', 'entry_depths_mm',
           'entry_override_pct', 'friction_beyond_reach', 'plant_sets', 'starts_in_air', 'verify']

BAND_STEADY_N, BAND_RIPPLE_N = 5.0, 25.0
# What the identified model leaves open, at least (see the module's text).
FLOORS = {'dead_time_s': 0.02, 'relative': 0.15, 'exponent': 0.03, 'noise': 0.20}
# The candidates: sets laid over the job after the identified ones (None: none of them), each
# with the identified Kalman noise, half and a quarter of it (KALMAN_SCALES: the noise of one
# sample makes the filter as slow as the noise allows, and a loop with dead time does better
# with a faster estimate and a noisier override), and the oracle's main gains about the laws'
# defaults (test/bench/bench_population.py). The predictive law over the levels: its
# switching penalty and horizon; the sliding mode law with integral action (Slotine & Li Sec.
# 7.1.3, as Park's Fig. 8 file): lambda and the boundary layer (0: from the balance condition);
# PI; these two with the job's quantiser and with the product's error feedback; and the
# uncommissioned defaults. Park's Fig. 8 file rounds the request (as the paper's PMC did): PI
# rounded cycled between two levels on population seed 42's #138 (a 9.2 rad/s servo damped
# at 0.34 slowed x1.39, interrupted cuts), 37.9 N steady with the identified settings, and
# with error feedback held 4.2-4.4 N (the oracle 4.18 N), with the entry feed held a fixed
# 0.3 s (held until the force is established, its re-entries wait out the servo's swing: 9.5 N).
KALMAN_SCALES = (1.0, 0.5, 0.25)
QUANTISERS = {'': (), ', error feedback': ('force_controller.quantiser=error_feedback',)}
CANDIDATES: Mapping[str, tuple[str, ...] | None] = {
    **{f'mpc, rho {rho:g}, horizon {horizon:g} s': (
        'force_controller.controller=mpc', f'force_controller.mpc_switch_penalty={rho!r}',
        f'force_controller.mpc_horizon_s={horizon!r}')
       for rho in (0.0, 0.25, 0.5, 2.0) for horizon in (0.15, 0.3, 0.6)},
    **{f'smc, lambda {lam:g}, epsilon {eps:g} N{name}': (
        'force_controller.controller=smc', 'force_controller.smc_surface=integral',
        f'force_controller.smc_lambda_per_s={lam!r}', f'force_controller.smc_epsilon_n={eps!r}',
        *quantiser)
       for lam in (5.0, 10.0, 20.0) for eps in (0.0, 50.0, 200.0)
       for name, quantiser in QUANTISERS.items()},
    **{f'pi{name}': ('force_controller.controller=pi', *quantiser)
       for name, quantiser in QUANTISERS.items()},
    'defaults': None,
}
PER_LAW = 4          # the best of each law on the identified plant go on to every plant
# A plant far out counts as MAX_COST times the band, not more. At 10 the few drawn plants on
# which a law fails outweighed the many it holds: on population seed 42's #92 (150 ms of dead
# time, an underdamped servo, a taper) the predictive law held 32 of 51 plants in band and
# 2.58 N on the identified plant, the sliding mode law 6 of 51 and 7.21 N, and the sliding mode
# law scored lower (2.07 against 2.13): 7.33 N steady on the machine, the oracle's 2.24 N. At
# 5: 2.54 N. Over seeds 15 and 42 (400 machines, each rule's choice cut on the true machine)
# 7 choices changed, none worse by 0.3 N; at 3, 26 changed and two got worse (seed 42's #138,
# 18.7 -> 35.5 N); the median of the drawn plants' costs lost a machine's regret on seed 15.
MAX_COST = 5.0
# The drifts of issue 16 at the sizes a machine makes them between commissioning and a job
# (population.py draws them): dead time +20-50 ms [s], and process gain, servo lag and friction
# x1.2-1.5; each size of each, one plant. Their share of the score: a third of the machines
# drift.
DRIFT_SIZES = ((0.02, 1.2), (0.035, 1.35), (0.05, 1.5))
DRIFT_WEIGHT = 1.0 / 3.0
SLACK_N = 1.0        # how much worse than the defaults on the identified plant is allowed
KALMAN = 'force_estimator.kalman_force_noise_n'


def friction_beyond_reach(ident: Identification, job: Experiment) -> str:
    """Where the job's axis runs faster than the commissioning's air move measured the
    friction at, a line that says so ('' where it does not). The axis feed is the feed per
    revolution times the spindle speed (G95): the job's fastest is its programmed feed at the
    table's highest level at its fastest spindle speed, under constant surface speed (G96)
    the program's clamp. Beyond the reach the estimator holds the curve's end value, and a
    curve still falling there leaves the estimate off by its fall: a G96 facing cut (500 ->
    1500 rpm) on a machine commissioned at 654 rpm (population seed 42 #2, measured to 196
    mm/min) held 10 N above the reference from the clamp on; commissioned at 1500 rpm, the
    fit found the curve's end at 297 mm/min and the cut held 1.3 N."""
    from turning_force.core.pmc.overrides import get_table

    plant, c = job.plant, job.controller
    rpm = max(plant.css_max_spindle_rpm if plant.css_surface_speed_m_min > 0.0
              else plant.spindle_speed_rpm, c.spindle_speed_rpm)
    top_pct = get_table(c.override_table).max_pct
    fastest = c.programmed_feed_mm_rev * rpm * top_pct / 100.0
    reach = ident.friction_reach_mm_min
    if not fastest > (1.0 + FRICTION_REACH_MARGIN) * reach:
        return ''
    return (f'friction: the air move measured it up to {reach:.0f} mm/min; {job.run.name} '
            f'feeds the axis at up to {fastest:.0f} mm/min ({top_pct:g} % at {rpm:.0f} rpm), '
            "where the estimator holds the curve's end (Park Eq. 25) and a friction that "
            'goes on falling reads as force: record the commissioning air move with the '
            f'spindle at {rpm:.0f} rpm')


def entry_depths_mm(program: DepthProfile) -> tuple[float, ...]:
    """The depths [mm] a program enters the work at: its start where that is in the cut, and
    each depth that follows a span in air."""
    depths = program.depth_mm
    entries = [depths[0]] if depths[0] > 0.0 else []
    entries += [after for before, after in itertools.pairwise(depths) if before <= 0.0 < after]
    return tuple(entries)


def starts_in_air(program: DepthProfile) -> bool:
    """Whether a program approaches the work in air before its first cut (its depth 0 at
    t = 0): there the estimator may read the friction before the first contact
    (``force_estimator.rezero_start_in_air``, which ``identify`` writes for such a job)."""
    return program.depth_mm[0] <= 0.0 < max(program.depth_mm)


def entry_override_pct(ident: Identification, job: Experiment,
                       entry_depths: Sequence[float], cut_depth_mm: float) -> float | None:
    """The entry feed (``pmc_bridge.air_cut_override_pct``) for a job entering the work at
    ``entry_depths`` [mm] on the identified machine, where the job's own is too fast: the
    highest level of the override table, below the job's, at which the deepest entry's force
    settles no higher than the reference (Park Eq. 1 with Kienzle's exponent, ``F = K_s d
    f_prog o^g``: the axis reaches the work at the entry feed, already settled in air, so the
    force rises to that value with tau_c and no further until the law acts), or the lowest
    level above 0 where none does. None where the job's own level passes, or is off (0).

    A fixed 30 % is Park's steel's: 3 mm at 30 % is 396 N. On a Kienzle material the force
    falls slower with the feed: population seed 42's #11 (g 0.64) cuts 887 N at 3 mm and 30 %,
    and its commissioned loop entered an interrupted cut (1, 2, 3 mm) 369 N over the reference;
    at 10 % (438 N), 8 N. The issue's bound, 100 N over the reference, is left to the
    identified process's error and the loop's moves after the entry: allowing the entry force
    10 % over the reference, seed 42's #14 (121 ms of dead time, a servo damped at 0.33, 545 N
    at 3 mm and 30 %) entered 116 N over; at 20 % (365 N), 45 N."""
    from turning_force.core.control.drift import start_feed_mm_min
    from turning_force.core.pmc.overrides import get_table

    c, ceiling = job.controller, job.bridge.air_cut_override_pct
    if not (ceiling > 0.0 and entry_depths):
        return None
    table = get_table(c.override_table)
    # the level [%] at which the deepest entry's force settles at the reference
    holding = 100.0 * start_feed_mm_min(ident, job, max(entry_depths) / cut_depth_mm) / \
        c.programmed_feed_rate_mm_min
    top = min(ceiling, holding)
    lowest = min(level for level in table.levels_pct if level > 0.0)
    if table.continuous:
        level = max(top, lowest)
    else:
        level = max([level for level in table.levels_pct if 0.0 < level <= top] or [lowest])
    return level if level < ceiling else None


def cost(steady_n: float, ripple_n: float) -> float:
    """How far a cut is from the band: ``steady / 5 N + max(0, ripple / 25 N - 1)`` (the module's
    text), at most :data:`MAX_COST`; NaN (no cut) as far as it goes."""
    value = steady_n / BAND_STEADY_N + max(0.0, ripple_n / BAND_RIPPLE_N - 1.0)
    return MAX_COST if not value <= MAX_COST else value


@dataclass(frozen=True)
class Prediction:
    """One candidate on the identified plant, the plants drawn about it and its drifts."""

    name: str
    sets: tuple[str, ...]
    steady_n: float        # on the identified plant
    mean_n: float
    ripple_n: float
    in_band: int           # plants in band, of ``plants``
    plants: int
    worst_steady_n: float
    score: float = math.nan   # the choice's (the module's text): lower is better

    @property
    def fraction(self) -> float:
        return self.in_band / self.plants

    def line(self) -> str:
        return (f'{self.name:40s} in band on {self.in_band:3d} / {self.plants:<3d} plants; '
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
    friction = dict(ident.friction_model.parameters())
    for key in ('friction_at_min_feed_a', 'friction_at_max_feed_a'):   # a friction drift
        friction[key] *= v.get('friction', 1.0)
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
    pivot = ident.process['gain_feed_mm_min'].value
    plants = []
    for _ in range(count):
        drawn = {key: float(rng.normal(centre[key], stds[key])) for key in centre}
        drawn['fluctuation'] = max(drawn['fluctuation'], 0.0)
        for key in ('gain', 'tau_c_s', 'noise', 'servo_a', 'servo_b'):
            drawn[key] = max(drawn[key], 0.2 * centre[key])   # a physical value
        drawn['exponent'] = min(max(drawn['exponent'], 0.3), 1.5)
        # G v^g turned about the feed G's spread is stated at: the force there is the drawn
        # gain's, whatever the exponent (see the module's text)
        drawn['gain'] *= pivot ** (centre['exponent'] - drawn['exponent'])
        plants.append(drawn)
    return plants


def drifted_plants(ident: Identification) -> list[dict[str, float]]:
    """The identified plant after each drift of :data:`DRIFT_SIZES`: ``values`` for
    :func:`plant_sets` (``friction``: the curve's scale)."""
    centre = estimates(ident)
    first = ident.servo.model == 'first_order'   # a slower servo: tau up, omega_n down
    plants = []
    for added_s, factor in DRIFT_SIZES:
        plants += [{'dead_time_s': centre['dead_time_s'] + added_s},
                   {'gain': centre['gain'] * factor},
                   {'servo_a': centre['servo_a'] * factor if first
                    else centre['servo_a'] / factor},
                   {'friction': factor}]
    return plants


def _law(sets: Sequence[str]) -> str:
    return next((a.split('=', 1)[1] for a in sets if a.startswith('force_controller.controller=')),
                'defaults')


def _cut(job: Experiment, machine: Sequence[str], sets: Sequence[str]
         ) -> tuple[float, float, float]:
    metrics = simulate(job.with_sets([*machine, *sets])).metrics
    return (metrics.get('steady_mean_abs_error_n', math.inf),
            metrics.get('mean_abs_error_n', math.inf), metrics.get('ripple_p2p_n', math.inf))


# a candidate's name: its settings laid over the identified ones (None: the defaults) and its
# cut on the identified plant (steady, mean, ripple)
_Tuned = dict[str, tuple[tuple[str, ...] | None, tuple[float, float, float]]]


def _tuned(job: Experiment, identified: Sequence[str], nominal: Sequence[str],
           monitor: Sequence[str]) -> _Tuned:
    """The first stage: every candidate with each Kalman noise of :data:`KALMAN_SCALES` on the
    identified plant, with the drift monitor's settings (``monitor``); the best
    :data:`PER_LAW` of each law, and the defaults, each with its cut on the identified plant
    (:func:`_cut`)."""
    kalman = next((float(a.split('=', 1)[1]) for a in identified if a.startswith(KALMAN + '=')),
                  None)
    grid: dict[str, tuple[str, ...]] = {}
    for name, extra in CANDIDATES.items():
        if extra is None:
            continue
        for scale in KALMAN_SCALES if kalman is not None else (1.0,):
            tail = () if kalman is None or scale == 1.0 else (f'{KALMAN}={kalman * scale!r}',)
            grid[name + ('' if scale == 1.0 else f', Kalman x{scale:g}')] = (*extra, *tail)
    cuts = {name: _cut(job, nominal, (*identified, *extra, *monitor))
            for name, extra in grid.items()}
    scores = {name: cost(steady, ripple) for name, (steady, _, ripple) in cuts.items()}
    chosen: _Tuned = {}
    for law in dict.fromkeys(_law(extra) for extra in grid.values()):
        ranked = sorted((n for n in grid if _law(grid[n]) == law), key=lambda n: scores[n])
        chosen.update({name: (grid[name], cuts[name]) for name in ranked[:PER_LAW]})
    chosen['defaults'] = (None, _cut(job, nominal, ()))
    return chosen


def verify(job: Experiment, ident: Identification, identified: Sequence[str],
           cut_depth_mm: float, plants: int = 50, seed: int = 0,
           monitor: Sequence[str] = ()) -> list[Prediction]:
    """The two stages of the module's text on the identified plant, ``plants`` drawn about it
    and its drifts, best first: ``identified`` are the identification's own ``--set``
    assignments, ``monitor`` the drift monitor's as ``identify`` writes them. The first
    prediction is the choice; the candidates never chosen (the defaults beat them) come
    last."""
    per_force = job.plant.current_per_force_a_n
    machines = [plant_sets(ident, cut_depth_mm, per_force)] + [
        plant_sets(ident, cut_depth_mm, per_force, drawn)
        for drawn in draw_plants(ident, plants, seed)]
    first_drifted = len(machines)
    machines += [plant_sets(ident, cut_depth_mm, per_force, values)
                 for values in drifted_plants(ident)]
    machines = [[*sets, f'lathe_sim.seed={seed + k + 1}'] for k, sets in enumerate(machines)]
    tuned = _tuned(job, identified, machines[0], monitor)
    given = {name: () if extra is None else (*identified, *extra)
             for name, (extra, _) in tuned.items()}
    laid = {name: (*sets, *monitor) if sets else () for name, sets in given.items()}
    # the identified plant's cut from the first stage, the drawn plants' now (each plant under
    # every candidate in turn: one draw of its noise serves them all, kernel/simulate.py)
    cuts = {name: [nominal] for name, (_, nominal) in tuned.items()}
    for machine in machines[1:]:
        for name, sets in laid.items():
            cuts[name].append(_cut(job, machine, sets))
    predictions = []
    for name, sets in given.items():
        results = cuts[name]
        steady = [r[0] for r in results]
        costs = [cost(s, r) for s, _, r in results]
        in_band = sum(s <= BAND_STEADY_N and r <= BAND_RIPPLE_N for s, _, r in results)
        about = sum(costs[1:first_drifted]) / max(first_drifted - 1, 1)
        after = sum(costs[first_drifted:]) / max(len(costs) - first_drifted, 1)
        score = (0.5 * costs[0] + 0.5 * about) * (1.0 - DRIFT_WEIGHT) + DRIFT_WEIGHT * after
        predictions.append(Prediction(name, sets, *results[0], in_band, len(results),
                                      max(steady), score))
    defaults = next(p for p in predictions if p.name == 'defaults')
    allowed = [p for p in predictions if p.in_band >= defaults.in_band
               and p.steady_n <= defaults.steady_n + SLACK_N]
    return sorted(allowed, key=lambda p: (p.score, p.worst_steady_n)) + [
        p for p in predictions if p not in allowed]
