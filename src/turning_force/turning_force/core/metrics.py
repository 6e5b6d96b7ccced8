"""Regulation metrics, named as DESIGN.md names them (the JSON keys of ``--json``).

All are computed from series sampled at the control period, with the tool in the workpiece
(air excluded). "Changes" are every entry into the cut, every change of depth of cut and every
change of reference force.
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from turning_force.core.errors import NoCutError

__all__ = ['METRIC_NAMES', 'OPTIONAL_METRICS', 'MetricSettings', 'compute_metrics']

FloatArray = npt.NDArray[np.float64]

METRIC_NAMES = ('mean_abs_error_n', 'steady_mean_abs_error_n', 'max_abs_error_n', 'overshoot_n',
                'entry_overshoot_n', 'settling_time_s', 'ripple_p2p_n', 'override_changes_per_s',
                'reachable_fraction')
# Where a run has them: the estimator's error against a recorded truth, the loop's alarms.
OPTIONAL_METRICS = ('estimate_error_rms_n', 'oscillation_alarms', 'drift_alarms',
                    'drift_alarm_s')


@dataclass(frozen=True)
class MetricSettings:
    """``settle_window_s``: time left out after each change in the steady figures;
    ``allowed_error_n``: the band for settling time; ``ripple_window_s``: the span the ripple is
    measured over before each depth change and at the end."""

    settle_window_s: float = 1.0
    allowed_error_n: float = 10.0
    ripple_window_s: float = 1.0


def compute_metrics(
    t_s: FloatArray,
    force_n: FloatArray,
    reference_n: FloatArray,
    depth_mm: FloatArray,
    applied_override_pct: FloatArray,
    depth_change_times_s: Sequence[float],
    settings: MetricSettings,
    reachable: npt.NDArray[np.bool_] | None = None,
    estimate_n: FloatArray | None = None,
    oscillation_alarm: FloatArray | None = None,
    drift_alarm: FloatArray | None = None,
) -> dict[str, float]:
    """The DESIGN.md metrics of one run, taken with the tool in the cut (``depth_mm > 0``): the
    time in air between two cuts is no regulation error.

    - ``mean_abs_error_n``: mean |F - F_ref| in the cut, transients included.
    - ``steady_mean_abs_error_n``: the same, leaving out ``settle_window_s`` after each change
      (an entry into the cut, a change of depth or of reference); what the papers call the
      average tracking error.
    - ``max_abs_error_n``: largest |F - F_ref| once the first entry's transient is over (the
      first settle window), so that it measures the depth steps, not the tool entering the cut.
    - ``overshoot_n``: largest excursion above F_ref after an entry or a depth change.
    - ``entry_overshoot_n``: the same after the entries only (each until the next change): what
      a wound-up feed does to a tool entering the work.
    - ``settling_time_s``: worst time after a depth change until |F - F_ref| stays within
      ``allowed_error_n``; the whole span to the next change if it never does.
    - ``ripple_p2p_n``: largest peak-to-peak force in the ``ripple_window_s`` before each depth
      change (an exit among them) and before the end, settle windows left out (a transient is
      not ripple).
    - ``override_changes_per_s``: changes of the applied override per second in the cut.
    - ``reachable_fraction``: the share of the cut in which the controller could reach the
      reference (``reachable``: false where its request sat at the table's end, pushing the
      wrong way; see :class:`turning_force.core.control.ControlOutput`). The steady figures
      leave out the part where it could not: an error no feed can remove is not a regulation
      error, and this figure says how much was left out.
    - ``estimate_error_rms_n`` (where ``estimate_n``, the estimated force, is given beside a
      true ``force_n``): the estimator's RMS error in the cut.
    - ``oscillation_alarms`` (where ``oscillation_alarm``, 1 while the controller's alarm
      holds, is given): how often it was raised.
    - ``drift_alarms``, ``drift_alarm_s`` (where ``drift_alarm``, the drift monitor's cause
      while its alarm holds, 0 none, is given): how often it named a cause, and (where it did)
      the time from the first entry into the cut to the first.
    """
    in_cut = depth_mm > 0
    if not np.any(in_cut):
        raise NoCutError('the tool never engages (an air cut): no force metrics')
    entries = t_s[in_cut & ~np.concatenate(([False], in_cut[:-1]))]
    start, end = float(entries[0]), float(t_s[-1])
    t, force, ref = t_s[in_cut], force_n[in_cut], reference_n[in_cut]
    can_reach = np.ones(t.size, dtype=bool) if reachable is None else reachable[in_cut]
    error = force - ref
    abs_error = np.abs(error)

    ref_changes = t[1:][np.diff(ref) != 0].tolist()
    depth_changes = sorted(c for c in depth_change_times_s if start < c <= end)
    changes = sorted({*entries.tolist(), *depth_changes, *ref_changes})
    settling = np.zeros(t.size, dtype=bool)
    for c in changes:
        settling |= (t >= c) & (t < c + settings.settle_window_s)
    steady = ~settling & can_reach
    after_engagement = t >= start + settings.settle_window_s

    overshoot, entry_overshoot, settling_time = 0.0, 0.0, 0.0
    entered = set(entries.tolist())
    bounds = sorted({*entries.tolist(), *depth_changes})
    for c0, c1 in itertools.pairwise([*bounds, end + 1e-9]):
        span = (t >= c0) & (t < c1)
        if not np.any(span):
            continue
        peak = float(np.max(error[span]))
        overshoot = max(overshoot, peak)
        if c0 in entered:
            entry_overshoot = max(entry_overshoot, peak)
            continue  # settling is measured after depth changes
        outside = t[span][abs_error[span] > settings.allowed_error_n]
        if outside.size:
            last = float(outside[-1])
            finished = last < float(t[span][-1])
            settling_time = max(settling_time, (last + (t[1] - t[0]) if finished else c1) - c0)

    ripple = 0.0
    for c in [*depth_changes, end + 1e-9]:
        window = (t >= c - settings.ripple_window_s) & (t < c) & steady
        if np.count_nonzero(window) > 1:
            ripple = max(ripple, float(np.ptp(force[window])))

    period = float(np.median(np.diff(t_s))) if t_s.size > 1 else 0.0
    duration = t.size * period
    applied = applied_override_pct[in_cut]
    changes_count = int(np.count_nonzero(np.diff(applied)[np.diff(t) <= 1.5 * period]))
    metrics = {
        'mean_abs_error_n': float(np.mean(abs_error)),
        'steady_mean_abs_error_n': float(np.mean(abs_error[steady])) if np.any(steady) else 0.0,
        'max_abs_error_n': float(np.max(abs_error[after_engagement]))
        if np.any(after_engagement) else float(np.max(abs_error)),
        'overshoot_n': max(overshoot, 0.0),
        'entry_overshoot_n': max(entry_overshoot, 0.0),
        'settling_time_s': float(min(settling_time, end - start)),
        'ripple_p2p_n': ripple,
        'override_changes_per_s': changes_count / duration if duration > 0 else 0.0,
        'reachable_fraction': float(np.mean(can_reach)),
    }
    if estimate_n is not None:
        miss = estimate_n[in_cut] - force
        known = np.isfinite(miss)
        if np.any(known):
            metrics['estimate_error_rms_n'] = float(np.sqrt(np.mean(miss[known] ** 2)))
    if oscillation_alarm is not None:
        raised = np.diff(oscillation_alarm > 0.0, prepend=False)
        metrics['oscillation_alarms'] = float(np.count_nonzero(raised & (oscillation_alarm > 0)))
    if drift_alarm is not None:
        named = np.diff(drift_alarm, prepend=0.0) != 0.0
        metrics['drift_alarms'] = float(np.count_nonzero(named & (drift_alarm > 0)))
        if np.any(drift_alarm > 0):
            metrics['drift_alarm_s'] = float(t_s[np.argmax(drift_alarm > 0)]) - start
    return metrics
