"""The feed drive as a force sensor: phase currents, d-q transform, friction, current-to-force.

Shared by the plant simulator (force -> currents) and the estimator (currents -> force), so the two
directions are one set of equations (Park 1998, Sec. 3).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from turning_force.core.errors import ConfigError
from turning_force.core.settings import Settings, setting

__all__ = ['CurrentBlock', 'CurrentForceMap', 'FeedDriveSettings', 'FrictionModel', 'clarke_park',
           'inverse_park_clarke', 'rotor_angle_rad']

FloatArray = npt.NDArray[np.float64]
_SQRT3 = math.sqrt(3.0)


@dataclass(frozen=True)
class CurrentBlock:
    """A block of feed-drive samples as a DAQ delivers it (the core side of ``ServoCurrents``).

    Sample ``k`` was taken at ``t0_s + k * sample_period_s``.
    """

    t0_s: float
    sample_period_s: float
    phase_u_a: FloatArray
    phase_v_a: FloatArray
    rotor_angle_rad: FloatArray
    feed_rate_mm_min: FloatArray

    def __len__(self) -> int:
        return int(self.phase_u_a.size)


def clarke_park(
    phase_u_a: FloatArray, phase_v_a: FloatArray, angle_rad: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """u, v phase currents and electrical angle -> (i_d, i_q), amplitude-invariant.

    Clarke with a balanced three-phase set (i_u + i_v + i_w = 0):
    ``i_alpha = i_u``, ``i_beta = (i_u + 2 i_v) / sqrt(3)``; then Park's rotation into the rotor
    frame: ``i_d = i_alpha cos(theta) + i_beta sin(theta)``,
    ``i_q = -i_alpha sin(theta) + i_beta cos(theta)``. The d-q frame turns with the rotor, so a
    steady torque gives a DC i_q (Park 1998, Sec. 3).
    """
    i_alpha = phase_u_a
    i_beta = (phase_u_a + 2.0 * phase_v_a) / _SQRT3
    cos, sin = np.cos(angle_rad), np.sin(angle_rad)
    return i_alpha * cos + i_beta * sin, -i_alpha * sin + i_beta * cos


def inverse_park_clarke(
    current_d_a: FloatArray, current_q_a: FloatArray, angle_rad: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """(i_d, i_q) and electrical angle -> (i_u, i_v): the inverse of :func:`clarke_park`."""
    cos, sin = np.cos(angle_rad), np.sin(angle_rad)
    i_alpha = current_d_a * cos - current_q_a * sin
    i_beta = current_d_a * sin + current_q_a * cos
    return i_alpha, (-i_alpha + _SQRT3 * i_beta) / 2.0


def rotor_angle_rad(position_mm: FloatArray, pitch_mm: float, pole_pairs: int) -> FloatArray:
    """Electrical rotor angle in [0, 2 pi) of a motor driving a ball screw directly."""
    return np.mod(2.0 * math.pi * pole_pairs * position_mm / pitch_mm, 2.0 * math.pi)


@dataclass(frozen=True)
class FrictionModel:
    """Feed-drive friction as a current, quadratic in feed rate (Park 1998, Eq. 25).

    ``I_fric = a (v_a - v_min)^2 + b`` for ``v_min <= v_a <= v_max``, with
    ``a = (I_fric(v_max) - I_fric(v_min)) / (v_max - v_min)^2`` and ``b = I_fric(v_min)``.
    Outside the calibrated range the curve is held at its end values, and below ``v_min`` it
    falls linearly to zero at standstill, where a stuck slide carries no Coulomb friction.
    Friction opposes motion, so the current has the sign of the feed rate.
    """

    a_a_per_mm_min2: float
    b_a: float
    min_feed_mm_min: float
    max_feed_mm_min: float

    def __post_init__(self) -> None:
        values = (self.a_a_per_mm_min2, self.b_a, self.min_feed_mm_min, self.max_feed_mm_min)
        if not all(math.isfinite(v) for v in values):
            raise ConfigError(f'friction model {values!r}: values must be finite')
        if not 0.0 < self.min_feed_mm_min < self.max_feed_mm_min:
            raise ConfigError(
                f'friction feeds min={self.min_feed_mm_min!r}, max={self.max_feed_mm_min!r} '
                'mm/min: need 0 < min < max'
            )

    @classmethod
    def from_end_points(
        cls, min_feed_mm_min: float, max_feed_mm_min: float, at_min_a: float, at_max_a: float
    ) -> FrictionModel:
        """Eq. 25's coefficients from the friction currents at the slowest and fastest feed."""
        span = max_feed_mm_min - min_feed_mm_min
        if not span > 0:
            raise ConfigError(
                f'friction feeds min={min_feed_mm_min!r}, max={max_feed_mm_min!r} mm/min: '
                'need min < max'
            )
        return cls((at_max_a - at_min_a) / span**2, at_min_a, min_feed_mm_min, max_feed_mm_min)

    @classmethod
    def calibrate(
        cls, feed_mm_min: Sequence[float], current_q_a: Sequence[float]
    ) -> FrictionModel:
        """Fit Eq. 25 to an air cut: mean i_q measured at two or more constant feeds.

        ``v_min`` and ``v_max`` are the slowest and fastest feeds cut; ``a`` and ``b`` are the
        least-squares fit of ``i_q = a (v - v_min)^2 + b`` (exact through two points).
        """
        v = np.asarray(feed_mm_min, dtype=float)
        i = np.asarray(current_q_a, dtype=float)
        if v.shape != i.shape or v.ndim != 1:
            raise ConfigError(
                f'friction calibration: {v.size} feeds and {i.size} currents do not pair up'
            )
        if not (np.all(np.isfinite(v)) and np.all(np.isfinite(i))):
            raise ConfigError('friction calibration: feeds and currents must be finite')
        if np.unique(v).size < 2 or np.any(v <= 0):
            raise ConfigError(
                f'friction calibration: feeds {v.tolist()!r} mm/min: need two or more distinct '
                'positive feeds'
            )
        v_min, v_max = float(v.min()), float(v.max())
        design = np.column_stack([(v - v_min) ** 2, np.ones_like(v)])
        (a, b), *_ = np.linalg.lstsq(design, i, rcond=None)
        return cls(float(a), float(b), v_min, v_max)

    def parameters(self) -> dict[str, float]:
        """The ``force_estimator`` parameters that hold this curve: its end points."""
        span = self.max_feed_mm_min - self.min_feed_mm_min
        return {'friction_min_feed_mm_min': self.min_feed_mm_min,
                'friction_max_feed_mm_min': self.max_feed_mm_min,
                'friction_at_min_feed_a': self.b_a,
                'friction_at_max_feed_a': self.a_a_per_mm_min2 * span**2 + self.b_a}

    def current_a(self, feed_rate_mm_min: FloatArray) -> FloatArray:
        """Friction current [A] at the given feed rates [mm/min] (Eq. 25)."""
        speed = np.abs(feed_rate_mm_min)
        v = np.clip(speed, self.min_feed_mm_min, self.max_feed_mm_min)
        quadratic = self.a_a_per_mm_min2 * (v - self.min_feed_mm_min) ** 2 + self.b_a
        stick = np.minimum(speed / self.min_feed_mm_min, 1.0)
        return np.sign(feed_rate_mm_min) * stick * quadratic


