"""Friction calibration (Park 1998, Eq. 25) from air-cut sessions.

An air cut is the programmed feed with no tool contact, recorded with the option disarmed: the
q-axis current is then friction plus Eq. 26's zero-force offset. Each session, once its feed has
settled, gives one point (feed, friction current); two or more feeds fit Eq. 25's curve
(:func:`turning_force.core.estimation.settings.calibrate_friction`). The result is the four
``force_estimator`` parameters that describe it.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from turning_force.core.errors import ConfigError
from turning_force.core.estimation.settings import air_cut_point, calibrate_friction
from turning_force.core.plant.drive import CurrentBlock, FrictionModel
from turning_force.session.bag import BagError
from turning_force.session.reader import Session

__all__ = ['Calibration', 'calibrate']


@dataclass(frozen=True)
class Calibration:
    model: FrictionModel
    feeds_mm_min: tuple[float, ...]
    currents_a: tuple[float, ...]

    def estimator_parameters(self) -> dict[str, float]:
        """The ``force_estimator`` parameters that hold this curve."""
        return self.model.parameters()

    def residual_a(self) -> float:
        """Largest distance of a measured point from the fitted curve [A]."""
        fitted = self.model.current_a(np.asarray(self.feeds_mm_min))
        return float(np.max(np.abs(fitted - np.asarray(self.currents_a))))


def _steady(session: Session, settle_s: float) -> CurrentBlock:
    """The session's blocks after ``settle_s``, joined into one."""
    starts = session.block_starts_s
    keep = np.flatnonzero(starts >= starts[0] + settle_s)
    if not keep.size:
        raise BagError(f'{session.path}: nothing left after the first {settle_s} s')
    if session.has_truth and np.nanmax(np.abs(session.signals['force_n'])) > 1.0:
        raise BagError(f'{session.path}: the tool cut (force up to '
                       f'{np.nanmax(session.signals["force_n"]):.0f} N): not an air cut')
    fields = ('phase_u_a', 'phase_v_a', 'rotor_angle_rad', 'feed_rate_mm_min')
    c = session.currents
    if c is not None:   # the arrays, rows kept, one after the other
        return CurrentBlock(float(starts[keep[0]]), c.sample_period_s,
                            *(getattr(c, f)[keep[0]:].reshape(-1) for f in fields))
    blocks = session.blocks[int(keep[0]):]
    return CurrentBlock(blocks[0].t0_s, blocks[0].sample_period_s,
                        *(np.concatenate([getattr(b, f) for b in blocks]) for f in fields))


def calibrate(sessions: Sequence[Session], settle_s: float = 0.5) -> Calibration:
    """Fit Eq. 25 to air cuts, one steady feed per session; ``settle_s`` [s] left out of each."""
    if not 0.0 <= settle_s < math.inf:
        raise ConfigError(f'--settle-s {settle_s!r}: expected a finite time >= 0 s')
    if not sessions:
        raise BagError('calibrate: no sessions given')
    experiment = sessions[0].experiment
    if experiment is None:
        raise BagError(f'{sessions[0].path}: no recorded settings: the current map (Eq. 26) '
                       'is needed')
    steady = [_steady(s, settle_s) for s in sessions]
    current_map = experiment.estimator.current_map
    points = [air_cut_point(b, current_map) for b in steady]
    return Calibration(calibrate_friction(steady, current_map),
                       tuple(p[0] for p in points), tuple(p[1] for p in points))
