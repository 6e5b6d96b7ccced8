"""Sessions that know how whole they are (issue 17): a run stopped by SIGINT or SIGTERM closes
its session as *ended early* (the blocks it ran and the planned count), one killed by SIGKILL
leaves a session read back as *killed* (what its complete chunks hold), and neither is ever read
as whole. Graph runs and ``run --core --out`` alike, stopped at random times; ``report``,
``replay`` and their JSON name the state."""

from __future__ import annotations

import contextlib
import json
import random
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from bagfaults import stopped_by
from turning_force.cli import Interrupted, main
from turning_force.commands.core_session import record_core
from turning_force.commands.run import run_lockstep
from turning_force.core.experiment import load_experiment
from turning_force.session.bag import BagError
from turning_force.session.reader import ENDED_EARLY, KILLED, WHOLE, read_session

FIG8 = Path(__file__).resolve().parents[2] / 'config' / 'experiments' / 'park1998_fig8.yaml'
COMMAND = Path(sys.prefix) / 'bin' / 'turning-force'
# 6,000 blocks through the graph (about 5 s here), 60,000 through the core loop (its run about
# 1.5 s, its writing about 2 s): long enough that a random time lands inside the recording.
GRAPH = ('graph', ['--set', 'experiment.duration_s=60.0'], 6000, 7.0)
CORE = ('core', ['--core', '--set', 'experiment.duration_s=600.0'], 60000, 4.0)
SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGKILL)


