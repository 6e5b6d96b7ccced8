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
from types import ModuleType

import numpy as np
import numpy.typing as npt

from turning_force.core import kernel, lti
from turning_force.core.drive import (
    CurrentBlock,
    CurrentForceMap,
    FeedDriveSettings,
    FrictionModel,
    clarke_park,
)
from turning_force.core.settings import setting

__all__ = [
    'EstimateStatus',
    'EstimatorSettings',
    'ForceEstimate',
    'ForceEstimator',
    'air_cut_point',
    'calibrate_friction',
    'detail_text',
    'rezeroed_text',
]

FloatArray = npt.NDArray[np.float64]

# Contiguous blocks on a new time line (a restarted DAQ, a stepped clock) before the estimator
# follows it: one stray stamp is refused, three in a row one block apart are a new clock.
RESYNC_BLOCKS = 3
# A sample past this many times the sensor's range is corrupt, not a saturated reading.
IMPLAUSIBLE_RANGE_FACTOR = 2.0


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
                                       low_open=True)
    lowpass_order: int = setting(2, 'Butterworth low-pass order', low=1, high=8)
    derivative_time_constant_s: float = setting(0.01, 'Time constant of the filtered derivative '
                                                'after the low-pass', 's', low=0.0,
                                                low_open=True, high=1.0)
    kalman_force_noise_n: float = setting(4.0, 'Standard deviation of one friction-compensated '
                                          'force sample (current noise / Eq. 26 slope)', 'N',
                                          low=0.0, low_open=True)
    kalman_accel_noise_n_s2: float = setting(2.0e4, 'Standard deviation of the force '
                                             'acceleration the model allows', 'N/s^2', low=0.0,
                                             low_open=True)
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
                                            'follows what the air move measures', 's',
                                            low=1e-3, high=600.0)
    rezero_max_change: float = setting(0.5, 'Friction re-zero: the scale on the calibrated '
                                       'friction stays within 1 -/+ this', low=0.0, high=0.9)
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


