"""One control chain: a block of currents in, the PMC's next override out.

The chain is what the graph does between the DAQ and the PMC, in the graph's order::

    machine inputs                      -> OverrideGate.on_inputs
    block -> ForceEstimator -> estimate -> OverrideGate.on_estimate (overload, cut detector)
    block's axis feed, spindle speed    -> OverrideGate.on_feed (the feed follows the override)
    spindle speed                       -> the controller's (Controller.spindle_speed)
                                        -> command_for (controller)  -> OverrideGate.on_command
                                        -> OverrideGate.answer -> Decision (to the PMC)

A learning cut (teach-in) that has just ended sets the controller's reference from the next block
on, as the bridge's ``force/reference`` does in the graph; cuts that ended go to :attr:`cuts`.
The nodes run the same pieces (``force_estimator`` the estimator, ``force_controller``
:func:`command_for`, ``pmc_bridge`` the gate), compiled where the core loop and replay run them,
so all of them make the same decisions from the same blocks.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
import numpy.typing as npt

from turning_force.core.control import ControllerSettings, ControlOutput, make_controller
from turning_force.core.control.base import Controller
from turning_force.core.errors import ConfigError
from turning_force.core.estimation.estimator import ForceEstimator, rezeroed_scale
from turning_force.core.estimation.settings import EstimatorSettings, ForceEstimate
from turning_force.core.plant.drive import CurrentBlock
from turning_force.core.pmc.gate import OverrideGate
from turning_force.core.pmc.settings import BridgeSettings, Decision
from turning_force.core.pmc.shopfloor import CutRecord, InputValues, Learned, taught_reference

__all__ = ['ChainStep', 'ControlChain', 'check_taught_reference', 'command_for',
           'command_for_would_act']

FloatArray = npt.NDArray[np.float64]


def command_for_would_act(estimate: ForceEstimate) -> bool:
    """Whether a controller acts on this estimate (the bridge, which sees the estimate too,
    then waits for the command instead of answering the block itself).

    A stale or invalid estimate says nothing new (it repeats the last good force): the
    controller sends nothing, and the PMC bridge's watchdog takes over if that goes on.
    """
    return estimate.status.actionable and math.isfinite(estimate.force_n)


def command_for(controller: Controller, estimate: ForceEstimate) -> ControlOutput | None:
    """The controller's command for an estimate, or None where it must not act. An estimate
    that re-zeroed the friction in air tells the controller's drift monitor the scale."""
    if not command_for_would_act(estimate):
        return None
    scale = rezeroed_scale(estimate.detail)
    if scale is not None:
        controller.rezeroed(scale)
    controller.feed(estimate.feed_rate_mm_min)
    return controller.update(estimate.force_n, estimate.force_rate_n_s)


@dataclass(frozen=True)
class ChainStep:
    """What one block led to: the estimate, the command (None if the controller did not act)
    and the gate's decision, which the PMC applies from the next block on."""

    estimate: ForceEstimate
    command: ControlOutput | None
    decision: Decision
    learned: Learned | None = None   # a learning cut that has just ended


