"""The paper-style figure of a session: force against reference with its allowed band, depth of
cut, feed and override over time, and the metrics beside them (Park 1998, Figs. 7-8 style); and
the cut log (HEIDENHAIN AFC's): per cut, its time, the time a fixed programmed feed would have
taken, max force, lowest override, overload events and the share of it the reference could be
reached in. The cuts are those the bridge recorded (``pmc/cuts``); a cut still open when the
recording ended is shown from the recorded signals, marked open."""

from __future__ import annotations

import base64
import datetime
import html
import io
import math
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use('Agg')  # files only; no display is needed or wanted

import matplotlib.pyplot as plt
import numpy as np
import numpy.typing as npt
from matplotlib.figure import Figure
from matplotlib.transforms import Bbox

from turning_force.core.metrics import METRIC_NAMES, OPTIONAL_METRICS
from turning_force.core.pmc.shopfloor import CutRecord
from turning_force.session.bag import CUSTOM_STARTED
from turning_force.session.reader import Session

FloatArray = npt.NDArray[np.float64]

__all__ = ['CUT_COLUMNS', 'ReportFacts', 'cut_table', 'figure', 'figure_png', 'report_facts',
           'write_html_report', 'write_report']

# The cut log's columns: heading, unit, and the text of a record's value.
CUT_COLUMNS: tuple[tuple[str, str, str], ...] = (
    ('cut', '', 'index'),
    ('start', 's', 'start_s'),
    ('time', 's', 'duration_s'),
    ('at 100 %', 's', 'programmed_feed_s'),
    ('max force', 'N', 'max_force_n'),
    ('lowest override', '%', 'min_override_pct'),
    ('overloads', '', 'overload_events'),
    ('reachable', '', 'reachable_fraction'),
    ('mean force', 'N', 'mean_force_n'),
    ('tool', '', 'tool'),
)

# Stamps after this are the wall clock (2001 on), not a simulation's time from 0 [s].
WALL_CLOCK_AFTER_S = 1e9


@dataclass(frozen=True)
class ReportFacts:
    """What a report says of its session besides the signals: what ran, where, when, and the
    band it was held to.

    ``start_s`` is the session's time 0 in its stamps' clock (the first block's first sample):
    a report's times are seconds from it, a wall-clock session's too. ``band_n`` is the allowed
    error the session's own settings give (``experiment.allowed_error_n``), ``band_from`` says
    where it came from."""

    experiment: str
    machine: str
    started: datetime.datetime | None
    start_s: float
    band_n: float
    band_from: str
    parameters: dict[str, dict[str, Any]]
    versions: dict[str, str]

    @property
    def date_text(self) -> str:
        return (self.started.strftime('%Y-%m-%d %H:%M UTC') if self.started is not None
                else 'date not recorded')

    @property
    def title(self) -> str:
        return f'{self.experiment} on {self.machine}, {self.date_text}'


def report_facts(session: Session) -> ReportFacts:
    """The facts of ``session`` a report prints (:class:`ReportFacts`)."""
    experiment = session.experiment
    starts = session.block_starts_s
    start_s = float(starts[0]) if starts.size else 0.0
    started: datetime.datetime | None = None
    if CUSTOM_STARTED in session.custom_data:
        started = datetime.datetime.fromisoformat(session.custom_data[CUSTOM_STARTED])
    elif start_s > WALL_CLOCK_AFTER_S:
        started = datetime.datetime.fromtimestamp(start_s, datetime.UTC)
    lathe = 'simulated lathe' if session.has_truth else 'lathe'
    if experiment is None:
        return ReportFacts(session.path.name, lathe, started, start_s, 0.0, 'no settings '
                           'recorded: no band', {}, session.versions)
    bridge = experiment.bridge
    machine = (f'{Path(bridge.machine_file).stem} ({lathe}, {bridge.override_table})'
               if bridge.machine_file else f'{lathe}, {bridge.override_table} override')
    given = 'allowed_error_n' in experiment.sections.get('experiment', {})
    return ReportFacts(experiment.run.name, machine, started, start_s,
                       experiment.run.allowed_error_n,
                       'experiment.allowed_error_n' if given else
                       'the default experiment.allowed_error_n: the session does not set it',
                       experiment.resolved_params(), session.versions)


