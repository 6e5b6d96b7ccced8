"""Replay: yesterday's recorded currents through today's control chain.

Open loop: the recorded ``servo/currents`` go through the same core code the nodes run (the
estimator, the controller and the PMC gate: :class:`turning_force.core.kernel.chain.ControlChain`),
with the recorded parameters changed by ``--set``; the plant is not re-simulated, so the new
commands do not change the recorded force. Recorded and re-run are compared on the same
footing: the estimated force against the reference, and the override (and the gate's reason)
each block was answered with. Replaying unchanged gives back exactly what was recorded, gate
decisions included: held, disarmed, watchdog. The machine's inputs (program enable,
threading, operator dial) are those each recorded decision saw; a session that started from a
taught reference (teach-in) starts from the reference it recorded, not from today's file.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt

from turning_force.core.errors import NoCutError, TurningForceError
from turning_force.core.experiment import Experiment, parse_set
from turning_force.core.kernel.batch import CurrentArrays, replay_chain
from turning_force.core.overlay import with_parameters_file
from turning_force.core.plant.drive import CurrentBlock
from turning_force.session.bag import BagError
from turning_force.session.reader import Session, estimate_metrics, recorded_reachable

__all__ = ['ReplayResult', 'lay_settings', 'replay']

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class ReplayResult:
    experiment: Experiment
    recorded: dict[str, float]
    rerun: dict[str, float]
    estimated_force_n: FloatArray
    requested_override_pct: FloatArray
    answered_override_pct: FloatArray
    reasons: npt.NDArray[np.int64]
    max_force_difference_n: float
    max_request_difference_pct: float
    differing_overrides: int
    differing_reasons: int

    def comparison(self, blocks: int) -> dict[str, float]:
        """How far the re-run is from the recording (``--json``'s ``comparison``)."""
        return {'max_force_difference_n': self.max_force_difference_n,
                'max_request_difference_pct': self.max_request_difference_pct,
                'differing_overrides': self.differing_overrides,
                'differing_reasons': self.differing_reasons, 'blocks': blocks}


def lay_settings(session: Session, experiment: Experiment | None,
                 params: Sequence[str | Path]) -> None:
    """The settings to replay with: ``experiment`` instead of the recorded ones (if given),
    then the ``--params`` files laid over them in order."""
    if experiment is not None:
        session.experiment = experiment
    if params and session.experiment is None:
        raise TurningForceError(f'{session.path}: no recorded parameters to lay --params '
                                'over; give --experiment')
    for file in params:
        assert session.experiment is not None
        session.experiment = with_parameters_file(session.experiment, file)


def replay(session: Session, sets: Sequence[str] = (),
           progress: Callable[[int, int], None] | None = None) -> ReplayResult:
    """Re-run the control chain (estimator, controller, PMC gate) on the session's currents.

    The gate is armed and disarmed when the recording says the bridge was (unless ``sets``
    change ``armed`` or ``arm_bridge``: then the settings say it); its decisions
    (watchdog, overload hold, invalid commands) are made as the bridge made them, at the end
    of each block.
    """
    if session.experiment is None:
        raise BagError(f'{session.path}: no recorded parameters to replay with')
    experiment = session.experiment.with_sets(sets)
    # The recording says when the bridge was armed; a --set of the arming says otherwise.
    overridden = any(parse_set(text)[1] in ('armed', 'arm_bridge') for text in sets)
    changes = [] if overridden else list(session.arm_changes)
    trace = replay_chain(experiment, _currents(session), changes, session.input_arrays,
                         _recorded_reference(session, experiment, sets), progress=progress)
    force = trace.estimated_force_n
    requested = trace.requested_override_pct
    answered = trace.applied_pct
    reasons = trace.reason.astype(np.int64)
    reachable = trace.reference_reachable
    s = session.signals
    recorded_force, recorded_answer = s['estimated_force_n'], s['answered_override_pct']

    def max_difference(a: FloatArray, b: FloatArray) -> float:
        both = ~(np.isnan(a) | np.isnan(b))
        return float(np.max(np.abs(a[both] - b[both]))) if np.any(both) else math.nan

    recorded = np.isfinite(recorded_answer)   # blocks the recording has an answer for
    return ReplayResult(
        experiment=experiment,
        recorded=_metrics(session, session.experiment, recorded_force, recorded_answer,
                          recorded_reachable(session)),
        rerun=_metrics(session, experiment, force, answered, reachable),
        estimated_force_n=force,
        requested_override_pct=requested,
        answered_override_pct=answered,
        reasons=reasons,
        max_force_difference_n=max_difference(force, recorded_force),
        max_request_difference_pct=max_difference(requested, s['requested_override_pct']),
        differing_overrides=int(np.count_nonzero(
            answered[recorded] != recorded_answer[recorded])),
        differing_reasons=int(np.count_nonzero(
            reasons[recorded] != s['override_reason'][recorded])),
    )


def _currents(session: Session) -> CurrentArrays | list[CurrentBlock]:
    """The session's currents as the reader holds them (arrays), or its blocks where they
    differ in length or sample period (those replay one block at a time)."""
    if session.currents is not None:
        return session.currents
    return list(session.blocks)


def _recorded_reference(session: Session, experiment: Experiment,
                        sets: Sequence[str]) -> float | None:
    """The reference a taught session started from: the first one its commands carried (the
    teach-in file may have changed since). A --set of the reference says otherwise."""
    bridge = experiment.bridge
    if not bridge.teach_file or bridge.teach_in:
        return None
    if any(parse_set(text)[1] == 'reference_force_n' for text in sets):
        return experiment.controller.reference_force_n
    recorded = session.signals['reference_n']
    first = recorded[np.isfinite(recorded)]
    return float(first[0]) if first.size else experiment.controller.reference_force_n


def _metrics(session: Session, experiment: Experiment, force_n: FloatArray,
             answered_pct: FloatArray, reachable: npt.NDArray[np.bool_]) -> dict[str, float]:
    """The metrics on the estimated force; none for a session without a cut (an air cut)."""
    try:
        return estimate_metrics(session, experiment, force_n, answered_pct, None, reachable)
    except NoCutError:
        return {}