class ControlChain:
    """Estimator, controller and override gate, stepped one block at a time.

    ``t_s`` of :meth:`step` is when the decision is made: the end of the block (the block is
    complete one sample after its last sample), which is what the bridge's clock reads when the
    command arrives in a lock-step run.

    ``reference_force_n``: the reference to start from. ``None``: the tool's taught one where
    the bridge names a teach-in file that has it (as the bridge publishes it when configured),
    else the controller settings'. Replay passes the one the session ran with.
    """

    def __init__(self, estimator: EstimatorSettings, controller: ControllerSettings,
                 bridge: BridgeSettings, t_s: float = 0.0,
                 reference_force_n: float | None = None) -> None:
        if reference_force_n is None:
            reference_force_n = taught_reference(bridge)
        if reference_force_n is not None:
            controller = _with_reference(controller, reference_force_n, bridge)
        self.estimator = ForceEstimator(estimator)
        self.controller = make_controller(controller)
        self.gate = OverrideGate(bridge, t_s=t_s)
        self.cuts: list[CutRecord] = []
        self._spindle_speed_rpm = math.nan   # as the machine's inputs last gave it

    def step(self, block: CurrentBlock, t_s: float | None = None,
             inputs: InputValues | None = None) -> ChainStep:
        """Run one block through the chain; ``t_s`` defaults to the end of the block;
        ``inputs``, the machine's inputs at its end (the live spindle speed among them; where
        it is not given, the spindle_speed_rpm parameter), as last given where None."""
        if t_s is None:
            t_s = block.t0_s + len(block) * block.sample_period_s
        if inputs is not None:
            self.gate.on_inputs(inputs)
            speed = inputs.spindle_speed_rpm
            self._spindle_speed_rpm = math.nan if speed is None else speed
            if inputs.tool_number is not None:   # its section, where the tools file has one
                self.controller.select_tool(inputs.tool_number)
        estimate = self.estimator.update(block)
        self.gate.on_estimate(estimate.force_n, estimate.status)
        self.gate.on_feed(float(np.mean(block.feed_rate_mm_min)), self._spindle_speed_rpm)
        self.controller.spindle_speed(self._spindle_speed_rpm)
        command = command_for(self.controller, estimate)
        if command is not None:
            self.gate.on_command(command.override_pct, t_s, command.reachable)
            # the friction the drift monitor read in the cut, off from the next block on
            offset = self.controller.friction_correction()
            line = self.estimator.correct(offset) if offset != 0.0 else ''
            if line:
                estimate = replace(estimate, detail=line)
        decision = self.gate.answer(t_s)
        self.controller.applied(decision.applied_pct, decision.engaged, decision.reason)
        learned = self.gate.take_learned()
        if learned is not None and not learned.refused:
            self.controller.retune(_with_reference(
                self.controller.settings, learned.taught.reference_force_n, self.gate.settings))
        self.cuts.extend(self.gate.take_cuts())
        return ChainStep(estimate, command, decision, learned)

    def arrays(self, sample_period_s: float) -> tuple[FloatArray, ...]:
        """(estimator parameters, state, controller parameters, state, levels, gate
        parameters, state, levels, the controller's and the gate's tool tables) as the
        compiled loops take them, the estimator's filter set for blocks sampled at
        ``sample_period_s`` (where that is a sample period). The estimator's and the
        controller's arrays are their own (live); the gate's are copies
        (:meth:`OverrideGate.arrays`)."""
        ep, es = self.estimator.arrays_for(sample_period_s)
        cp, cs, clevels = self.controller.arrays
        gp, gs, glevels = self.gate.arrays()
        return (ep, es, cp, cs, clevels, gp, gs, glevels, self.controller.tool_table,
                self.gate.tool_table)

    def close(self) -> list[CutRecord]:
        """The end of the session: every cut, the one still open marked incomplete."""
        self.gate.close()
        self.cuts.extend(self.gate.take_cuts())
        return self.cuts


def check_taught_reference(reference_force_n: float, bridge: BridgeSettings) -> None:
    """Refuse a taught reference that would hold the feed (not below the overload limit)."""
    if not reference_force_n < bridge.overload_force_n:
        raise ConfigError(f'{bridge.teach_file}: tools.{bridge.tool}.reference_force_n = '
                          f'{reference_force_n!r}: not below pmc_bridge.overload_force_n '
                          f'({bridge.overload_force_n:g} N)')


def _with_reference(controller: ControllerSettings, reference_force_n: float,
                    bridge: BridgeSettings) -> ControllerSettings:
    """The controller settings with a taught reference."""
    check_taught_reference(reference_force_n, bridge)
    return controller.replace(reference_force_n=reference_force_n)
