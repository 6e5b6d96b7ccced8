"""A population of simulated machines, and the commissioning flow run on each: what "works on
ordinary machines" means, measured.

:func:`draw` makes machines from a seed, each parameter uniform in its range: PMC dead time 0-150
ms; the feed servo first order (tau 0.1-0.35 s) for 70 % of them and second order (natural
frequency 6-20 rad/s, damping 0.3-1.0) for 30 %; a Kienzle cutting exponent 0.6-1.0 with K_s
scaled to keep Park's force at 0.2 mm/rev, then times 0.8-1.5; current noise 0.01-0.1 A, force
noise 0-5 %; spindle 500-1500 rpm; tau_c 0.02-0.2 s; a job of steps, a taper, a long
multi-step job, a deep step or an interrupted cut; and for a third of them a drift between
commissioning and the job (dead time, process gain, friction or servo).

:func:`commission` is the user's flow: the commissioning experiment recorded on the machine
(``run --core --out``), ``identify`` with the job's depth range and its closed-loop verification
on the job (:mod:`turning_force.core.verification`), whose chosen settings are laid over the
job. :func:`run_job` cuts the job with any settings on the machine as it is
then (drifted where it drifts).
"""

from __future__ import annotations

import tempfile
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from turning_force.core.control import drift
from turning_force.core.control.law import ControllerBase
from turning_force.core.experiment import Experiment, assignments, load_experiment
from turning_force.core.identify import Identification, IdentifySettings
from turning_force.core.kernel.simulate import simulate
from turning_force.core.plant.drive import FeedDriveSettings
from turning_force.core.pmc.shopfloor import ShopFloorSettings
from turning_force.core.verification import (
    Prediction,
    entry_depths_mm,
    entry_override_pct,
    starts_in_air,
    verify,
)

__all__ = ['JOBS', 'PARK_DRIFTS', 'Commissioned', 'Machine', 'approached', 'commission', 'draw',
           'identified_sets', 'identify_machine', 'park_drifts', 'run_job']

EXPERIMENTS = Path('config/experiments')   # the repository's, from its root
PARK_KS_N_MM2 = 2200.0   # Park's steel at g = 1 (park1998_fig8.yaml)
DRIVE = FeedDriveSettings()   # the lathe's defaults: a friction drift scales its curve
PARK_FEED_MM_REV = 0.2
# The jobs: depth_times_s, depth_mm, interpolation, duration.
JOBS: Mapping[str, tuple[tuple[float, ...], tuple[float, ...], str, float]] = {
    'steps': ((0.0, 4.0, 8.0), (1.0, 2.0, 3.0), 'step', 12.0),
    'taper': ((0.0, 12.0), (1.0, 2.5), 'linear', 12.0),
    'long': ((0.0, 3.0, 6.0, 9.0, 12.0, 15.0, 18.0, 21.0),
             (1.5, 2.5, 1.0, 3.0, 2.0, 1.2, 2.8, 1.8), 'step', 24.0),
    'deep': ((0.0, 5.0), (1.0, 3.5), 'step', 10.0),
    'interrupted': ((0.0, 3.0, 4.0, 7.0, 8.0), (2.0, 0.0, 2.0, 0.0, 2.0), 'step', 11.0),
}
APPROACH_STEP_S = 0.01   # a taper's entry after an approach: one control period
DRIFTS = ('dead time', 'process gain', 'friction', 'servo')
PRODUCT_REACTION = ControllerBase.__dataclass_fields__['oscillation_reaction'].default


