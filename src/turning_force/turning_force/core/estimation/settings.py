"""Cutting force from feed-drive phase currents (Park 1998, Sec. 3; El-Sinawi 2011).

Per block of DAQ samples: u, v, rotor angle -> i_q (Clarke + Park) -> subtract the friction
current at the measured feed rate (Eq. 25) -> force by the inverse of Eq. 26 -> a filter that gives
force and force rate to the controller, its state carried across blocks. Two filters:

- ``lowpass``: Butterworth low-pass (Park's preprocessor) and a filtered derivative of its output.
- ``kalman``: a steady-state Kalman filter on a force / force-rate model driven by white force
  acceleration (the estimator of El-Sinawi 2011, Sec. 4, on the force alone).

``test/bench/bench_estimator.py`` measures both on noisy currents; the default is the one that
measured better.
"""

from __future__ import annotations

import enum
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from turning_force.core.plant.drive import (
    CurrentBlock,
    CurrentForceMap,
    FeedDriveSettings,
    FrictionModel,
    clarke_park,
)
from turning_force.core.settings import setting

__all__ = ['FRICTION_REACH_MARGIN', 'EstimateStatus', 'EstimatorSettings', 'ForceEstimate',
           'air_cut_point', 'calibrate_friction']

FloatArray = npt.NDArray[np.float64]

# Contiguous blocks on a new time line (a restarted DAQ, a stepped clock) before the estimator
# follows it: one stray stamp is refused, three in a row one block apart are a new clock.
RESYNC_BLOCKS = 3
# A sample past this many times the sensor's range is corrupt, not a saturated reading.
IMPLAUSIBLE_RANGE_FACTOR = 2.0
# How far past the fastest feed the air move measured the friction at the axis may run before
# it is said (``friction_measured_to_mm_min``; ``identify --job`` from the job file): past it
# the curve's end is held (Park Eq. 25), and 10 % further on the simulated lathe's curve (0.60
# A at 6 mm/min, 0.35 A at 300) moves the friction by 0.02 A at most, about 3 N of force.
FRICTION_REACH_MARGIN = 0.1


class EstimateStatus(enum.IntEnum):
    """Matches the ``STATUS_*`` constants of ``turning_force_msgs/ForceEstimate``."""

    OK = 0
    STALE = 1
    INVALID_INPUT = 2
    SATURATED = 3

    @property
    def actionable(self) -> bool:
        """Whether a controller may act on an estimate of this status. A saturated current
        still says the force is large; a stale or invalid one says nothing new."""
        return self in (EstimateStatus.OK, EstimateStatus.SATURATED)


