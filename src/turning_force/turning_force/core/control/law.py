"""What a control law is to the controller that runs it (:class:`Law`), and what it gives
(:class:`ControlOutput`)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from types import ModuleType
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt

if TYPE_CHECKING:
    from turning_force.core.control.settings import ControllerSettings

__all__ = ['ControlOutput', 'Law']

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


@dataclass(frozen=True)
class ControlOutput:
    """One control decision (the core side of ``FeedCommand``).

    ``error_n`` is ``F - F_ref`` (Park Eq. 9); ``sliding_variable`` is the controller's ``s``
    (0 for controllers that have none); ``reachable`` is false once the request has sat at the
    table's end, pushing the wrong way for the force to follow, for ``unreachable_after_s``: at
    150 % with the force still below the reference (the cut is too light for it), or at 0 %
    with it still above.
    """

    override_pct: float
    error_n: float
    sliding_variable: float
    reachable: bool = True
