"""Friction calibration from air-cut sessions recorded through the graph (Park 1998, Eq. 25)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from turning_force.commands.run import run_lockstep
from turning_force.core.experiment import load_experiment
from turning_force.session.bag import BagError
from turning_force.session.calibrate import calibrate
from turning_force.session.reader import read_session

EXPERIMENTS = Path(__file__).resolve().parents[2] / 'config' / 'experiments'


@pytest.fixture(scope='module')
def air_cuts(tmp_path_factory):
    experiment = load_experiment(EXPERIMENTS / 'air_cut.yaml')
    folder = tmp_path_factory.mktemp('air')
    sessions = []
    for feed in (0.05, 0.15, 0.3):   # 30, 90, 180 mm/min at 600 rpm
        bag = folder / f'air_{feed}'
        run_lockstep(experiment.with_sets([f'/**.programmed_feed_mm_rev={feed}']), bag)
        sessions.append(read_session(bag))
    return experiment, sessions


def test_air_cuts_give_back_the_machines_friction(air_cuts):
    experiment, sessions = air_cuts
    result = calibrate(sessions)
    truth = experiment.plant.friction
    np.testing.assert_allclose(result.feeds_mm_min, [30.0, 90.0, 180.0], rtol=1e-3)
    # Each point is 1500 samples of 0.02 A noise: the mean is good to about 0.001 A.
    np.testing.assert_allclose(result.currents_a,
                               truth.current_a(np.array(result.feeds_mm_min)), atol=2e-3)
    # The fitted Eq. 25 curve (vertex at the slowest feed cut) stays within 5 mA of the machine's
    # over the range calibrated.
    feeds = np.linspace(30.0, 180.0, 16)
    np.testing.assert_allclose(result.model.current_a(feeds), truth.current_a(feeds), atol=5e-3)
    parameters = result.estimator_parameters()
    assert parameters['friction_min_feed_mm_min'] == pytest.approx(30.0, rel=1e-3)
    assert parameters['friction_at_max_feed_a'] == pytest.approx(
        float(result.model.current_a(np.array([180.0]))[0]), abs=1e-3)


def test_a_session_that_cut_is_not_an_air_cut(air_cuts, tmp_path):
    experiment = load_experiment(EXPERIMENTS / 'park1998_fig8.yaml').with_sets(
        ['experiment.duration_s=1.0'])
    bag = tmp_path / 'cut'
    run_lockstep(experiment, bag)
    with pytest.raises(BagError, match=r'the tool cut .*not an air cut'):
        calibrate([air_cuts[1][0], read_session(bag)])
