"""From a DAQ's raw samples to a block of feed-drive currents (the core side of ``servo_daq``).

Park's set-up (Park et al. 1998, Sec. 3) measures the u and v phase currents of the feed servo
motor with Hall-effect current sensors; the third phase follows from ``i_u + i_v + i_w = 0``.
The rotor's electrical angle, needed for the d-q transform, comes from the motor's encoder (a
counter of A/B quadrature edges) or from an analog angle output of the drive. A hardware-timed
DAQ delivers both in blocks on one sample clock; :class:`DaqConverter` turns each block into a
:class:`~turning_force.core.plant.drive.CurrentBlock`:

- phase current ``i = (u_volts - offset_v) * hall_scale_a_per_v`` per phase;
- mechanical position in motor revolutions: ``counts / encoder_counts_per_rev`` (encoder) or
  the unwrapped electrical angle over ``2 pi pole_pairs`` (analog angle);
- electrical angle ``theta = mod(zero + 2 pi pole_pairs revs, 2 pi)`` (as
  :func:`~turning_force.core.plant.drive.rotor_angle_rad` for a motor on the ball screw);
- feed rate from the position ``feed_rate_window`` samples back:
  ``v[k] = pitch (revs[k] - revs[k - W]) / (W T) * 60`` [mm/min], so that one encoder count
  does not become a spike; the window reaches into the previous block.

Pure numpy: no driver, no ROS; tested on the reference session's arrays.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from turning_force.core.errors import ConfigError
from turning_force.core.plant.drive import CurrentBlock
from turning_force.core.settings import Settings, setting

__all__ = ['DaqConverter', 'DaqSettings']

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class DaqSettings(Settings):
    """The NI-DAQ on the machine PC (``servo_daq`` parameters)."""

    SECTION = 'servo_daq'

    device: str = setting('Dev1', 'NI-DAQ device name, as NI MAX shows it')
    current_u_channel: str = setting('ai0', 'Analog input of the u-phase Hall sensor')
    current_v_channel: str = setting('ai1', 'Analog input of the v-phase Hall sensor')
    angle_input: str = setting('encoder', 'Rotor angle from the motor encoder (a counter) or '
                               'an analog angle output of the drive', choices=('encoder',
                                                                               'analog'))
    encoder_counter: str = setting('ctr0', 'Counter the encoder A/B (and Z) lines go to')
    angle_channel: str = setting('ai2', 'Analog input of the rotor angle (angle_input analog)')
    sample_rate_hz: float = setting(1000.0, 'Sample clock of currents and angle', 'Hz',
                                    low=10.0, high=1e6)
    samples_per_block: int = setting(10, 'Samples per published block (one control period)',
                                     low=1, high=1_000_000, unit='-')
    input_range_v: float = setting(10.0, 'Analog input range, +/-', 'V', low=0.0,
                                   low_open=True, high=10.0)
    hall_scale_a_per_v: float = setting(10.0, 'Phase current per volt of Hall sensor output '
                                        '(both phases)', 'A/V', low=0.0, low_open=True, high=1e4)
    current_u_offset_v: float = setting(0.0, 'u-phase sensor output at zero current', 'V',
                                        low=-10.0, high=10.0)
    current_v_offset_v: float = setting(0.0, 'v-phase sensor output at zero current', 'V',
                                        low=-10.0, high=10.0)
    encoder_counts_per_rev: int = setting(10000, 'Encoder counts per motor revolution, after '
                                          'x4 decoding', low=1, unit='-', high=2**31 - 1)
    angle_v_per_rad: float = setting(10.0 / (2.0 * math.pi), 'Analog angle output: volts per '
                                     'electrical radian (0 V at 0 rad)', 'V/rad', low=0.0,
                                     low_open=True, high=1e3)
    electrical_zero_rad: float = setting(0.0, 'Electrical angle at encoder count 0 (the '
                                         "encoder's alignment to the rotor)", 'rad',
                                         low=-2.0 * math.pi, high=2.0 * math.pi)
    pole_pairs: int = setting(4, 'Pole pairs of the feed servo motor', low=1, high=64, unit='-')
    ball_screw_pitch_mm: float = setting(12.0, 'Ball-screw pitch (motor on the screw)', 'mm',
                                         low=0.0, low_open=True, high=100.0)
    feed_rate_window: int = setting(10, 'Samples the feed rate is differenced over', low=1,
                                    high=100000, unit='-')
    frame_id: str = setting('z_axis', 'frame_id of the published blocks')

    @property
    def sample_period_s(self) -> float:
        return 1.0 / self.sample_rate_hz


class DaqConverter:
    """Raw DAQ blocks -> :class:`CurrentBlock`, carrying the position history across blocks."""

    def __init__(self, settings: DaqSettings) -> None:
        self.settings = settings
        self._history = np.empty(0)   # the last feed_rate_window positions [rev]
        self._last_angle = math.nan   # analog: the last unwrapped electrical angle [rad]

    def phase_currents_a(self, u_volts: npt.ArrayLike,
                         v_volts: npt.ArrayLike) -> tuple[FloatArray, FloatArray]:
        """u and v phase currents [A] from the Hall sensors' voltages."""
        s = self.settings
        u = (np.asarray(u_volts, dtype=np.float64) - s.current_u_offset_v) * s.hall_scale_a_per_v
        v = (np.asarray(v_volts, dtype=np.float64) - s.current_v_offset_v) * s.hall_scale_a_per_v
        return u, v

    def revolutions(self, angle_samples: npt.ArrayLike) -> FloatArray:
        """Motor position [rev] from encoder counts, or from analog angle volts."""
        s = self.settings
        raw = np.asarray(angle_samples, dtype=np.float64)
        if s.angle_input == 'encoder':
            out: FloatArray = raw / s.encoder_counts_per_rev
            return out
        theta = raw / s.angle_v_per_rad
        if math.isfinite(self._last_angle):   # unwrap across the block boundary
            theta = np.concatenate([[self._last_angle], theta])
            unwrapped = np.unwrap(theta)[1:]
        else:
            unwrapped = np.unwrap(theta)
        if unwrapped.size:
            self._last_angle = float(unwrapped[-1])
        revs: FloatArray = unwrapped / (2.0 * math.pi * s.pole_pairs)
        return revs

    def convert(self, t0_s: float, u_volts: npt.ArrayLike, v_volts: npt.ArrayLike,
                angle_samples: npt.ArrayLike) -> CurrentBlock:
        """One block: sample ``k`` was taken at ``t0_s + k / sample_rate_hz``."""
        s = self.settings
        phase_u, phase_v = self.phase_currents_a(u_volts, v_volts)
        revs = self.revolutions(angle_samples)
        if not phase_u.size == phase_v.size == revs.size:
            raise ConfigError(f'servo_daq: a block of {phase_u.size} u, {phase_v.size} v and '
                              f'{revs.size} angle samples: need one of each per sample')
        if s.angle_input == 'encoder':
            angle = np.mod(s.electrical_zero_rad + 2.0 * math.pi * s.pole_pairs * revs,
                           2.0 * math.pi)
        else:
            angle = np.mod(2.0 * math.pi * s.pole_pairs * revs, 2.0 * math.pi)
        window = s.feed_rate_window
        joined = np.concatenate([self._history, revs])
        back = np.arange(joined.size) - window
        first = self._history.size
        # Where the history is shorter than the window (the first block), the oldest sample.
        idx = np.clip(back[first:], 0, None)
        steps = (np.arange(first, joined.size) - idx).astype(np.float64)
        delta = joined[first:] - joined[idx]
        with np.errstate(invalid='ignore', divide='ignore'):
            rate = np.where(steps > 0, delta / (steps * s.sample_period_s), 0.0)
        feed = rate * s.ball_screw_pitch_mm * 60.0
        self._history = joined[-window:]
        return CurrentBlock(t0_s=t0_s, sample_period_s=s.sample_period_s, phase_u_a=phase_u,
                            phase_v_a=phase_v, rotor_angle_rad=angle,
                            feed_rate_mm_min=feed.astype(np.float64))