@dataclass(frozen=True)
class EstimatorSettings(FeedDriveSettings):
    """The force estimator (``force_estimator`` parameters); the drive fields are the
    calibrated friction (an air cut, :func:`calibrate_friction`) and current map."""

    SECTION = 'force_estimator'

    force_filter: str = setting('kalman', 'Filter giving force and force rate',
                                choices=('lowpass', 'kalman'))
    lowpass_cutoff_hz: float = setting(20.0, 'Butterworth low-pass cut-off', 'Hz', low=0.0,
                                       low_open=True, high=1e5)
    lowpass_order: int = setting(2, 'Butterworth low-pass order', low=1, high=8, unit='-')
    derivative_time_constant_s: float = setting(0.01, 'Time constant of the filtered derivative '
                                                'after the low-pass', 's', low=0.0,
                                                low_open=True, high=1.0)
    kalman_force_noise_n: float = setting(4.0, 'Standard deviation of one friction-compensated '
                                          'force sample (current noise / Eq. 26 slope)', 'N',
                                          low=0.0, low_open=True, high=1e5,
                                          cite='Park 1998, Eq. 26; El-Sinawi 2011')
    kalman_accel_noise_n_s2: float = setting(2.0e4, 'Standard deviation of the force '
                                             'acceleration the model allows', 'N/s^2', low=0.0,
                                             low_open=True, high=1e12, cite='El-Sinawi 2011')
    current_range_a: float = setting(30.0, 'Phase-current sensor range; samples beyond it mark '
                                     'the estimate saturated', 'A', low=0.0, low_open=True,
                                     high=1e4)
    rezero_below_n: float = setting(40.0, 'Friction re-zero: a force estimate below this for '
                                    'rezero_after_s means the tool is out of the material, '
                                    'and the q current is friction alone; keep it below the '
                                    'lightest cut; 0: never re-zero', 'N', low=0.0, high=1e4)
    rezero_after_s: float = setting(0.3, 'Friction re-zero: how long the force must stay below '
                                    'rezero_below_n first', 's', low=0.0, low_open=True,
                                    high=60.0)
    rezero_time_constant_s: float = setting(0.3, 'Friction re-zero: how fast the friction scale '
                                            'follows what a long air move measures (each air '
                                            "move's mean is taken where that is faster)", 's',
                                            low=1e-3, high=600.0)
    rezero_stale_s: float = setting(300.0, 'Friction re-zero: a WARN on /diagnostics when no '
                                    'air move has re-zeroed the friction for this long (a '
                                    'program without one: friction that drifts goes unseen); '
                                    '0: no warning', 's', low=0.0, high=86400.0)
    friction_measured_to_mm_min: float = setting(
        0.0, 'The fastest feed the friction curve was measured at (identify writes it: its air '
        "move's fastest level); past it the estimate holds the curve's end (Park Eq. 25), and "
        'a WARN on /diagnostics says so where the axis runs over 10 % faster for half a '
        "second (a faster spindle than the commissioning's, a G96 cut); 0: not said",
        'mm/min', low=0.0, high=1e6, cite='Park 1998, Eq. 25')
    model_cutting_time_constant_s: float = setting(
        0.05, "Friction re-zero: the cutting force's time constant tau_c (Park Eq. 1; identify "
        'writes the identified one): the re-zero takes the tail of the force the tool left, '
        'decaying with it from rezero_below_n, off what it reads as friction in air; 0: a '
        'static process, no tail', 's', low=0.0, high=10.0, cite='Park 1998, Eq. 1')
    rezero_fall_fraction: float = setting(0.25, 'Friction re-zero: an estimate that has '
                                          'fallen below this fraction of the cut it left (its '
                                          'mean over the last seconds) and stays within '
                                          'rezero_max_change of the friction above '
                                          'rezero_below_n for rezero_after_s is the tool in '
                                          'air too (a friction drift lifts the estimate in '
                                          'air); 0: the level alone', '-', low=0.0, high=0.9)
    rezero_start_in_air: bool = setting(
        False, 'Friction re-zero: the session starts with the tool out of the material (the '
        "program approaches the work in air): an estimate within a friction drift's lift "
        '(rezero_max_change of the friction above rezero_below_n) is air, as after an exit, '
        'until it has stood over the lift for 0.1 s (a cut) or read below rezero_below_n for '
        "rezero_after_s; off where a run may start in a light cut (Park's Fig. 13 cuts at 50 N "
        "from t = 0). identify --job writes it where the job's program starts in air")
    rezero_max_change: float = setting(0.5, 'Friction re-zero: the scale on the calibrated '
                                       'friction stays within 1 -/+ this', low=0.0, high=0.9,
                                       unit='-')
    max_stamp_jump_s: float = setting(1.0, 'A block stamped further than this after the end of '
                                      'the previous one is refused (a corrupt stamp), until '
                                      f'{RESYNC_BLOCKS} contiguous blocks show a new time line',
                                      's', low=0.0, low_open=True, high=3600.0)


@dataclass(frozen=True)
class ForceEstimate:
    """What the estimator says after a block (the core side of ``ForceEstimate``)."""

    t_s: float
    force_n: float
    force_rate_n_s: float
    current_q_a: float
    friction_current_a: float
    status: EstimateStatus = EstimateStatus.OK
    detail: str = ''
    feed_rate_mm_min: float = math.nan   # the block's mean axis feed, as the DAQ measured it


def calibrate_friction(
    air_cuts: Sequence[CurrentBlock], current_map: CurrentForceMap
) -> FrictionModel:
    """Eq. 25 from an air cut: blocks taken at two or more constant feeds, no tool contact.

    With no cutting force the friction current is ``i_q`` less Eq. 26's zero-force offset; each
    block gives one point (its mean feed, its mean friction current).
    """
    points = [air_cut_point(block, current_map) for block in air_cuts]
    return FrictionModel.calibrate([p[0] for p in points], [p[1] for p in points])


def air_cut_point(block: CurrentBlock, current_map: CurrentForceMap) -> tuple[float, float]:
    """One air-cut block's (mean feed [mm/min], friction current [A])."""
    _, current_q = clarke_park(block.phase_u_a, block.phase_v_a, block.rotor_angle_rad)
    return float(np.mean(block.feed_rate_mm_min)), float(np.mean(current_q)) - current_map.offset_a
