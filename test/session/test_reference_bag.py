"""The committed reference session (bags/reference/park1998_fig8): still readable, and replaying
it with today's code reproduces what was recorded."""

from pathlib import Path

import pytest

from turning_force.session.reader import read_session, recorded_metrics
from turning_force.session.replay import replay

REFERENCE = Path(__file__).resolve().parents[2] / 'bags' / 'reference' / 'park1998_fig8'


def test_reference_session_replays_to_what_was_recorded():
    session = read_session(REFERENCE)
    assert len(session.blocks) == 1200
    result = replay(session)
    assert result.max_force_difference_n == 0.0
    assert result.differing_overrides == 0
    assert result.rerun == result.recorded


def test_reference_session_holds_parks_figure():
    metrics = recorded_metrics(read_session(REFERENCE))
    assert metrics['steady_mean_abs_error_n'] <= 8.9   # Park 1998 Fig. 8
    assert metrics['mean_abs_error_n'] == pytest.approx(8.02, abs=0.01)