@dataclass(frozen=True)
class Machine:
    """One simulated machine: its ``lathe_sim`` settings, its job, and how it drifts."""

    index: int
    seed: int
    plant: Mapping[str, Any]
    job: str
    drift: str = ''
    drifted: Mapping[str, Any] = field(default_factory=dict)
    approach_s: float = 0.0   # the job's approach in air before its first cut [s]

    def sets(self, *, after_drift: bool) -> list[str]:
        """The machine as ``--set`` assignments (the spindle speed is every node's)."""
        plant = {**self.plant, **(self.drifted if after_drift else {})}
        spindle = plant.pop('spindle_speed_rpm')
        return [f'/**.spindle_speed_rpm={spindle!r}',
                *(f'lathe_sim.{key}={value!r}' for key, value in plant.items())]

    def describe(self) -> str:
        p = self.plant
        servo = (f'servo {p["servo_time_constant_s"]:.2f} s' if p['servo_model'] == 'first_order'
                 else f'servo {p["servo_natural_freq_rad_s"]:.1f} rad/s, zeta '
                      f'{p["servo_damping"]:.2f}')
        return (f'#{self.index} dead {p["pmc_dead_time_s"] * 1e3:.0f} ms, {servo}, g '
                f'{p["cutting_exponent"]:.2f}, K_s {p["specific_cutting_force_n_mm2"]:.0f}, '
                f'noise {p["current_noise_a"]:.3f} A + {p["force_noise_fraction"]:.1%}, '
                f'{p["spindle_speed_rpm"]:.0f} rpm, tau_c {p["cutting_time_constant_s"]:.3f} s, '
                f'job {self.job}' + (f', drift: {self.drift}' if self.drift else ''))


def draw(count: int, seed: int) -> list[Machine]:
    """``count`` machines from ``seed`` (the same seed, the same machines)."""
    rng = np.random.default_rng(seed)
    machines = []
    for index in range(count):
        g = float(rng.uniform(0.6, 1.0))
        plant: dict[str, Any] = {
            'seed': int(rng.integers(1, 2**31)),
            'pmc_dead_time_s': round(float(rng.uniform(0.0, 0.15)), 3),
            'cutting_exponent': round(g, 3),
            'specific_cutting_force_n_mm2': round(
                PARK_KS_N_MM2 * PARK_FEED_MM_REV ** (1.0 - g) * float(rng.uniform(0.8, 1.5)), 1),
            'current_noise_a': round(float(rng.uniform(0.01, 0.1)), 4),
            'force_noise_fraction': round(float(rng.uniform(0.0, 0.05)), 4),
            'spindle_speed_rpm': round(float(rng.uniform(500.0, 1500.0)), 1),
            'cutting_time_constant_s': round(float(rng.uniform(0.02, 0.2)), 3),
        }
        if rng.uniform() < 0.7:
            plant.update(servo_model='first_order',
                         servo_time_constant_s=round(float(rng.uniform(0.1, 0.35)), 3))
        else:
            plant.update(servo_model='second_order',
                         servo_natural_freq_rad_s=round(float(rng.uniform(6.0, 20.0)), 2),
                         servo_damping=round(float(rng.uniform(0.3, 1.0)), 3))
        job = str(rng.choice(list(JOBS)))
        drift, drifted = '', dict[str, Any]()
        if rng.uniform() < 1.0 / 3.0:
            drift, drifted = _drift(str(rng.choice(DRIFTS)), plant, rng)
        machines.append(Machine(index, seed, plant, job, drift, drifted))
    return machines


def _drift(kind: str, plant: Mapping[str, Any],
           rng: np.random.Generator) -> tuple[str, dict[str, Any]]:
    factor = float(rng.uniform(1.2, 1.5))
    if kind == 'dead time':
        after = round(plant['pmc_dead_time_s'] + float(rng.uniform(0.02, 0.05)), 3)
        return f'dead time to {after * 1e3:.0f} ms', {'pmc_dead_time_s': after}
    if kind == 'process gain':
        return (f'process gain x{factor:.2f}', {'specific_cutting_force_n_mm2': round(
            plant['specific_cutting_force_n_mm2'] * factor, 1)})
    if kind == 'friction':   # the lathe's friction curve, scaled as a whole
        return (f'friction x{factor:.2f}', {
            'friction_at_min_feed_a': round(DRIVE.friction_at_min_feed_a * factor, 4),
            'friction_at_max_feed_a': round(DRIVE.friction_at_max_feed_a * factor, 4)})
    if plant['servo_model'] == 'first_order':
        return (f'servo x{factor:.2f} slower', {'servo_time_constant_s': round(
            plant['servo_time_constant_s'] * factor, 3)})
    return (f'servo x{factor:.2f} slower', {'servo_natural_freq_rad_s': round(
        plant['servo_natural_freq_rad_s'] / factor, 2)})


