"""The control laws by name: the one list the settings' choices and the controller use."""

from __future__ import annotations

from collections.abc import Mapping

from turning_force.core.control import adaptive, adaptive_pp, adaptive_smc, pi, smc, staircase
from turning_force.core.control.law import Law

__all__ = ['CONTROLLERS']

CONTROLLERS: Mapping[str, Law] = {
    module.LAW.name: module.LAW
    for module in (smc, adaptive, adaptive_smc, adaptive_pp, pi, staircase)
}
