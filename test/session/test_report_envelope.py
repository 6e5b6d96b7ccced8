"""The report draws a long session as its envelope, one column of the figure at a time: every
spike stays on the figure, and short sessions are drawn sample by sample as before."""

from __future__ import annotations

import numpy as np

from turning_force.session.report import COLUMNS, _band, _envelope, _spans


def test_a_short_signal_is_drawn_as_it_is():
    t = np.arange(2 * COLUMNS, dtype=float)
    y = np.sin(t)
    drawn_t, drawn_y = _envelope(t, y)
    assert drawn_t is t and drawn_y is y


def test_an_hour_keeps_its_spikes_and_its_order():
    n = 360_000   # an hour of 10 ms blocks
    t = np.arange(n) * 0.01 + 0.01
    y = np.full(n, 500.0)
    y[123_457] = 800.0   # one block's spike
    y[250_001] = 90.0    # and one dip
    y[300_000:300_500] = np.nan   # blocks without an answer
    drawn_t, drawn_y = _envelope(t, y)
    assert drawn_t.size <= 2 * COLUMNS + 2
    assert np.nanmax(drawn_y) == 800.0 and np.nanmin(drawn_y) == 90.0
    assert drawn_t[np.nanargmax(drawn_y)] == t[123_457]   # at its own time
    assert np.all(np.diff(drawn_t) >= 0)                  # a line through them goes forward
    assert np.isnan(drawn_y).any()                        # the gap stays a gap


def test_the_band_holds_each_columns_extremes():
    n = 100_000
    t = np.arange(n, dtype=float)
    y = np.where(np.arange(n) % 997 == 0, 600.0, 500.0)
    starts, low, high = _band(t, y)
    assert starts.size <= COLUMNS and starts[0] == 0.0
    assert low.min() == 500.0 and high.max() == 600.0


def test_spans_a_pixel_apart_are_drawn_as_one():
    mask = np.zeros(100, dtype=bool)
    mask[[10, 11, 14, 40]] = True
    assert _spans(mask) == [(10, 11), (14, 14), (40, 40)]
    assert _spans(mask, join=3) == [(10, 14), (40, 40)]