# Park's Fig. 8 machine (park1998_fig8.yaml) with Kim's 80 ms PMC dead time, and issue 16's drifts.
PARK_KIM: Mapping[str, Any] = {
    'seed': 1, 'pmc_dead_time_s': 0.08, 'servo_model': 'first_order',
    'servo_time_constant_s': 0.17, 'cutting_exponent': 1.0,
    'specific_cutting_force_n_mm2': PARK_KS_N_MM2, 'current_noise_a': 0.02,
    'force_noise_fraction': 0.0, 'spindle_speed_rpm': 600.0, 'cutting_time_constant_s': 0.05}
PARK_DRIFTS: Mapping[str, Mapping[str, Any]] = {
    'dead time +50 %': {'pmc_dead_time_s': 0.12},
    'process gain +40 %': {'specific_cutting_force_n_mm2': 1.4 * PARK_KS_N_MM2},
    'feed friction +25 %': {'friction_at_min_feed_a': 1.25 * DRIVE.friction_at_min_feed_a,
                            'friction_at_max_feed_a': 1.25 * DRIVE.friction_at_max_feed_a},
    'servo tau x1.8': {'servo_time_constant_s': 1.8 * 0.17},
}


def park_drifts() -> list[Machine]:
    """Park's Fig. 8 job (steps 1-2-3 mm) on :data:`PARK_KIM`, once per drift of
    :data:`PARK_DRIFTS` (issue 16)."""
    return [Machine(k, PARK_KIM['seed'], PARK_KIM, 'steps', drift, drifted)
            for k, (drift, drifted) in enumerate(PARK_DRIFTS.items())]


def job_experiment(machine: Machine, *, after_drift: bool = True,
                   experiments: Path = EXPERIMENTS) -> Experiment:
    """Park's Fig. 8 file with the machine's job and the machine (drifted where it drifts),
    with the product's entry feed and oscillation reaction."""
    times, depths, interpolation, duration = approached(JOBS[machine.job], machine.approach_s)
    return load_experiment(experiments / 'park1998_fig8.yaml').with_sets([
        *machine.sets(after_drift=after_drift), f'lathe_sim.depth_times_s={list(times)!r}',
        f'lathe_sim.depth_mm={list(depths)!r}',
        f'lathe_sim.depth_interpolation={interpolation}', f'experiment.duration_s={duration!r}',
        f'experiment.name=machine_{machine.index}',
        # the product's entry feed and oscillation reaction (Park's file keeps the paper's:
        # entering at the programmed feed, the law alone)
        f'pmc_bridge.air_cut_override_pct={ShopFloorSettings().air_cut_override_pct!r}',
        f'force_controller.oscillation_reaction={PRODUCT_REACTION}'])


def approached(job: tuple[tuple[float, ...], tuple[float, ...], str, float], approach_s: float
               ) -> tuple[tuple[float, ...], tuple[float, ...], str, float]:
    """A job of :data:`JOBS` after ``approach_s`` in air, as a program approaches the work at
    the entry feed from its clearance (1 mm at 0.2 mm/rev, 1000 rpm and a 30 % entry feed: 1 s).
    A taper's depth steps to its first value over :data:`APPROACH_STEP_S`."""
    times, depths, interpolation, duration = job
    if approach_s <= 0.0:
        return job
    if interpolation == 'linear' and approach_s <= APPROACH_STEP_S:
        raise ValueError(f'an approach of {approach_s!r} s: a taper needs more than '
                         f'{APPROACH_STEP_S:g} s')
    later = tuple(t + approach_s for t in times)
    if interpolation == 'linear':
        return ((0.0, approach_s - APPROACH_STEP_S, *later), (0.0, 0.0, *depths), interpolation,
                duration + approach_s)
    return (0.0, *later), (0.0, *depths), interpolation, duration + approach_s


@dataclass(frozen=True)
class Commissioned:
    """What the user's flow gives on a machine: the identified settings, and the candidate
    the closed-loop verification chose with its prediction."""

    identified: tuple[str, ...]
    chosen: Prediction
    predictions: tuple[Prediction, ...]
    monitor: tuple[str, ...] = ()   # the drift monitor's settings (control.drift.identified)

    @property
    def written(self) -> list[str]:
        """What ``identify`` writes for the job: the chosen candidate's settings with the
        drift monitor's (which corrects a friction drift it reads in the cut), or nothing but
        the uncommissioned defaults where it chose them."""
        return [*self.chosen.sets, *(self.monitor if self.chosen.name != 'defaults' else ())]