def cut_table(session: Session) -> list[CutRecord]:
    """The session's cuts: those recorded, and the one still open at the end of the recording
    (from the blocks the bridge answered as engaged), marked incomplete."""
    cuts = list(session.cuts)
    s = session.signals
    engaged = s['engaged'] == 1.0
    if not engaged.size or not engaged[-1]:
        return cuts
    first = int(np.flatnonzero(~engaged)[-1] + 1) if np.any(~engaged) else 0
    if session.experiment is not None and first > 0:   # the detector's debounce: the cut began
        bridge = session.experiment.bridge                # that many blocks before it said so
        debounce = bridge.debounce_blocks(bridge.control_period_s)
        first = max(first - (debounce - 1), 0)
    if cuts and cuts[-1].end_s >= session.t_s[first]:
        return cuts    # the bridge closed it (deactivated before the recording ended)
    period = float(session.t_s[1] - session.t_s[0]) if session.t_s.size > 1 else 0.0
    force = s['estimated_force_n'][first:]
    # The override a block ran at is the answer to the block before.
    applied = s['answered_override_pct'][max(first - 1, 0):-1]
    reachable = s['reference_reachable'][first:]
    commanded = reachable[np.isfinite(reachable)]
    cuts.append(CutRecord(
        index=len(cuts) + 1, tool=session.experiment.bridge.tool if session.experiment else '',
        start_s=float(session.t_s[first]) - period, end_s=float(session.t_s[-1]),
        programmed_feed_s=float(np.nansum(applied) / 100.0 * period),
        max_force_n=float(np.nanmax(force)), mean_force_n=float(np.nanmean(force)),
        min_override_pct=float(np.nanmin(applied)) if applied.size else math.nan,
        overload_events=0, breakage=False,
        reachable_fraction=float(np.mean(commanded != 0.0)) if commanded.size else math.nan,
        complete=False))
    return cuts


def _cut_cells(record: CutRecord, start_s: float) -> list[str]:
    """A cut's row as text, its start in seconds from the session's ``start_s``."""
    cells = []
    for _, unit, name in CUT_COLUMNS:
        value = getattr(record, name)
        if name == 'start_s':
            value -= start_s
        if name == 'index':
            cells.append(f'{value}' + ('' if record.complete else ' (open)')
                         + (' learned' if record.learned else '')
                         + (' BREAKAGE' if record.breakage else ''))
        elif name == 'reachable_fraction':
            cells.append('-' if math.isnan(value) else f'{value:.0%}')
        elif isinstance(value, int | str):
            cells.append(f'{value}')
        else:
            cells.append(f'{value:.{0 if unit in ("N", "%") else 2}f}')
    return cells

METRIC_LABELS = {
    'mean_abs_error_n': ('mean |error|', 'N'),
    'steady_mean_abs_error_n': ('steady |error|', 'N'),
    'max_abs_error_n': ('max |error|', 'N'),
    'overshoot_n': ('overshoot', 'N'),
    'entry_overshoot_n': ('overshoot at entries', 'N'),
    'settling_time_s': ('settling time', 's'),
    'ripple_p2p_n': ('ripple p-p', 'N'),
    'override_changes_per_s': ('override changes', '1/s'),
    'reachable_fraction': ('reference reachable', 'of the cut'),
    'estimate_error_rms_n': ('estimate error rms', 'N'),
    'oscillation_alarms': ('oscillation alarms', ''),
    'drift_alarms': ('drift alarms', ''),
    'drift_alarm_s': ('first drift alarm', 's in the cut'),
    'realtime_factor': ('realtime factor', 'x'),
}


# Columns of the time axis a signal is drawn in: about the plot's width in pixels (12 in at
# 120 dpi, four fifths of it), twice over. A longer signal is drawn as its envelope.
COLUMNS = 2000