class ForceEstimator:
    """Force and force rate from blocks of feed-drive currents.

    A block with non-finite samples, mismatched arrays, a bad or changed sample period, or a
    stamp not after the previous one (or further ahead than ``max_stamp_jump_s``) is reported
    ``INVALID_INPUT``; so is a block with a sample past twice the sensor range (no Hall sensor
    reads that: a corrupt value) or whose values overflow the filter.
    The estimate then repeats the last good force, always finite, and the filter restarts at
    the next good block: a gap in the data is not bridged by a filter state that no longer
    matches it.

    Stamps: a DAQ that restarts (or a clock that steps) starts a new time line; after
    ``RESYNC_BLOCKS`` contiguous blocks on it, the estimator follows it. One stray stamp
    (1e9 s) is refused and the blocks after it, on the old time line, are taken as before.

    Friction re-zero: while the tool is out of the material (Park Eq. 25 drifts with the
    slideway's temperature and lubrication), the q current less Eq. 26's zero-force offset is
    friction alone, and its ratio to the calibrated curve at this feed scales the curve, within
    ``rezero_max_change``.

    The arithmetic is written once, as the compiled ``estimator_update`` of
    :mod:`turning_force.core.kernel.jit` (which the compiled loops run on :meth:`arrays_for`);
    this class holds its parameters and state and puts its codes into words.
    """

    def __init__(self, settings: EstimatorSettings) -> None:
        jit = kernel.load()
        self.settings = settings
        self._params = _estimator_params(jit, settings)
        state = np.zeros(jit.ES_SIZE)
        state[jit.ES_LAST_T] = state[jit.ES_NEXT_T] = -math.inf
        state[jit.ES_SCALE] = 1.0
        state[jit.ES_STATUS] = EstimateStatus.STALE
        self._state = state
        self._work = np.empty(0)
        self._last = ForceEstimate(0.0, 0.0, 0.0, 0.0, 0.0, EstimateStatus.STALE, 'no data yet')

    @property
    def last(self) -> ForceEstimate:
        return self._last

    @property
    def friction_scale(self) -> float:
        """Re-zeroed friction / calibrated friction."""
        return float(self._state[kernel.load().ES_SCALE])

    @property
    def restarts(self) -> int:
        """How often the filter restarted after a refused block."""
        return int(self._state[kernel.load().ES_RESTARTS])

    def arrays_for(self, sample_period_s: float) -> tuple[FloatArray, FloatArray]:
        """(parameters, state) as ``estimator_update`` reads them (live: a loop that runs
        them runs this estimator), the filter's coefficients set for blocks sampled at
        ``sample_period_s`` (where that is one)."""
        jit = kernel.load()
        if (self._state[jit.ES_ACTIVE] == 0.0 and math.isfinite(sample_period_s)
                and sample_period_s > 0):
            _set_filter(jit, self._params, self.settings, sample_period_s)
        return self._params, self._state

    def update(self, block: CurrentBlock) -> ForceEstimate:
        """Process one block; return the estimate at its last sample."""
        jit = kernel.load()
        params, state = self.arrays_for(block.sample_period_s)
        n = len(block)
        if self._work.size < 2 * n:
            self._work = np.empty(2 * n)
        status = int(jit.estimate_block(
            params, state, float(block.t0_s), float(block.sample_period_s),
            _contiguous(block.phase_u_a), _contiguous(block.phase_v_a),
            _contiguous(block.rotor_angle_rad), _contiguous(block.feed_rate_mm_min),
            self._work))
        detail = detail_text(self.settings, block, int(state[jit.ES_DCODE]),
                             float(state[jit.ES_DVAL]), float(state[jit.ES_DVAL + 1]))
        if status == EstimateStatus.INVALID_INPUT:
            last = self._last
            self._last = ForceEstimate(last.t_s, last.force_n, last.force_rate_n_s,
                                       last.current_q_a, last.friction_current_a,
                                       EstimateStatus.INVALID_INPUT, detail)
        else:
            self._last = ForceEstimate(
                float(state[jit.ES_T]), float(state[jit.ES_F]), float(state[jit.ES_R]),
                float(state[jit.ES_IQ]), float(state[jit.ES_IFR]), EstimateStatus(status),
                detail)
        return self._last


def _contiguous(values: FloatArray) -> FloatArray:
    """What the compiled function takes: C-contiguous, writable float64 (a block decoded from
    a bag is a read-only view of the message's buffer)."""
    out = np.ascontiguousarray(values, dtype=np.float64)
    return out if out.flags.writeable else out.copy()


def _estimator_params(jit: ModuleType, settings: EstimatorSettings) -> FloatArray:
    """The estimator's parameters (``E_*``); the filter's coefficients come with
    :func:`_set_filter` once the sample period is known."""
    p = np.zeros(jit.E_SIZE)
    p[jit.E_KIND] = jit.KALMAN if settings.force_filter == 'kalman' else jit.LOWPASS
    f, m = settings.friction, settings.current_map
    p[jit.E_FR_A], p[jit.E_FR_B] = f.a_a_per_mm_min2, f.b_a
    p[jit.E_FR_MIN], p[jit.E_FR_MAX] = f.min_feed_mm_min, f.max_feed_mm_min
    p[jit.E_MAP_OFF], p[jit.E_MAP_PER] = m.offset_a, m.per_force_a_n
    p[jit.E_RANGE] = settings.current_range_a
    p[jit.E_REZ_BELOW], p[jit.E_REZ_AFTER] = settings.rezero_below_n, settings.rezero_after_s
    p[jit.E_REZ_TAU] = settings.rezero_time_constant_s
    p[jit.E_REZ_MAX] = settings.rezero_max_change
    p[jit.E_MAX_JUMP] = settings.max_stamp_jump_s
    p[jit.E_GAIN_DT] = math.nan
    return p