def stop_at(bag: Path, args: list[str], signum: int, delay_s: float
            ) -> tuple[int, str]:
    """Start ``turning-force run ... --out bag``, wait until its session is open, let it run
    ``delay_s`` more, send ``signum``; the exit status and stderr."""
    run = subprocess.Popen([str(COMMAND), 'run', str(FIG8), '--out', str(bag), *args],
                           stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 120.0
        while not (bag / 'metadata.yaml').is_file():
            assert run.poll() is None, run.communicate()
            assert time.monotonic() < deadline, 'the session never opened'
            with contextlib.suppress(subprocess.TimeoutExpired):
                run.wait(timeout=0.02)
        with contextlib.suppress(subprocess.TimeoutExpired):
            run.wait(timeout=delay_s)
        if run.poll() is None:
            run.send_signal(signum)
        _, err = run.communicate(timeout=120)
    finally:
        run.kill()
    return run.returncode, err


def check_stopped(bag: Path, signum: int, status: int, err: str, planned: int) -> str:
    """The session ``bag`` left by ``signum`` (exit ``status``, ``err``) is read back as what
    happened to it, with the right count of blocks; returns its state."""
    lines = [line for line in err.splitlines() if not line.startswith('[')]   # node logs
    assert 'Traceback' not in err, err
    try:
        session = read_session(bag, partial=True)
    except BagError as exc:   # stopped before the first block was written
        said = str(exc)
        assert said.startswith(f'{bag}: no servo/currents blocks in the session ('), said
        assert (f'killed: never closed; the complete chunks hold 0 of {planned}' in said
                if signum == signal.SIGKILL else
                f'ended early: stopped by {signal.Signals(signum).name} after 0 of {planned}'
                in said), said
        return KILLED if signum == signal.SIGKILL else ENDED_EARLY
    state = session.wholeness
    assert state is not None
    blocks = len(session.blocks)
    assert state.blocks == blocks and state.planned == planned
    # The blocks read are the run's first ones, one after the other: nothing in between lost.
    starts = session.block_starts_s
    assert starts[0] == 0.0
    assert np.allclose(np.diff(starts), 0.01, atol=1e-9)
    if state.state == WHOLE:   # the run ended before the signal, or the signal came after
        assert blocks == planned and read_session(bag).warning == ''   # the session closed
        return WHOLE
    if signum == signal.SIGKILL:
        assert status == -signal.SIGKILL
        assert state.state == KILLED, state   # all blocks, when killed as it closed
        # Only the torn end: no CRC or structure error in what was written.
        assert all('ends inside a record' in d or 'no footer' in d or 'summary' in d
                   for d in state.lost), state.lost
        with pytest.raises(BagError, match=rf'^{re.escape(str(bag))}: killed: never closed; '
                                           rf'the complete chunks hold {blocks} of {planned}'):
            read_session(bag)
        return KILLED
    name = signal.Signals(signum).name
    assert status == 128 + signum, err
    assert len(lines) == 1, err
    said = int(lines[0].split('after block ')[1].split()[0])
    assert (state.state, state.stopped_by, blocks) == (ENDED_EARLY, name, said), (state, err)
    assert blocks < planned
    closed = read_session(bag)   # closed cleanly: read without --partial, saying so
    assert closed.warning == (f'{bag}: ended early: stopped by {name} after {blocks} of '
                              f'{planned} planned blocks (closed cleanly)')
    return ENDED_EARLY


# -- the two cases of the issue, deterministic ---------------------------------------------

def test_a_graph_run_stopped_after_one_block_reads_as_ended_early(tmp_path, capfd):
    # Issue 17: stopped by SIGINT after 1 of 1,200 blocks, this session was reported as whole
    # with a steady error of 0.000.
    bag = tmp_path / 'one'
    with pytest.raises(Interrupted):
        run_lockstep(load_experiment(FIG8), bag, stopped_by(signal.SIGINT))
    capfd.readouterr()   # the nodes' logs
    assert main(['report', str(bag), '--json', '--out', str(tmp_path / 'one.png')]) == 0
    out = capfd.readouterr()
    state = json.loads(out.out)['session_state']
    assert (state['state'], state['blocks'], state['planned'], state['stopped_by']) == (
        ENDED_EARLY, 1, 1200, 'SIGINT')
    assert out.err == (f'turning-force: warning: {bag}: ended early: stopped by SIGINT after '
                       '1 of 1200 planned blocks (closed cleanly)\n')
    assert main(['replay', str(bag), '--json']) == 0
    assert json.loads(capfd.readouterr().out)['session_state']['state'] == ENDED_EARLY


def test_a_core_run_stopped_after_its_first_batch_reads_as_ended_early(tmp_path, capsys):
    # Issue 17: `run --core --out` stopped by SIGTERM left 2,048 of 60,000 blocks that read
    # as whole. Stopped where the command's handler stops it: after a batch of blocks.
    bag = tmp_path / 'core'
    experiment = load_experiment(FIG8).with_sets(['experiment.duration_s=600.0'])
    with pytest.raises(Interrupted):
        record_core(experiment, bag, stopped_by(signal.SIGTERM))
    session = read_session(bag)
    assert session.wholeness is not None
    assert session.wholeness.to_json() | {'text': ''} == {
        'state': ENDED_EARLY, 'blocks': 2048, 'planned': 60000, 'recorded': 2048,
        'stopped_by': 'SIGTERM', 'lost': [], 'chunks': session.wholeness.chunks,
        'unverified_chunks': 0, 'repaired': False, 'text': ''}
    assert main(['replay', str(bag)]) == 0
    assert 'ended early: stopped by SIGTERM after 2048 of 60000 planned blocks' in \
        capsys.readouterr().out


# -- real processes, real signals ------------------------------------------------------------

@pytest.mark.parametrize(('kind', 'signum'), [(GRAPH, signal.SIGINT), (CORE, signal.SIGTERM),
                                              (GRAPH, signal.SIGKILL), (CORE, signal.SIGKILL)],
                         ids=['graph-SIGINT', 'core-SIGTERM', 'graph-SIGKILL', 'core-SIGKILL'])
def test_a_sample_of_runs_stopped_at_random_times(tmp_path, kind, signum):
    name, args, planned, longest_s = kind
    delay_s = random.Random(f'{name}{signum}').uniform(0.5, longest_s * 0.6)
    status, err = stop_at(tmp_path / 'bag', args, signum, delay_s)
    check_stopped(tmp_path / 'bag', signum, status, err, planned)


KILLS = 100


@pytest.mark.slow
@pytest.mark.parametrize('case', range(KILLS))
def test_a_hundred_runs_stopped_at_random_times(tmp_path, case):
    # Every signal on graph and core runs, each at a random time from the session's opening
    # to a little past the run's end (seeded: the same times on every machine).
    draw = random.Random(case)
    name, args, planned, longest_s = (GRAPH, CORE)[case % 2]
    signum = SIGNALS[(case // 2) % 3]
    status, err = stop_at(tmp_path / 'bag', args, signum, draw.uniform(0.0, longest_s))
    state = check_stopped(tmp_path / 'bag', signum, status, err, planned)
    print(f'kill {case}: {name} {signal.Signals(signum).name} -> {state}')