def _spans(mask: npt.NDArray[np.bool_], join: int = 0) -> list[tuple[int, int]]:
    """(first, last) indices of each run of True in ``mask``; runs fewer than ``join`` apart
    drawn as one (they would be one on the figure)."""
    edges = np.flatnonzero(np.diff(np.concatenate([[0], mask.astype(np.int8), [0]])))
    spans = [(int(a), int(b) - 1) for a, b in zip(edges[::2], edges[1::2], strict=True)]
    joined: list[tuple[int, int]] = []
    for first, last in spans:
        if joined and first - joined[-1][1] <= join:
            joined[-1] = (joined[-1][0], last)
        else:
            joined.append((first, last))
    return joined


def _bins(n: int, columns: int = COLUMNS) -> int:
    """Samples per column for ``n`` samples (1: drawn as they are)."""
    return 1 if n <= 2 * columns else -(-n // columns)


def _by_column(y: FloatArray, step: int) -> FloatArray:
    """``y`` as rows of ``step`` samples, one per column, the last padded with NaN."""
    padded = np.full(-(-y.size // step) * step, np.nan)
    padded[:y.size] = y
    return padded.reshape(-1, step)


def _envelope(t: FloatArray, y: FloatArray, columns: int = COLUMNS
              ) -> tuple[FloatArray, FloatArray]:
    """``y`` over ``t`` as at most two points per column: the smallest and the largest of the
    samples in it, in the order they came, so that a line through them spans every spike the
    column holds (what a line through all of them would paint). NaN where a column has no
    number."""
    step = _bins(t.size, columns)
    if step == 1:
        return t, y
    rows = _by_column(y, step)
    count = rows.shape[0]
    finite = np.isfinite(rows)
    low = np.where(finite, rows, np.inf).argmin(axis=1)
    high = np.where(finite, rows, -np.inf).argmax(axis=1)
    first, second = np.minimum(low, high), np.maximum(low, high)
    index = np.arange(count) * step
    at = np.stack([index + first, index + second], axis=1).reshape(-1)
    at = np.minimum(at, t.size - 1)
    values = np.where(np.repeat(finite.any(axis=1), 2), y[at], np.nan)
    return t[at], values


def _band(t: FloatArray, y: FloatArray, columns: int = COLUMNS
          ) -> tuple[FloatArray, FloatArray, FloatArray]:
    """The start of each column, and the smallest and largest of ``y`` in it."""
    step = _bins(t.size, columns)
    if step == 1:
        return t, y, y
    rows = _by_column(y, step)
    with warnings.catch_warnings():
        warnings.simplefilter('ignore', RuntimeWarning)   # an all-NaN column: NaN
        return t[::step], np.nanmin(rows, axis=1), np.nanmax(rows, axis=1)


def write_report(session: Session, metrics: dict[str, float], out: Path) -> Path:
    """Draw the session to ``out`` (PNG) and return the path."""
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_bytes(figure_png(session, metrics))
    return out


def figure_png(session: Session, metrics: dict[str, float]) -> bytes:
    """The figure of a session as PNG bytes; the PNG's Title, Description and Creation Time
    say what ran, where and when (:class:`ReportFacts`)."""
    facts = report_facts(session)
    fig = figure(session, metrics, facts)
    buffer = io.BytesIO()
    metadata = {'Title': facts.title, 'Software': _software(facts.versions),
                'Description': f'session {session.path}; band +/-{facts.band_n:g} N from '
                               f'{facts.band_from}; time from the session start'}
    if facts.started is not None:
        metadata['Creation Time'] = facts.started.isoformat()
    fig.savefig(buffer, format='png', dpi=120, metadata=metadata)
    plt.close(fig)
    return buffer.getvalue()


def _software(versions: dict[str, str]) -> str:
    return ', '.join(f'{name} {version}' for name, version in versions.items())


def figure(session: Session, metrics: dict[str, float], facts: ReportFacts | None = None
           ) -> Figure:
    """The figure of a session: force against reference with the session's band, depth, feed
    and override over time in seconds from the session's start, the metrics and the cut log.
    The caller closes it (``plt.close``)."""
    facts = facts or report_facts(session)
    s, t = session.signals, session.t_s - facts.start_s
    experiment = session.experiment
    reference = s['reference_n']
    if experiment is not None:
        reference = np.where(np.isnan(reference), experiment.controller.reference_force_n,
                             reference)
    band = facts.band_n

    fig = plt.figure(figsize=(12, 8.5), layout='constrained')
    grid = fig.add_gridspec(4, 2, width_ratios=(4, 1), height_ratios=(2.2, 1, 1, 1.4))
    ax_force = fig.add_subplot(grid[0, 0])
    ax_depth = fig.add_subplot(grid[1, 0], sharex=ax_force)
    ax_feed = fig.add_subplot(grid[2, 0], sharex=ax_force)
    ax_override = fig.add_subplot(grid[3, 0], sharex=ax_force)
    ax_table = fig.add_subplot(grid[:, 1])

    if band > 0:
        t_band, low, high = _band(t, reference)
        ax_force.fill_between(t_band, low - band, high + band, color='tab:green',
                              alpha=0.15, step='post', label=f'allowed ±{band:g} N')
    ax_force.step(*_envelope(t, reference), where='post', color='tab:green', lw=1.2,
                  label='reference')
    if session.has_truth:
        ax_force.plot(*_envelope(t, s['force_n']), color='tab:blue', lw=1.2,
                      label='cutting force (true)')
    ax_force.plot(*_envelope(t, s['estimated_force_n']), color='tab:orange', lw=0.8, alpha=0.8,
                  label='estimated from currents')
    out_of_reach = s['reference_reachable'] == 0.0   # NaN (no flag recorded): reachable
    for k, (first, last) in enumerate(_spans(out_of_reach, _bins(t.size) - 1)):
        ax_force.axvspan(t[first], t[last], color='tab:red', alpha=0.12, lw=0,
                         label='reference out of reach' if k == 0 else None)
    ax_force.set_ylabel('force [N]')
    ax_force.legend(loc='lower right', fontsize=8)

    if session.has_truth:
        ax_depth.plot(*_envelope(t, s['depth_mm']), color='tab:brown')
        ax_feed.plot(*_envelope(t, s['feed_mm_rev']), color='tab:purple')
    ax_depth.set_ylabel('depth of cut [mm]')
    ax_feed.set_ylabel('feed [mm/rev]')

    ax_override.plot(*_envelope(t, s['requested_override_pct']), color='tab:gray', lw=0.7,
                     label='requested (continuous)')
    applied = s['applied_override_pct'] if session.has_truth else s['answered_override_pct']
    ax_override.step(*_envelope(t, applied), where='post', color='tab:red', lw=1.2,
                     label='applied (PMC)')
    ax_override.set_ylabel('override [%]')
    ax_override.set_xlabel('time from the session start [s]')
    ax_override.legend(loc='upper right', fontsize=8)
    for ax in (ax_force, ax_depth, ax_feed, ax_override):
        ax.grid(alpha=0.3)

    title = facts.title
    if experiment is not None and experiment.run.paper_figure:
        title += f' (reproduces {experiment.run.paper_figure})'
    if experiment is not None:
        c = experiment.controller
        title += (f'\ncontroller {c.controller}, F_ref {c.reference_force_n:g} N, allowed '
                  f'±{band:g} N')
    fig.suptitle(title, fontsize=11)

    ax_table.axis('off')
    rows = [[METRIC_LABELS[k][0], f'{metrics[k]:.2f} {METRIC_LABELS[k][1]}']
            for k in (*METRIC_NAMES, *OPTIONAL_METRICS, 'realtime_factor') if k in metrics]
    if experiment is not None and experiment.run.paper_steady_mean_abs_error_n:
        rows.append(['paper', f'{experiment.run.paper_steady_mean_abs_error_n:g} N'])
    if rows:   # an air cut has no metrics
        table = ax_table.table(cellText=rows, colLabels=['metric', 'value'],
                               loc='upper center', cellLoc='left', colWidths=[0.6, 0.4])
        table.auto_set_font_size(False)
        table.set_fontsize(8)
        table.scale(1.0, 1.4)
    cuts = cut_table(session)
    if cuts:
        shown = cuts[:12]   # the HTML report lists them all
        height = 0.03 * (len(shown) + 1)
        log = ax_table.table(
            cellText=[[cell for k, cell in enumerate(_cut_cells(r, facts.start_s))
                       if k in (0, 2, 3, 4, 5, 6)]
                      for r in shown],
            colLabels=['cut', 't', 't100', 'Fmax', 'min %', 'ovl'],
            cellLoc='left', bbox=Bbox.from_bounds(0.0, 0.0, 1.0, height),
            colWidths=[0.2, 0.15, 0.17, 0.16, 0.16, 0.16])
        log.auto_set_font_size(False)
        log.set_fontsize(6)
        ax_table.text(0.0, height + 0.01, 'cut log: time t [s], t100 at a fixed 100 % [s], Fmax '
                      '[N], lowest override [%], overload events', fontsize=7,
                      transform=ax_table.transAxes, wrap=True)

    return fig


def write_html_report(session: Session, metrics: dict[str, float], out: Path) -> Path:
    """One self-contained HTML page to hand on: what ran, on which machine, when, with which
    software; the figure (embedded PNG), the metrics, the cut log and every parameter."""
    facts = report_facts(session)
    image = base64.b64encode(figure_png(session, metrics)).decode('ascii')
    e = html.escape
    rows = ''.join(
        f'<tr><td>{e(METRIC_LABELS[k][0])}</td><td>{e(k)}</td>'
        f'<td style="text-align:right">{metrics[k]:.3f} {e(METRIC_LABELS[k][1])}</td>'
        '</tr>' for k in (*METRIC_NAMES, *OPTIONAL_METRICS, 'realtime_factor') if k in metrics)
    cuts = cut_table(session)
    cut_rows = ''.join('<tr>' + ''.join(f'<td style="text-align:right">{e(c)}</td>'
                                        for c in _cut_cells(r, facts.start_s)) + '</tr>'
                       for r in cuts)
    cut_head = ''.join(f'<th>{e(h)}{f" [{u}]" if u else ""}</th>' for h, u, _ in CUT_COLUMNS)
    cut_log = (f'<h2>Cut log</h2><p>start: seconds from the session start</p><table border="1" '
               f'cellpadding="4" class="cuts"><tr>{cut_head}</tr>{cut_rows}</table>'
               if cuts else '')
    about = ''.join(f'<tr><th style="text-align:left">{e(k)}</th><td>{e(v)}</td></tr>'
                    for k, v in (
        ('experiment', facts.experiment), ('machine', facts.machine),
        ('recorded', facts.date_text), ('session', str(session.path)),
        ('allowed band', f'±{facts.band_n:g} N ({facts.band_from})'),
        ('software', _software(facts.versions) or 'not recorded')))
    settings = ''.join(
        f'<h3>{e(section)}</h3><table border="1" cellpadding="3" class="parameters">'
        + ''.join(f'<tr><td>{e(name)}</td><td>{e(str(value))}</td></tr>'
                  for name, value in values.items()) + '</table>'
        for section, values in facts.parameters.items())
    out.write_text(
        f'<!DOCTYPE html>\n<html><head><meta charset="utf-8"><title>{e(facts.title)}</title>'
        f'</head><body style="font-family:sans-serif"><h1>{e(facts.title)}</h1>'
        f'<table class="about" cellpadding="3">{about}</table>'
        f'<img alt="force, depth, feed and override over time" '
        f'src="data:image/png;base64,{image}" style="max-width:100%">'
        f'<h2>Metrics</h2><table border="1" cellpadding="4"><tr><th>metric</th><th>key</th>'
        f'<th>value</th></tr>{rows}</table>{cut_log}'
        f'<h2>Parameters</h2>{settings or "<p>none recorded</p>"}</body></html>\n')
    return out
