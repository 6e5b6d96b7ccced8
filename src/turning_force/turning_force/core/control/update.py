"""One control period, compiled, for every law: the law's ``step`` and what every law shares
around it (:class:`~turning_force.core.control.base.Controller` states it): the guard on
non-finite input, output and state, the error-feedback quantiser, the reachability flag.

The law is chosen by its number (``C_KIND``) through the dispatch
:mod:`turning_force.core.control.dispatch` writes for the laws installed.
:class:`~turning_force.core.control.base.Controller` runs :func:`controller_update` one period
at a time, the compiled loops (:mod:`turning_force.core.kernel.loops`) many periods at once.
"""

from __future__ import annotations

import math

import numpy as np

from turning_force.core.compiled import Arr, compiled, entry, pymax, pymin, quantise
from turning_force.core.control import dispatch
from turning_force.core.control.law import (
    C_CONT,
    C_EF,
    C_GAP,
    C_KIND,
    C_MAX,
    C_MIN,
    C_PERIOD,
    C_REF,
    C_UNREACH,
    CS_CARRY,
    CS_HELD,
    CS_PINNED,
    CS_RESETS,
    CS_SIDE,
    OUT_ERR,
    OUT_PCT,
    OUT_REACH,
    OUT_S,
    clip,
)

__all__ = ['control_step', 'controller_start', 'controller_update']

_laws = dispatch.load()
law_step, law_reset, law_finite, law_sent = _laws.step, _laws.reset, _laws.finite, _laws.sent


@compiled
def _track_reach(cp: np.ndarray, cs: np.ndarray, request: float, error: float) -> float:
    """1.0 while the reference can be reached, else 0.0 (:class:`..control.Controller`)."""
    tolerance = pymin(cp[C_GAP] / 2.0, 5.0)
    side = 0
    if request >= cp[C_MAX] - tolerance and error < 0.0:
        side = 1
    elif request <= cp[C_MIN] + tolerance and error > 0.0:
        side = -1
    pinned_side = int(cs[CS_SIDE])
    if side != 0 and side == pinned_side:
        cs[CS_PINNED] += cp[C_PERIOD]
    elif side != 0:
        cs[CS_SIDE], cs[CS_PINNED] = side, cp[C_PERIOD]
    else:
        reached = (pinned_side == 1 and (error >= 0.0 or request
                                         < cp[C_MAX] - 2.0 * tolerance)) or (
            pinned_side == -1 and (error <= 0.0 or request > cp[C_MIN] + 2.0 * tolerance))
        if reached:
            cs[CS_SIDE], cs[CS_PINNED] = 0.0, 0.0
    return 1.0 if cs[CS_PINNED] < cp[C_UNREACH] else 0.0


@compiled
def _recover(cp: np.ndarray, cs: np.ndarray, error: float, out: np.ndarray) -> None:
    cs[CS_RESETS] += 1.0
    cs[CS_CARRY] = 0.0
    law_reset(int(cp[C_KIND]), cp, cs)
    out[OUT_PCT] = cs[CS_HELD]
    out[OUT_ERR] = error if math.isfinite(error) else 0.0
    out[OUT_S] = 0.0
    out[OUT_REACH] = 1.0


@compiled
def controller_update(cp: np.ndarray, cs: np.ndarray, levels: np.ndarray, force: float,
                      rate: float, out: np.ndarray) -> None:
    """One control period: the law, the guard on its state, the error-feedback quantiser and
    the reachability flag; out = (pct, error, s, reachable)."""
    error = force - cp[C_REF]
    if not (math.isfinite(force) and math.isfinite(rate)):
        _recover(cp, cs, error, out)
        return
    kind = int(cp[C_KIND])
    law_step(kind, cp, cs, force, rate, out)
    if not (math.isfinite(out[OUT_PCT]) and math.isfinite(out[OUT_S])
            and law_finite(kind, cp, cs)):
        _recover(cp, cs, error, out)
        return
    request = out[OUT_PCT]
    continuous = cp[C_CONT] != 0.0
    if cp[C_EF] == 0.0 or continuous:
        sent = request
    else:
        wanted = clip(cp, request + cs[CS_CARRY])
        sent = quantise(levels, continuous, wanted)
        cs[CS_CARRY] = pymin(pymax(request + cs[CS_CARRY] - sent, -cp[C_GAP]), cp[C_GAP])
    law_sent(kind, cp, cs, quantise(levels, continuous, sent))
    cs[CS_HELD] = sent
    out[OUT_REACH] = _track_reach(cp, cs, request, out[OUT_ERR])
    out[OUT_PCT] = sent


@entry('void(float64[::1], float64[::1])')
def controller_start(cp: Arr, cs: Arr) -> None:
    """A controller's first state, from the held request (``CS_HELD``) and its parameters."""
    law_reset(int(cp[C_KIND]), cp, cs)


@entry('void(float64[::1], float64[::1], float64[::1], float64, float64, float64[::1])')
def control_step(cp: Arr, cs: Arr, levels: Arr, force: float, rate: float, out: Arr) -> None:
    """:func:`controller_update` from Python (the nodes, replay)."""
    controller_update(cp, cs, levels, force, rate, out)
