"""Replay: yesterday's recorded currents through today's estimator, controller and quantiser.

Open loop: the recorded ``servo/currents`` go through the same core code the nodes run, with the
recorded parameters changed by ``--set``; the plant is not re-simulated, so the new commands do
not change the recorded force. Recorded and re-run are compared on the same footing: the
estimated force against the reference, and the quantised override each answers a block with.
Replaying unchanged gives back exactly what was recorded.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from turning_force.core.control import make_controller
from turning_force.core.estimation import ForceEstimator
from turning_force.core.experiment import Experiment
from turning_force.core.overrides import get_table
from turning_force.session.bag import BagError
from turning_force.session.reader import Session, estimate_metrics

__all__ = ['ReplayResult', 'replay']

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class ReplayResult:
    experiment: Experiment
    recorded: dict[str, float]
    rerun: dict[str, float]
    estimated_force_n: FloatArray
    requested_override_pct: FloatArray
    answered_override_pct: FloatArray
    max_force_difference_n: float
    max_request_difference_pct: float
    differing_overrides: int


def replay(session: Session, sets: Sequence[str] = (),
           progress: Callable[[int, int], None] | None = None) -> ReplayResult:
    """Re-run estimator, controller and quantiser on the session's recorded currents."""
    if session.experiment is None:
        raise BagError(f'{session.path}: no recorded parameters to replay with')
    experiment = session.experiment.with_sets(sets)
    estimator = ForceEstimator(experiment.estimator)
    controller = make_controller(experiment.controller)
    table = get_table(experiment.bridge.override_table)
    n = len(session.blocks)
    force = np.full(n, np.nan)
    requested = np.full(n, np.nan)
    answered = np.full(n, np.nan)
    for k, block in enumerate(session.blocks):
        estimate = estimator.update(block)
        force[k] = estimate.force_n
        if estimate.status.actionable:
            out = controller.update(estimate.force_n, estimate.force_rate_n_s)
            requested[k] = out.override_pct
            answered[k] = table.quantise(out.override_pct)
        if progress is not None:
            progress(k + 1, n)
    s = session.signals
    recorded_force, recorded_answer = s['estimated_force_n'], s['answered_override_pct']

    def max_difference(a: FloatArray, b: FloatArray) -> float:
        both = ~(np.isnan(a) | np.isnan(b))
        return float(np.max(np.abs(a[both] - b[both]))) if np.any(both) else math.nan

    return ReplayResult(
        experiment=experiment,
        recorded=estimate_metrics(session, session.experiment, recorded_force, recorded_answer),
        rerun=estimate_metrics(session, experiment, force, answered),
        estimated_force_n=force,
        requested_override_pct=requested,
        answered_override_pct=answered,
        max_force_difference_n=max_difference(force, recorded_force),
        max_request_difference_pct=max_difference(requested, s['requested_override_pct']),
        differing_overrides=int(np.count_nonzero(
            ~np.isclose(answered, recorded_answer, equal_nan=True))),
    )