@dataclass(frozen=True)
class CurrentForceMap:
    """The static map between friction-free q-axis current and cutting force (Park 1998, Eq. 26).

    ``I_q = offset_a + per_force_a_n * F_c``; Park's FANUC 0-T z axis: ``-0.12432 + 0.00629 F``,
    about 145 N per ampere.
    """

    offset_a: float = -0.12432
    per_force_a_n: float = 0.00629

    def __post_init__(self) -> None:
        if not (math.isfinite(self.offset_a) and math.isfinite(self.per_force_a_n)):
            raise ConfigError(f'current-force map {self!r}: values must be finite')
        if self.per_force_a_n <= 0:
            raise ConfigError(
                f'current_per_force_a_n = {self.per_force_a_n!r}: must be positive'
            )

    def current_a(self, force_n: FloatArray) -> FloatArray:
        return self.offset_a + self.per_force_a_n * force_n

    def force_n(self, current_a: FloatArray) -> FloatArray:
        return (current_a - self.offset_a) / self.per_force_a_n


@dataclass(frozen=True)
class FeedDriveSettings(Settings):
    """The feed drive as a force sensor: friction (Eq. 25) and current-to-force (Eq. 26).

    The simulator holds the machine's true values; the estimator holds what calibration found
    (:func:`turning_force.core.estimation.settings.calibrate_friction`). The same fields serve
    both. """

    friction_min_feed_mm_min: float = setting(6.0, 'Slowest feed of the friction curve (Park '
                                              'Eq. 25)', 'mm/min', low=0.0, low_open=True,
                                              high=1e5, cite='Park 1998, Eq. 25')
    friction_max_feed_mm_min: float = setting(300.0, 'Fastest feed of the friction curve',
                                              'mm/min', low=0.0, low_open=True, high=1e5,
                                              cite='Park 1998, Eq. 25')
    friction_at_min_feed_a: float = setting(0.60, 'Friction current at the slowest feed', 'A',
                                            low=-100.0, high=100.0, cite='Park 1998, Eq. 25')
    friction_at_max_feed_a: float = setting(0.35, 'Friction current at the fastest feed', 'A',
                                            low=-100.0, high=100.0, cite='Park 1998, Eq. 25')
    current_offset_a: float = setting(-0.12432, 'q-axis current at zero force (Park Eq. 26)',
                                      'A', low=-100.0, high=100.0, cite='Park 1998, Eq. 26')
    current_per_force_a_n: float = setting(0.00629, 'q-axis current per newton of cutting force '
                                           '(Park Eq. 26)', 'A/N', low=0.0, low_open=True,
                                           high=1.0, cite='Park 1998, Eq. 26')

    def check(self) -> None:
        if self.friction_max_feed_mm_min <= self.friction_min_feed_mm_min:
            self.fail('friction_max_feed_mm_min', 'must exceed friction_min_feed_mm_min '
                      f'({self.friction_min_feed_mm_min})')

    @property
    def friction(self) -> FrictionModel:
        return FrictionModel.from_end_points(
            self.friction_min_feed_mm_min, self.friction_max_feed_mm_min,
            self.friction_at_min_feed_a, self.friction_at_max_feed_a)

    @property
    def current_map(self) -> CurrentForceMap:
        return CurrentForceMap(self.current_offset_a, self.current_per_force_a_n)
