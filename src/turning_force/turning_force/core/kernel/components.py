"""The controllers on the kernel, one block at a time, behind the reference classes'
interface: what the nodes and :class:`turning_force.core.loop.ControlChain` (replay) run when
the kernel covers their settings."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from turning_force.core.control import Controller, ControllerSettings, ControlOutput
from turning_force.core.control import make_controller as make_reference_controller
from turning_force.core.kernel import jit as K
from turning_force.core.kernel import pack

__all__ = ['CompiledController']

FloatArray = npt.NDArray[np.float64]


class CompiledController:
    """A control law (:func:`turning_force.core.control.make_controller`) on the kernel: the
    same requests, the same resets, the same reachability."""

    compiled = True

    def __init__(self, settings: ControllerSettings,
                 reference: Controller | None = None) -> None:
        self._reference = reference or make_reference_controller(settings)
        self.name = self._reference.name
        self.min_pct, self.max_pct = self._reference.min_pct, self._reference.max_pct
        self._params = pack.controller_params(self._reference)
        self._state = pack.controller_state(self._reference)
        self._levels = pack.levels(self._reference._table)
        self._out = np.zeros(4)

    @property
    def settings(self) -> ControllerSettings:
        return self._reference.settings

    @property
    def resets(self) -> int:
        return int(self._state[K.CS_RESETS])

    def retune(self, settings: ControllerSettings) -> None:
        """Controller.retune: new dynamic settings from the next update on."""
        self._reference.retune(settings)
        self._params = pack.controller_params(self._reference)

    def update(self, force_n: float, force_rate_n_s: float) -> ControlOutput:
        """Controller.update."""
        out = self._out
        K.control_step(self._params, self._state, self._levels, float(force_n),
                       float(force_rate_n_s), out)
        return ControlOutput(float(out[K.OUT_PCT]), float(out[K.OUT_ERR]),
                             float(out[K.OUT_S]), bool(out[K.OUT_REACH] != 0.0))
