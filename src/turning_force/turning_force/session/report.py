"""The paper-style figure of a session: force against reference with its allowed band, depth of
cut, feed and override over time, and the metrics beside them (Park 1998, Figs. 7-8 style); and
the cut log (HEIDENHAIN AFC's): per cut, its time, the time a fixed programmed feed would have
taken, max force, lowest override, overload events and the share of it the reference could be
reached in. The cuts are those the bridge recorded (``pmc/cuts``); a cut still open when the
recording ended is shown from the recorded signals, marked open."""

from __future__ import annotations

import base64
import html
import io
import math
import warnings
from pathlib import Path

import matplotlib

matplotlib.use('Agg')  # files only; no display is needed or wanted

import matplotlib.pyplot as plt
import numpy as np
import numpy.typing as npt
from matplotlib.transforms import Bbox

from turning_force.core.metrics import METRIC_NAMES, OPTIONAL_METRICS
from turning_force.core.pmc.shopfloor import CutRecord
from turning_force.session.reader import Session

FloatArray = npt.NDArray[np.float64]

__all__ = ['CUT_COLUMNS', 'cut_table', 'figure_png', 'write_html_report', 'write_report']

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
)


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


def _cut_cells(record: CutRecord) -> list[str]:
    cells = []
    for _, unit, name in CUT_COLUMNS:
        value = getattr(record, name)
        if name == 'index':
            cells.append(f'{value}' + ('' if record.complete else ' (open)')
                         + (' learned' if record.learned else '')
                         + (' BREAKAGE' if record.breakage else ''))
        elif name == 'reachable_fraction':
            cells.append('-' if math.isnan(value) else f'{value:.0%}')
        elif isinstance(value, int):
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
    """The figure of a session as PNG bytes."""
    s, t = session.signals, session.t_s
    experiment = session.experiment
    reference = s['reference_n']
    if experiment is not None:
        reference = np.where(np.isnan(reference), experiment.controller.reference_force_n,
                             reference)
    band = experiment.run.allowed_error_n if experiment is not None else 0.0

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
    ax_force.grid(alpha=0.3)

    if session.has_truth:
        ax_depth.plot(*_envelope(t, s['depth_mm']), color='tab:brown')
        ax_feed.plot(*_envelope(t, s['feed_mm_rev']), color='tab:purple')
    ax_depth.set_ylabel('depth of cut [mm]')
    ax_feed.set_ylabel('feed [mm/rev]')
    for ax in (ax_depth, ax_feed):
        ax.grid(alpha=0.3)

    ax_override.plot(*_envelope(t, s['requested_override_pct']), color='tab:gray', lw=0.7,
                     label='requested (continuous)')
    applied = s['applied_override_pct'] if session.has_truth else s['answered_override_pct']
    ax_override.step(*_envelope(t, applied), where='post', color='tab:red', lw=1.2,
                     label='applied (PMC)')
    ax_override.set_ylabel('override [%]')
    ax_override.set_xlabel('time [s]')
    ax_override.legend(loc='upper right', fontsize=8)
    ax_override.grid(alpha=0.3)

    title = experiment.run.name if experiment is not None else session.path.name
    if experiment is not None and experiment.run.paper_figure:
        title += f' (reproduces {experiment.run.paper_figure})'
    if experiment is not None:
        c = experiment.controller
        title += (f'\ncontroller {c.controller}, table {c.override_table}, '
                  f'F_ref {c.reference_force_n:g} N')
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
            cellText=[[cell for k, cell in enumerate(_cut_cells(r)) if k in (0, 2, 3, 4, 5, 6)]
                      for r in shown],
            colLabels=['cut', 't', 't100', 'Fmax', 'min %', 'ovl'],
            cellLoc='left', bbox=Bbox.from_bounds(0.0, 0.0, 1.0, height),
            colWidths=[0.2, 0.15, 0.17, 0.16, 0.16, 0.16])
        log.auto_set_font_size(False)
        log.set_fontsize(6)
        ax_table.text(0.0, height + 0.01, 'cut log: time t [s], t100 at a fixed 100 % [s], Fmax '
                      '[N], lowest override [%], overload events', fontsize=7,
                      transform=ax_table.transAxes, wrap=True)

    buffer = io.BytesIO()
    fig.savefig(buffer, format='png', dpi=120)
    plt.close(fig)
    return buffer.getvalue()


def write_html_report(session: Session, metrics: dict[str, float], out: Path) -> Path:
    """One self-contained HTML page: the figure (embedded PNG) and the metrics table."""
    image = base64.b64encode(figure_png(session, metrics)).decode('ascii')
    experiment = session.experiment
    title = html.escape(experiment.run.name if experiment is not None else session.path.name)
    rows = ''.join(
        f'<tr><td>{html.escape(METRIC_LABELS[k][0])}</td><td>{html.escape(k)}</td>'
        f'<td style="text-align:right">{metrics[k]:.3f} {html.escape(METRIC_LABELS[k][1])}</td>'
        '</tr>' for k in (*METRIC_NAMES, *OPTIONAL_METRICS, 'realtime_factor')
        if k in metrics)
    cuts = cut_table(session)
    cut_rows = ''.join('<tr>' + ''.join(f'<td style="text-align:right">{html.escape(c)}</td>'
                                        for c in _cut_cells(r)) + '</tr>' for r in cuts)
    cut_head = ''.join(f'<th>{html.escape(h)}{f" [{u}]" if u else ""}</th>'
                       for h, u, _ in CUT_COLUMNS)
    cut_log = (f'<h2>Cut log</h2><table border="1" cellpadding="4" class="cuts"><tr>{cut_head}'
               f'</tr>{cut_rows}</table>' if cuts else '')
    out.write_text(
        f'<!DOCTYPE html>\n<html><head><meta charset="utf-8"><title>{title}</title></head>'
        f'<body style="font-family:sans-serif"><h1>{title}</h1>'
        f'<p>session: {html.escape(str(session.path))}</p>'
        f'<img alt="force, depth, feed and override over time" '
        f'src="data:image/png;base64,{image}" style="max-width:100%">'
        f'<table border="1" cellpadding="4"><tr><th>metric</th><th>key</th><th>value</th></tr>'
        f'{rows}</table>{cut_log}</body></html>\n')
    return out
