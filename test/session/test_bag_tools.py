"""Sessions that survive any bag tool (issue 18, item 6): the settings are recorded on the
``session/settings`` topic, so a round trip through ``rosbags-convert`` (MCAP -> SQLite 3 ->
MCAP), which drops ``metadata.yaml``'s custom data, leaves a session that ``report`` and
``replay`` still read, with its settings, its plan and how it ended."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from bagfaults import stopped_by
from turning_force.cli import Interrupted, main
from turning_force.commands.core_session import record_core
from turning_force.core.experiment import load_experiment
from turning_force.session.bag import CUSTOM_END, CUSTOM_PARAMETERS
from turning_force.session.reader import ENDED_EARLY, WHOLE, read_session, recorded_metrics

CONVERT = Path(sys.prefix) / 'bin' / 'rosbags-convert'
FIG8 = Path(__file__).resolve().parents[2] / 'config' / 'experiments' / 'park1998_fig8.yaml'


def round_trip(bag: Path, out: Path) -> Path:
    """``bag`` through rosbags-convert to SQLite 3 and back to MCAP."""
    sqlite = out.with_name(out.name + '_sqlite3')
    for src, dst, storage in ((bag, sqlite, 'sqlite3'), (sqlite, out, 'mcap')):
        subprocess.run([str(CONVERT), '--src', str(src), '--dst', str(dst), '--dst-storage',
                        storage], check=True, capture_output=True, timeout=120)
    info = yaml.safe_load((out / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    assert not info.get('custom_data')   # the tool dropped them: only the topic has them
    return out


def test_report_and_replay_read_a_session_after_rosbags_convert(reference_bag, tmp_path,
                                                                capfd):
    # Issue 18: after this round trip `report` and `replay` refused the session (no settings).
    bag = round_trip(reference_bag, tmp_path / 'converted')
    original, converted = read_session(reference_bag), read_session(bag)
    assert converted.custom_data[CUSTOM_PARAMETERS] == original.custom_data[CUSTOM_PARAMETERS]
    assert recorded_metrics(converted) == recorded_metrics(original)
    assert main(['report', str(bag), '--json', '--out', str(tmp_path / 'r.png')]) == 0
    out = capfd.readouterr()
    state = json.loads(out.out)['session_state']
    assert (state['state'], state['blocks'], state['planned']) == (WHOLE, 1200, 1200)
    # rosbags writes no chunk CRC: said, not hidden.
    assert state['unverified_chunks'] == state['chunks'] > 0
    assert 'chunks carry no CRC: their bytes cannot be verified' in out.err
    assert main(['replay', str(bag), '--json']) == 0
    comparison = json.loads(capfd.readouterr().out)['comparison']
    assert comparison['blocks'] == 1200 and comparison['differing_overrides'] == 0


def test_how_a_session_ended_survives_the_round_trip(tmp_path):
    bag = tmp_path / 'stopped'
    experiment = load_experiment(FIG8).with_sets(['experiment.duration_s=30.0'])
    with pytest.raises(Interrupted):
        record_core(experiment, bag, stopped_by(signal.SIGTERM))
    converted = read_session(round_trip(bag, tmp_path / 'converted'))
    assert CUSTOM_END in converted.custom_data
    assert converted.wholeness is not None
    assert (converted.wholeness.state, converted.wholeness.blocks, converted.wholeness.planned,
            converted.wholeness.stopped_by) == (ENDED_EARLY, 2048, 3000, 'SIGTERM')
