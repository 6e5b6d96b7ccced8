"""The force controller's settings (``force_controller`` parameters): what every law shares
(:class:`~turning_force.core.control.law.ControllerBase`) and each law's own, composed from the
laws installed (:func:`~turning_force.core.control.registry.compose`)."""

from __future__ import annotations

from typing import TYPE_CHECKING

from turning_force.core.control.law import ControllerBase
from turning_force.core.control.registry import compose

__all__ = ['ControllerSettings']

if TYPE_CHECKING:
    ControllerSettings = ControllerBase
else:
    ControllerSettings = compose()
