"""Fixed-gain PI on the override with anti-windup by clamping the integral.

``pct = I - kp (F - F_ref)``, ``I += -ki (F - F_ref) T``; where the output would pass a
limit, the integral is set so that it sits on the limit, and it leaves the limit as soon as
the error changes sign.

What commercial adaptive-feed options run.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from turning_force.core.compiled import compiled, pymax, pymin
from turning_force.core.control.law import (
    C_LAW,
    C_MAX,
    C_MIN,
    C_PERIOD,
    C_REF,
    CS_HELD,
    CS_LAW,
    OUT_ERR,
    OUT_PCT,
    OUT_S,
    ControllerBase,
    Law,
    clip,
)
from turning_force.core.settings import setting

__all__ = ['LAW', 'Settings']


@dataclass(frozen=True)
class Settings(ControllerBase):
    """The PI law's gains."""

    # A PI gain past these moves the feed over the whole table for a newton or two of sensor
    # noise: no longer a regulator.
    pi_kp_pct_per_n: float = setting(0.02, 'PI proportional gain', '%/N', low=0.0, high=10.0,
                                     dynamic=True)
    pi_ki_pct_per_n_s: float = setting(0.2, 'PI integral gain', '%/(N s)', low=0.0, high=100.0,
                                       dynamic=True)


P_KP, P_KI = C_LAW, C_LAW + 1
S_INTEGRAL = CS_LAW


def fill(settings: ControllerBase) -> tuple[Sequence[float], int]:
    assert isinstance(settings, Settings)
    return [settings.pi_kp_pct_per_n, settings.pi_ki_pct_per_n_s], 1


@compiled
def reset(cp: np.ndarray, cs: np.ndarray) -> None:
    cs[S_INTEGRAL] = cs[CS_HELD]


@compiled
def step(cp: np.ndarray, cs: np.ndarray, force: float, rate: float, out: np.ndarray) -> None:
    """PI, the integral clamped (the module's text)."""
    error = force - cp[C_REF]
    proportional = -cp[P_KP] * error
    integral = cs[S_INTEGRAL] - cp[P_KI] * error * cp[C_PERIOD]
    cs[S_INTEGRAL] = pymin(pymax(integral, cp[C_MIN] - proportional), cp[C_MAX] - proportional)
    out[OUT_PCT], out[OUT_ERR], out[OUT_S] = clip(cp, cs[S_INTEGRAL] + proportional), error, 0.0


LAW = Law('pi', Settings, fill, 'fixed-gain PI with anti-windup')
