"""A relay with a dead band on the feedrate override: the force limiter of the first
adaptive-control-constraint systems, before regulation.

With ``e = F - F_ref`` and the override ``u`` [%] ramped at ``r`` [%/s] for one control period
``T``::

    u(k) = u(k-1) - r T    if e > b
    u(k) = u(k-1) + r T    if e < -b
    u(k) = u(k-1)          otherwise

clipped to the override table. Inside the band ``b`` the feed is left alone; outside it, the
override ramps towards the band. The loop is an integrator with a relay: it settles in the band
where the ramp of one dead time moves the force less than ``2 b``, and limit-cycles around it
elsewhere.
"""

from __future__ import annotations

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


@dataclass(frozen=True)
class Settings(ControllerBase):
    """The relay's band and ramp (force_controller parameters)."""

    relay_band_n: float = setting(20.0, 'Dead band b around the reference: no change inside it',
                                  'N', low=0.0, high=1e5, dynamic=True)
    relay_ramp_pct_s: float = setting(100.0, 'Ramp r of the override outside the band', '%/s',
                                      low=0.0, low_open=True, high=1e4, dynamic=True)


P_BAND, P_RAMP = C_LAW, C_LAW + 1
S_OVERRIDE = CS_LAW


def fill(settings: ControllerBase) -> tuple[Sequence[float], int]:
    assert isinstance(settings, Settings)
    return [settings.relay_band_n, settings.relay_ramp_pct_s], 1


@compiled
def reset(cp: np.ndarray, cs: np.ndarray) -> None:
    cs[S_OVERRIDE] = cs[CS_HELD]


@compiled
def step(cp: np.ndarray, cs: np.ndarray, force: float, rate: float, out: np.ndarray) -> None:
    error = force - cp[C_REF]
    change = cp[P_RAMP] * cp[C_PERIOD]
    if error > cp[P_BAND]:
        cs[S_OVERRIDE] = clip(cp, cs[S_OVERRIDE] - change)
    elif error < -cp[P_BAND]:
        cs[S_OVERRIDE] = clip(cp, cs[S_OVERRIDE] + change)
    out[OUT_PCT], out[OUT_ERR], out[OUT_S] = cs[S_OVERRIDE], error, 0.0


LAW = Law('relay', Settings, fill, 'a relay with a dead band on the override (an example)')
