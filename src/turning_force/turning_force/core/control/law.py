"""What a control law is to the controller that runs it (:class:`Law`)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from types import ModuleType
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt

if TYPE_CHECKING:
    from turning_force.core.control.settings import ControllerSettings

__all__ = ['Law']

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class Law:
    """A control law as the compiled controller runs it.

    ``kind``: its number in ``controller_update``'s dispatch (``jit.SMC``, ...). ``fill``: reads
    the law's settings (and what it derives from them: models, initial estimates) into the
    parameters ``p`` (``C_*`` slots); returns the parameters (a longer array where the law
    needs more slots) and the length of the state's queue (``CS_QUEUE`` on)."""

    name: str
    kind: Callable[[ModuleType], int]
    fill: Callable[[ModuleType, ControllerSettings, FloatArray], tuple[FloatArray, int]]
    summary: str
