"""Closed-loop what-if replay (``replay SESSION --closed-loop``): a new setting tried on
yesterday's cut with the force it would have caused, not only the overrides it would have asked
for.

Open-loop replay feeds the recorded currents to a new controller: its overrides are computed,
but the force they would have caused is not. Here the machine is identified
(:mod:`turning_force.core.identify`, from the session itself or from a commissioning session
given with ``--identified-from``), and the session's experiment, with its job, runs in closed
loop on the identified plant (:func:`turning_force.core.verification.plant_sets`, the plant the
commissioning's verification runs on) twice: as recorded, and with the candidate settings. The
first is the model's fit: how far its replay of what happened is from what the session recorded,
so the user knows how far to trust the second.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from turning_force.core.errors import NoCutError, TurningForceError
from turning_force.core.identify import IdentifySettings
from turning_force.core.kernel.simulate import simulate
from turning_force.core.metrics import METRIC_NAMES
from turning_force.core.verification import plant_sets
from turning_force.session.identify import cut_depth_mm, identify_sessions
from turning_force.session.reader import read_session, recorded_metrics

__all__ = ['WhatIf', 'what_if']

# The figures compared: recorded, the model's replay of the recorded settings, the candidate.
COMPARED = ('steady_mean_abs_error_n', 'mean_abs_error_n', 'ripple_p2p_n', 'entry_overshoot_n')


@dataclass(frozen=True)
class WhatIf:
    """A candidate's predicted metrics beside the recorded ones, and the model's fit."""

    session: str
    sets: tuple[str, ...]
    recorded: dict[str, float]        # what the session recorded
    replayed: dict[str, float]        # the recorded settings on the identified plant
    predicted: dict[str, float]       # the candidate on the identified plant
    plant: tuple[str, ...]            # the identified plant, as lathe_sim assignments

    def fit_n(self, name: str = 'steady_mean_abs_error_n') -> float:
        """How far the model's replay of the recorded settings is from the recording."""
        return abs(self.replayed.get(name, 0.0) - self.recorded.get(name, 0.0))

    def to_json(self) -> dict[str, object]:
        return {'session': self.session, 'sets': list(self.sets), 'recorded': self.recorded,
                'replayed': self.replayed, 'predicted': self.predicted,
                'plant': list(self.plant)}

    def lines(self) -> list[str]:
        head = f'  {"metric":26s} {"recorded":>10s} {"model":>10s} {"candidate":>10s}'
        rows = [f'  {name:26s} {self.recorded.get(name, float("nan")):10.3f} '
                f'{self.replayed.get(name, float("nan")):10.3f} '
                f'{self.predicted.get(name, float("nan")):10.3f}'
                for name in METRIC_NAMES if name in COMPARED]
        fit = (f'  the model replays the recorded settings within {self.fit_n():.2f} N of the '
               "recorded steady error: trust the candidate's figures about as far")
        return [head, *rows, fit]


def what_if(bag: str | Path, sets: Sequence[str],
            identified_from: Sequence[str | Path] = ()) -> WhatIf:
    """``sets`` tried on the session ``bag`` in closed loop (the module's text)."""
    session = read_session(bag)
    if session.experiment is None:
        raise TurningForceError(f'{bag}: no recorded settings: nothing to replay in closed loop')
    experiment = session.experiment
    # From the session itself: closed loop, on the controller's own override steps, with the
    # friction the session's estimator ran with (a production cut has no air move).
    ident, sessions = identify_sessions(list(identified_from) or [bag], IdentifySettings(),
                                        None if identified_from else ())
    depth = cut_depth_mm(sessions) or max(experiment.plant.depth_profile.depth_mm)
    plant = tuple(plant_sets(ident, depth, experiment.plant.current_per_force_a_n))
    try:
        recorded = recorded_metrics(session)
        replayed = simulate(experiment.with_sets(list(plant))).metrics
        predicted = simulate(experiment.with_sets([*plant, *sets])).metrics
    except NoCutError as exc:
        raise TurningForceError(f'{bag}: {exc}') from exc
    return WhatIf(str(bag), tuple(sets), recorded, replayed, predicted, plant)
