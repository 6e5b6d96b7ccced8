"""The conventional adaptive force controller (Masory & Koren 1980, as Park compares to).

An integral controller on the feed whose gain is divided by an on-line estimate of the
process gain ``K_p = F / f_a`` [N per mm/rev], so that the loop gain stays at
``adaptive_loop_gain_per_s`` whatever the depth of cut::

    f_c(k) = f_c(k-1) - G T (F(k) - F_ref) / K_p_hat(k)

``f_a`` is the controller's own first-order servo model of its commands; it does not know
which override level the PMC applied, as a conventional controller does not.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from turning_force.core.compiled import compiled
from turning_force.core.control.law import (
    C_LAW,
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
    """The conventional adaptive controller's settings."""

    adaptive_loop_gain_per_s: float = setting(3.0, 'Closed-loop integral gain the adaptive '
                                              'controller holds (Masory & Koren); at most '
                                              '1 / control_period_s', '1/s', low=0.0,
                                              low_open=True, high=1e4, dynamic=True,
                                              cite='Park 1998, Figs. 1-2 (Masory & Koren)')
    adaptive_estimate_time_constant_s: float = setting(0.05, 'Smoothing of the on-line process '
                                                       'gain estimate', 's', low=0.0, high=10.0)

    def check(self) -> None:
        super().check()
        if self.adaptive_loop_gain_per_s * self.control_period_s > 1.0:
            # A discrete integral loop with gain G T > 1 overshoots every period; past 2 it
            # diverges.
            self.fail('adaptive_loop_gain_per_s', f'above 1 / control_period_s '
                                                  f'({1.0 / self.control_period_s:g} 1/s)')


P_MODEL_TAU, P_LOOP_GAIN, P_ESTIMATE_TAU = range(C_LAW, C_LAW + 3)
S_COMMAND, S_MODEL, S_GAIN = range(CS_LAW, CS_LAW + 3)


def fill(settings: ControllerBase) -> tuple[Sequence[float], int]:
    assert isinstance(settings, Settings)
    return [settings.model_servo_time_constant_s, settings.adaptive_loop_gain_per_s,
            settings.adaptive_estimate_time_constant_s], 3


@compiled
def reset(cp: np.ndarray, cs: np.ndarray) -> None:
    held = cs[CS_HELD]
    cs[S_COMMAND] = held
    cs[S_MODEL] = held
    cs[S_GAIN] = math.nan


@compiled
def step(cp: np.ndarray, cs: np.ndarray, force: float, rate: float, out: np.ndarray) -> None:
    """The integral law with the gain estimate (the module's text)."""
    dt = cp[C_PERIOD]
    cs[S_MODEL] += (cs[S_COMMAND] - cs[S_MODEL]) * (1.0 - math.exp(-dt / cp[P_MODEL_TAU]))
    ref = cp[C_REF]
    error = force - ref
    if cs[S_MODEL] > 1.0 and force > 0.05 * ref:
        measured = force / cs[S_MODEL]
        if math.isnan(cs[S_GAIN]):
            cs[S_GAIN] = measured
        else:
            tau = cp[P_ESTIMATE_TAU]
            weight = 1.0 - math.exp(-dt / tau) if tau > 0 else 1.0
            cs[S_GAIN] += weight * (measured - cs[S_GAIN])
    if not math.isnan(cs[S_GAIN]):
        change = cp[P_LOOP_GAIN] * dt * error / cs[S_GAIN]
        cs[S_COMMAND] = clip(cp, cs[S_COMMAND] - change)
    out[OUT_PCT], out[OUT_ERR], out[OUT_S] = cs[S_COMMAND], error, 0.0


LAW = Law('adaptive', Settings, fill,
          'the conventional adaptive controller Park compares against (Masory & Koren 1980)')