def identify_machine(machine: Machine, experiments: Path = EXPERIMENTS,
                     production: Sequence[str] | None = None) -> tuple[Identification, float]:
    """The commissioning experiment recorded on ``machine`` before it drifts, and ``identify``
    on it: the identification and the commissioning cut's depth [mm]. With ``production`` (the
    settings it was cut with), re-commissioning from yesterday's parts instead: the job cut
    with them on the machine as it is now (drifted), ``identify`` on that production session
    (what it cannot identify kept from those settings, as ``--prior``)."""
    from turning_force.commands.core_session import record_core
    from turning_force.session.identify import cut_depth_mm, identify_sessions

    experiment = (load_experiment(experiments / 'commissioning.yaml').with_sets(
        machine.sets(after_drift=False)) if production is None else
        job_experiment(machine, experiments=experiments).with_sets(list(production)))
    with tempfile.TemporaryDirectory() as folder:
        session = Path(folder) / 'session'
        record_core(experiment, session)
        ident, sessions = identify_sessions([session], IdentifySettings(),
                                            None if production is None else ())
    return ident, cut_depth_mm(sessions) or 1.0


def identified_sets(machine: Machine, ident: Identification, cut_depth: float,
                    depths_mm: tuple[float, float] | None = None,
                    experiments: Path = EXPERIMENTS) -> tuple[list[str], list[str]]:
    """What ``identify`` writes for the machine's job (for jobs ``depths_mm`` deep, where that
    is given): the identified model (``--set`` assignments for force_controller and
    force_estimator, and pmc_bridge's entry feed where the job's deepest entry needs a lower
    one: :func:`~turning_force.core.verification.entry_override_pct`; for the machine's own
    job, ``rezero_start_in_air`` where it approaches the work in air), and the drift
    monitor's settings."""
    cut = [d for d in JOBS[machine.job][1] if d > 0]
    depths = depths_mm or (min(cut), max(cut))
    job = job_experiment(machine, after_drift=False, experiments=experiments)
    found = ident.parameters(depths, cut_depth, job.controller.reference_force_n)
    if depths_mm is None and starts_in_air(job.plant.depth_profile):
        found['force_estimator']['rezero_start_in_air'] = True   # as identify --job writes
    identified = [a for node, params in found.items() for a in assignments(node, params)]
    # the entry feed for the depths the program enters at (for other depths, the deepest)
    entry = entry_override_pct(ident, job, entry_depths_mm(job.plant.depth_profile)
                               if depths_mm is None else depths[1:], cut_depth)
    if entry is not None:
        identified += assignments('pmc_bridge', {'air_cut_override_pct': entry})
    # the program's start is known for the machine's own job, not for other depths
    monitor = drift.identified(ident, job, depths, cut_depth,
                               job.plant.depth_profile if depths_mm is None else None)
    return identified, assignments('force_controller', monitor)


def commission(machine: Machine, experiments: Path = EXPERIMENTS, plants: int = 50,
               production: Sequence[str] | None = None) -> Commissioned:
    """The user's flow on ``machine`` before it drifts: the commissioning experiment recorded,
    ``identify`` with the job's depth range, verified in closed loop on the job. With
    ``production``, re-commissioning from yesterday's parts (:func:`identify_machine`)."""
    ident, cut_depth = identify_machine(machine, experiments, production)
    identified, monitor = identified_sets(machine, ident, cut_depth, experiments=experiments)
    # The user verifies on the job's file: the machine as commissioned, not its drift.
    job = job_experiment(machine, after_drift=False, experiments=experiments)
    predictions = verify(job, ident, tuple(identified), cut_depth, plants=plants,
                         seed=machine.seed + machine.index, monitor=tuple(monitor))
    return Commissioned(tuple(identified), predictions[0], tuple(predictions), tuple(monitor))


def run_job(machine: Machine, sets: Sequence[str] = (),
            experiments: Path = EXPERIMENTS) -> dict[str, float]:
    """The job's metrics on the machine as it is at the job, with ``sets`` laid over."""
    return simulate(job_experiment(machine, experiments=experiments).with_sets(
        list(sets))).metrics
