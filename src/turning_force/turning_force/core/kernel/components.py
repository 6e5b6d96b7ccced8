"""The estimator and the controllers on the kernel, one block at a time, behind the reference
classes' interfaces: what the nodes and :class:`turning_force.core.loop.ControlChain` (replay)
run when the kernel covers their settings. The one-line details the reference writes are
written here from the kernel's codes and values, word for word."""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from turning_force.core.control import Controller, ControllerSettings, ControlOutput
from turning_force.core.control import make_controller as make_reference_controller
from turning_force.core.drive import CurrentBlock
from turning_force.core.estimation import (
    IMPLAUSIBLE_RANGE_FACTOR,
    EstimateStatus,
    EstimatorSettings,
    ForceEstimate,
    ForceEstimator,
)
from turning_force.core.kernel import jit as K
from turning_force.core.kernel import pack

__all__ = ['CompiledController', 'CompiledEstimator', 'detail_text']

FloatArray = npt.NDArray[np.float64]


def _contiguous(values: FloatArray) -> FloatArray:
    """What the kernel's signature takes: C-contiguous, writable float64 (a block decoded from
    a bag is a read-only view of the message's buffer)."""
    out = np.ascontiguousarray(values, dtype=np.float64)
    return out if out.flags.writeable else out.copy()


class CompiledEstimator:
    """:class:`ForceEstimator` on the kernel (same estimates, same details, same restarts)."""

    compiled = True

    def __init__(self, settings: EstimatorSettings,
                 reference: ForceEstimator | None = None) -> None:
        self.settings = settings
        reference = reference or ForceEstimator(settings)
        self._params = pack.estimator_params(settings)
        self._state = pack.estimator_state(reference, self._params)
        self._work = np.empty(0)
        self._last = reference.last

    @property
    def last(self) -> ForceEstimate:
        return self._last

    @property
    def friction_scale(self) -> float:
        return float(self._state[K.ES_SCALE])

    @property
    def restarts(self) -> int:
        return int(self._state[K.ES_RESTARTS])

    def update(self, block: CurrentBlock) -> ForceEstimate:
        """ForceEstimator.update."""
        dt = block.sample_period_s
        if self._state[K.ES_ACTIVE] == 0.0 and math.isfinite(dt) and dt > 0:
            pack.set_filter(self._params, self.settings, dt)   # a new filter may start
        n = len(block)
        if self._work.size < 2 * n:
            self._work = np.empty(2 * n)
        status = int(K.estimate_block(
            self._params, self._state, float(block.t0_s), float(dt),
            _contiguous(block.phase_u_a), _contiguous(block.phase_v_a),
            _contiguous(block.rotor_angle_rad), _contiguous(block.feed_rate_mm_min),
            self._work))
        s = self._state
        if status == K.INVALID_INPUT:
            last = self._last
            self._last = ForceEstimate(last.t_s, last.force_n, last.force_rate_n_s,
                                       last.current_q_a, last.friction_current_a,
                                       EstimateStatus.INVALID_INPUT, self._detail(block))
        else:
            self._last = ForceEstimate(float(s[K.ES_T]), float(s[K.ES_F]), float(s[K.ES_R]),
                                       float(s[K.ES_IQ]), float(s[K.ES_IFR]),
                                       EstimateStatus(status), self._detail(block))
        return self._last

    def _detail(self, block: CurrentBlock) -> str:
        """The reference's one line for the kernel's detail code."""
        s = self._state
        return detail_text(self.settings, block, int(s[K.ES_DCODE]), float(s[K.ES_DVAL]),
                           float(s[K.ES_DVAL + 1]))


def detail_text(settings: EstimatorSettings, block: CurrentBlock, code: int, a: float,
                b: float) -> str:
    """The reference estimator's one line (ForceEstimate.detail) for the kernel's detail code
    and values on ``block``."""
    if code == K.D_NONE:
        return ''
    if code == K.D_LENGTHS:
        arrays = (block.phase_u_a, block.phase_v_a, block.rotor_angle_rad,
                  block.feed_rate_mm_min)
        return f'array lengths {[x.size for x in arrays]} differ or are empty'
    if code == K.D_DT_BAD:
        return f'sample period {block.sample_period_s!r} s is not a positive number'
    if code == K.D_DT_CHANGED:
        return f'sample period changed from {a!r} s to {block.sample_period_s!r} s'
    if code == K.D_NONFINITE:
        return f'{int(a)} non-finite samples'
    if code == K.D_STAMP_NONFINITE:
        return f'stamp {block.t0_s!r} s is not finite'
    if code == K.D_STAMP_NOT_AFTER:
        return f'stamp {block.t0_s!r} s is not after the previous {b!r} s'
    if code == K.D_STAMP_JUMP:
        return (f'stamp {block.t0_s!r} s jumps {b:.6g} s past the previous block '
                f'(max_stamp_jump_s {settings.max_stamp_jump_s:g})')
    if code == K.D_IMPLAUSIBLE:
        return (f'phase current {a:.3g} A is beyond {IMPLAUSIBLE_RANGE_FACTOR:g} x the '
                f'sensor range ({settings.current_range_a:g} A): not a reading')
    if code == K.D_OVERFLOW:
        return f'currents overflow the force computation (|i| up to {a:.3g} A)'
    if code == K.D_FILTER_OVERFLOW:
        return f'force filter overflowed (|i| up to {a:.3g} A)'
    if code == K.D_SATURATED:
        return f'phase current {a:.3g} A beyond the sensor range'
    return rezeroed_text(a)


def rezeroed_text(scale: float) -> str:
    """The reference's line for a friction re-zero (``K.D_REZEROED``) to ``scale``."""
    return f'friction re-zeroed in air: {scale:.3f} x calibrated'


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
