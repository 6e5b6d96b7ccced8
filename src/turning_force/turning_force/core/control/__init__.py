"""Cutting-force controllers behind one interface, chosen by name.

Each controller takes, once per control period, the estimated force and force rate and the
reference, and returns the feedrate override it asks for: continuous, in percent of the programmed
feed, inside the override table's range. The PMC's quantisation happens after it (see
:mod:`turning_force.core.pmc.overrides`); the controllers do not see it, as on a real CNC.

One module per law, in :mod:`.laws` (or in a package of its own, through the
``turning_force.laws`` entry point group: :mod:`.registry`); ours:

- ``smc``: continuous sliding mode control (Park 1998, Eqs. 5-21).
- ``adaptive``: the conventional adaptive controller Park compares against: an integral
  controller whose gain follows an on-line estimate of the process gain (Masory & Koren 1980).
- ``adaptive_smc``: discrete adaptive sliding mode control with a variable forgetting factor
  (Hwang & Chen 1990, Eqs. 11-39, Remarks 1-2).
- ``adaptive_pp``: Kim's adaptive controller: recursive least squares on an ARMA model (Kim
  Eq. 12) with dead zone and covariance resetting, and a pole-placement controller with
  integral action (a servo-compensator, Kim Eqs. 16-18) redesigned every period.
- ``pi``: fixed-gain PI with anti-windup, what commercial adaptive-feed options run.
- ``staircase``: no regulation: a scripted override staircase, the commissioning experiment's
  excitation for ``turning-force identify``.

The two adaptive laws share one recursive least-squares estimator (:mod:`.rls`), and the
sliding mode law a Smith predictor (:mod:`.predictor`). The names, the settings
(:mod:`.settings`) and the compiled dispatch (:mod:`.dispatch`) come from one registry
(:mod:`.registry`). Every law runs compiled, through one :class:`Controller` (:mod:`.base`)
and :mod:`.update`, which does around each law's step what every law shares.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from turning_force.core.control.law import ControlOutput, Law
from turning_force.core.control.registry import CONTROLLERS
from turning_force.core.control.settings import ControllerSettings

if TYPE_CHECKING:
    from turning_force.core.control.base import Controller

__all__ = ['CONTROLLERS', 'ControlOutput', 'ControllerSettings', 'Law', 'make_controller']


def make_controller(settings: ControllerSettings) -> Controller:
    """The controller running the law ``settings.controller`` names (validated by the
    settings); its compiled code is imported here, not with the settings."""
    from turning_force.core.control.base import Controller

    return Controller(settings)
