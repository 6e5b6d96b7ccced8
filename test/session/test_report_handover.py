"""A report a user can hand on, from real recorded sessions: a core session (``run --core
--out``) and a wall-clock one from the all-in-one graph as the machine PC runs it. The title
names the experiment, the machine and the date; times are seconds from the session's start
(not epoch seconds); the band drawn is the session's own; the HTML carries the parameters, the
machine, the software versions and the date, and the cut log row by row."""

from __future__ import annotations

import datetime
import io
import os
import re

import matplotlib.pyplot as plt
import numpy as np
import pytest
from matplotlib.collections import PolyCollection
from PIL import Image

from graph_run import record_regulated
from turning_force.cli import main
from turning_force.session.reader import read_session, recorded_metrics
from turning_force.session.report import figure, figure_png, report_facts

BAND_N = 37.0   # not the shopfloor file's 25 N nor the default 10 N


def today() -> str:
    return datetime.datetime.now(datetime.UTC).strftime('%Y-%m-%d')


@pytest.fixture(scope='module')
def core_session(tmp_path_factory, experiments_dir):
    bag = tmp_path_factory.mktemp('handover') / 'shopfloor'
    assert main(['run', str(experiments_dir / 'shopfloor.yaml'), '--core', '--out', str(bag),
                 '--set', f'experiment.allowed_error_n={BAND_N}']) == 0
    return read_session(bag)


def band_of(fig) -> tuple[float, float]:
    """The largest half-width of the shaded band about the reference, and its label."""
    ax = fig.axes[0]
    (fill,) = [c for c in ax.collections if isinstance(c, PolyCollection)
               and str(c.get_label()).startswith('allowed')]
    ys = fill.get_paths()[0].vertices[:, 1]
    return float(ys.max() - ys.min()) / 2.0, str(fill.get_label())


def times_of(fig) -> np.ndarray:
    return np.concatenate([line.get_xdata() for ax in fig.axes[:4] for line in ax.lines])


def test_the_title_names_experiment_machine_and_date(core_session):
    facts = report_facts(core_session)
    assert re.fullmatch(f'shopfloor on simulated lathe, fanuc_0t_4bit override, {today()} '
                        r'\d\d:\d\d UTC', facts.title), facts.title
    png = Image.open(io.BytesIO(figure_png(core_session, recorded_metrics(core_session))))
    assert png.text['Title'] == facts.title
    assert png.text['Creation Time'].startswith(today())
    assert 'turning_force ' in png.text['Software']


def test_the_band_drawn_is_the_sessions_own(core_session):
    facts = report_facts(core_session)
    assert (facts.band_n, facts.band_from) == (BAND_N, 'experiment.allowed_error_n')
    fig = figure(core_session, recorded_metrics(core_session))
    try:
        # The shopfloor reference is 500 N throughout: the band is 500 +/- 37 N.
        half, label = band_of(fig)
        assert half == pytest.approx(BAND_N) and label == f'allowed ±{BAND_N:g} N'
    finally:
        plt.close(fig)


def test_the_html_report_carries_what_a_reader_needs(core_session, tmp_path):
    out = tmp_path / 'report.html'
    assert main(['report', str(core_session.path), '--out', str(out)]) == 0
    text = out.read_text()
    facts = report_facts(core_session)
    assert f'<title>{facts.title}</title>' in text and f'<h1>{facts.title}</h1>' in text
    assert '<td>simulated lathe, fanuc_0t_4bit override</td>' in text
    assert f'<td>{today()} ' in text
    for name, version in core_session.versions.items():
        assert f'{name} {version}' in text
    # Every parameter of every node, as the session recorded it.
    assert '<h3>force_controller</h3>' in text and '<h3>pmc_bridge</h3>' in text
    assert f'<tr><td>allowed_error_n</td><td>{BAND_N}</td></tr>' in text
    assert '<tr><td>tool</td><td>T0101</td></tr>' in text
    # The cut log, one row per cut the bridge recorded, its start in session seconds.
    table = text.split('class="cuts">', 1)[1].split('</table>', 1)[0]
    rows = re.findall(r'<tr><td[^>]*>(\d+)</td><td[^>]*>([\d.]+)</td>', table)
    assert len(rows) == len(core_session.cuts) >= 2
    for (index, start), cut in zip(rows, core_session.cuts, strict=True):
        assert int(index) == cut.index and float(start) == pytest.approx(cut.start_s, abs=0.005)
    assert 'T0101' in table


def test_a_wall_clock_session_reads_in_seconds_from_its_start(context, executor, spin_until,
                                                              tmp_path, fig8):
    """The all-in-one graph on the wall clock, recording as the machine PC does: the
    recorder captures the nodes' parameters and embeds the experiment file."""
    bag = tmp_path / 'wall'
    record_regulated(context, executor, spin_until, fig8, bag, f'/handover_{os.getpid()}', 150,
                     f'experiment_file: {fig8}')   # 1.5 s of regulated cutting
    session = read_session(bag)
    facts = report_facts(session)
    assert facts.start_s > 1.0e9   # the stamps are the wall clock
    assert facts.title.startswith(f'park1998_fig8 on simulated lathe, fanuc_0t_4bit override, '
                                  f'{today()} ')
    # fig8's own band (25 N), from the embedded file: the nodes' captured parameters have no
    # experiment section, and the default would be 10 N.
    assert (facts.band_n, facts.band_from) == (25.0, 'experiment.allowed_error_n')
    fig = figure(session, recorded_metrics(session))
    try:
        t = times_of(fig)
        t = t[np.isfinite(t)]
        duration_s = float(session.t_s[-1] - session.t_s[0])
        assert 0.0 <= t.min() < 0.05 and t.max() == pytest.approx(duration_s, abs=0.05)
        assert band_of(fig)[0] == pytest.approx(25.0)
        assert fig.axes[3].get_xlabel() == 'time from the session start [s]'
    finally:
        plt.close(fig)