def _set_filter(jit: ModuleType, params: FloatArray, settings: EstimatorSettings,
                dt_s: float) -> None:
    """The filter's coefficients for sample period ``dt_s``.

    - ``kalman``: the steady-state gain of a Kalman filter for x = [F, dF/dt] under white
      force acceleration (El-Sinawi 2011, Sec. 4, on the force alone; :func:`lti.kalman_gain`):
      the filter is then linear and time-invariant.
    - ``lowpass``: Park's Butterworth preprocessor as second-order sections (cut-off at most
      0.9 x Nyquist), its unit initial state, and the filtered derivative
      ``y[k] = alpha y[k-1] + (1 - alpha) (x[k] - x[k-1]) / dt``,
      ``alpha = exp(-dt / derivative_time_constant_s)``.
    """
    if params[jit.E_GAIN_DT] == dt_s:
        return
    if settings.force_filter == 'kalman':
        params[jit.E_K0], params[jit.E_K1] = lti.kalman_gain(
            dt_s, settings.kalman_accel_noise_n_s2, settings.kalman_force_noise_n)
    else:
        from scipy import signal  # 0.7-0.9 s to import: only where the low-pass is chosen

        cutoff = min(settings.lowpass_cutoff_hz, 0.9 * 0.5 / dt_s)
        sos = signal.butter(settings.lowpass_order, cutoff, fs=1.0 / dt_s, output='sos')
        if sos.shape[0] > 4:
            raise ValueError(f'lowpass_order {settings.lowpass_order}: more than 4 sections')
        params[jit.E_NSEC] = sos.shape[0]
        params[jit.E_SOS:jit.E_SOS + sos.size] = sos.ravel()
        zi = signal.sosfilt_zi(sos) * 1.0
        params[jit.E_SOS_ZI:jit.E_SOS_ZI + zi.size] = zi.ravel()
        alpha = math.exp(-dt_s / settings.derivative_time_constant_s)
        params[jit.E_DB0], params[jit.E_DB1] = np.array([1.0, -1.0]) * (1.0 - alpha) / dt_s
        params[jit.E_DA1] = -alpha
    params[jit.E_GAIN_DT] = dt_s


def detail_text(settings: EstimatorSettings, block: CurrentBlock, code: int, a: float,
                b: float) -> str:
    """The one line (:attr:`ForceEstimate.detail`) for the estimator's detail code and values
    on ``block``."""
    jit = kernel.load()
    if code == jit.D_NONE:
        return ''
    if code == jit.D_LENGTHS:
        arrays = (block.phase_u_a, block.phase_v_a, block.rotor_angle_rad,
                  block.feed_rate_mm_min)
        return f'array lengths {[x.size for x in arrays]} differ or are empty'
    if code == jit.D_DT_BAD:
        return f'sample period {block.sample_period_s!r} s is not a positive number'
    if code == jit.D_DT_CHANGED:
        return f'sample period changed from {a!r} s to {block.sample_period_s!r} s'
    if code == jit.D_NONFINITE:
        return f'{int(a)} non-finite samples'
    if code == jit.D_STAMP_NONFINITE:
        return f'stamp {block.t0_s!r} s is not finite'
    if code == jit.D_STAMP_NOT_AFTER:
        return f'stamp {block.t0_s!r} s is not after the previous {b!r} s'
    if code == jit.D_STAMP_JUMP:
        return (f'stamp {block.t0_s!r} s jumps {b:.6g} s past the previous block '
                f'(max_stamp_jump_s {settings.max_stamp_jump_s:g})')
    if code == jit.D_IMPLAUSIBLE:
        return (f'phase current {a:.3g} A is beyond {IMPLAUSIBLE_RANGE_FACTOR:g} x the '
                f'sensor range ({settings.current_range_a:g} A): not a reading')
    if code == jit.D_OVERFLOW:
        return f'currents overflow the force computation (|i| up to {a:.3g} A)'
    if code == jit.D_FILTER_OVERFLOW:
        return f'force filter overflowed (|i| up to {a:.3g} A)'
    if code == jit.D_SATURATED:
        return f'phase current {a:.3g} A beyond the sensor range'
    return rezeroed_text(a)


def rezeroed_text(scale: float) -> str:
    """The line for a friction re-zero to ``scale``."""
    return f'friction re-zeroed in air: {scale:.3f} x calibrated'


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
