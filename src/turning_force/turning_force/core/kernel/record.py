"""The core loop, keeping every sample: a session's arrays without ROS.

:func:`turning_force.core.kernel.simulate.simulate` keeps one row per control period;
identification reads the DAQ's samples (feed rate, q-axis current) and a dynamometer beside them.
:func:`record` runs the same loop (plant -> :class:`~turning_force.core.kernel.chain.ControlChain`
-> plant, the override applied one block later) and returns what a recorded session holds, as a
:class:`~turning_force.core.identify.Recording`, with the simulator's truth beside it. """

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from turning_force.core.estimation.settings import EstimateStatus
from turning_force.core.experiment import Experiment
from turning_force.core.identify import Recording, program_depths_mm
from turning_force.core.kernel.chain import ControlChain
from turning_force.core.plant.drive import clarke_park
from turning_force.core.plant.lathe import LathePlant
from turning_force.core.plant.settings import Dynamometer, PlantSettings

__all__ = ['CoreRecording', 'record']

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class CoreRecording:
    """A run's :class:`Recording` and the truth behind it, per sample ``(blocks, samples)``."""

    recording: Recording
    plant: PlantSettings
    force_n: FloatArray
    depth_mm: FloatArray
    rotor_angle_rad: FloatArray

    def truth(self) -> dict[str, float]:
        """What identification should find: the simulator's own values.

        The dead time as the plant applies it (whole samples); ``ksd_n_mm`` at the deepest cut,
        Park's linear one: the secant of ``F = K_s d f^g`` at the programmed feed;
        ``force_noise_n`` the standard deviation of one friction-compensated force sample in
        the cut: the current noise through the d-q transform at the angles the rotor had
        (``var i_q = sigma^2 (sin^2 - 2 sin cos / sqrt 3 + 5/3 cos^2)``, from the Clarke
        transform of two independent phase noises) over Eq. 26's slope, and the process's own
        fluctuation (uniform: ``(r F)^2 / 3``).
        """
        p = self.plant
        dt = self.recording.sample_period_s
        cut = self.depth_mm > 0
        angle = self.rotor_angle_rad[cut]
        sin, cos = np.sin(angle), np.cos(angle)
        current_var = p.current_noise_a**2 * (sin * sin - 2.0 / np.sqrt(3.0) * sin * cos
                                              + 5.0 / 3.0 * cos * cos)
        force_var = (current_var / p.current_per_force_a_n**2
                     + (p.force_noise_fraction * self.force_n[cut]) ** 2 / 3.0)
        out = {
            'dead_time_s': round(p.pmc_dead_time_s / dt) * dt,
            'ksd_n_mm': (p.specific_cutting_force_n_mm2 * float(np.max(self.depth_mm))
                         * p.programmed_feed_mm_rev ** (p.cutting_exponent - 1.0)),
            'cutting_exponent': p.cutting_exponent,
            'cutting_time_constant_s': p.cutting_time_constant_s,
            'force_noise_n': float(np.sqrt(np.mean(force_var))) if force_var.size else 0.0,
        }
        if p.servo_model == 'first_order':
            out['time_constant_s'] = p.servo_time_constant_s
        else:
            out['natural_freq_rad_s'] = p.servo_natural_freq_rad_s
            out['damping'] = p.servo_damping
        return out


def record(experiment: Experiment, name: str | None = None) -> CoreRecording:
    """Run ``experiment`` through the core loop and keep its samples. The dynamometer reads
    every block when ``lathe_sim.dynamometer`` is set (else the measured force is absent)."""
    plant_settings = experiment.plant
    chain = ControlChain(experiment.estimator, experiment.controller, experiment.bridge)
    applied = plant_settings.approach_override_pct
    plant = LathePlant(plant_settings, initial_override_pct=applied)
    dynamometer = (Dynamometer(plant_settings.dynamometer_noise_n, plant_settings.seed)
                   if plant_settings.dynamometer else None)
    steps = round(experiment.run.duration_s / experiment.run.control_period_s)
    n = plant.samples_per_block
    start, override, estimate = np.empty(steps), np.empty(steps), np.empty(steps)
    saturated = np.zeros(steps, dtype=bool)
    measured = np.full(steps, np.nan)
    feed, current, force, depth, angle = (np.empty((steps, n)) for _ in range(5))
    for k in range(steps):
        block = plant.step(applied)
        c = block.currents
        step = chain.step(c)
        start[k], override[k] = c.t0_s, applied
        estimate[k] = step.estimate.force_n
        saturated[k] = step.estimate.status == EstimateStatus.SATURATED
        feed[k], force[k], depth[k], angle[k] = (c.feed_rate_mm_min, block.force_n,
                                                 block.depth_mm, c.rotor_angle_rad)
        current[k] = clarke_park(c.phase_u_a, c.phase_v_a, c.rotor_angle_rad)[1]
        if dynamometer is not None:
            measured[k] = dynamometer.read_n(block.force_n)
        applied = step.decision.applied_pct
    recording = Recording(
        name=name or experiment.run.name,
        sample_period_s=1.0 / plant_settings.sample_rate_hz,
        programmed_feed_rate_mm_min=plant_settings.programmed_feed_rate_mm_min,
        spindle_speed_rpm=plant_settings.spindle_speed_rpm,
        current_map=experiment.estimator.current_map,
        block_start_s=start, override_pct=override, estimated_force_n=estimate,
        saturated=saturated, feed_rate_mm_min=feed, current_q_a=current,
        measured_force_n=measured if dynamometer is not None else None,
        depth_mm=program_depths_mm(plant_settings.depth_profile, start, feed.shape[1],
                                   1.0 / plant_settings.sample_rate_hz))
    return CoreRecording(recording, plant_settings, force, depth, angle)
