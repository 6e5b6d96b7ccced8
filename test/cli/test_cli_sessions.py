"""The turning-force command on broken sessions, and runs that are stopped, killed or run out of
disk: one line on stderr that names the bag and says what is wrong, the right exit status,
never a traceback; and what was recorded stays readable."""

from __future__ import annotations

import contextlib
import json
import math
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import pytest
import yaml

from bagfaults import (
    FIRST_CHUNK_BLOCKS,
    REFERENCE,
    chunks,
    copy_reference,
    flip,
    foreign_bag,
    mcap_of,
    random_middle,
    rewrite,
    truncate,
    wrong_type_bag,
)
from turning_force.cli import main
from turning_force.core.metrics import METRIC_NAMES
from turning_force.session.bag import CUSTOM_RECORDING
from turning_force.session.reader import read_session

FIG8 = Path(__file__).resolve().parents[2] / 'config' / 'experiments' / 'park1998_fig8.yaml'
COMMAND = Path(sys.prefix) / 'bin' / 'turning-force'


def one_line(capfd) -> str:
    err = capfd.readouterr().err
    assert err.count('\n') == 1 and 'Traceback' not in err, err
    return err.strip()


def no_metadata(out: Path) -> Path:
    copy_reference(out)
    (out / 'metadata.yaml').unlink()
    return out


BROKEN: dict[str, tuple[Callable[[Path], Path], str]] = {
    # name: (builder, what the line says after the bag)
    'random bytes': (lambda p: random_middle(copy_reference(p)),
                     f'servo/currents {FIRST_CHUNK_BLOCKS} of 1200 blocks read'),
    'cut at 50 %': (lambda p: truncate(copy_reference(p), 0.5),
                    f'servo/currents {FIRST_CHUNK_BLOCKS} of 1200 blocks read'),
    'corrupt zstd': (lambda p: flip(copy_reference(p), [chunks(REFERENCE)[0][1] + 50]),
                     'servo/currents 607 of 1200 blocks read'),
    'no metadata': (no_metadata, 'no metadata.yaml beside park1998_fig8.mcap'),
    'foreign': (foreign_bag, 'no servo/currents topic (/chatter): not a turning_force session'),
    'wrong type': (wrong_type_bag, '/servo/currents is std_msgs/msg/Float64, not '
                                   'turning_force_msgs/msg/ServoCurrents'),
}


@pytest.mark.parametrize('command', [['report'], ['replay'], ['replay', '--publish'],
                                     ['calibrate']])
@pytest.mark.parametrize('case', list(BROKEN))
def test_a_broken_session_is_one_line_naming_it(capfd, tmp_path, command, case):
    build, says = BROKEN[case]
    bag = build(tmp_path / 'bag')
    out = ['--out', str(tmp_path / 'r.png')] if command == ['report'] else []
    assert main([command[0], str(bag), *command[1:], *out]) == 2
    line = one_line(capfd)
    assert line.startswith(f'turning-force: {bag}: ') and says in line


def test_partial_reports_what_is_there_with_one_warning_line(capfd, tmp_path):
    bag = random_middle(copy_reference(tmp_path / 'middle'))
    assert main(['report', str(bag), '--out', str(tmp_path / 'r.png'), '--partial']) == 0
    assert one_line(capfd).startswith(f'turning-force: warning: partial session: {bag}: '
                                      f'damaged: servo/currents {FIRST_CHUNK_BLOCKS} of 1200 '
                                      'blocks')


def test_repair_rebuilds_a_cut_session(capfd, tmp_path):
    bag = truncate(copy_reference(tmp_path / 'cut'), 0.99)
    assert main(['repair', str(bag), '--json']) == 0
    out = json.loads(capfd.readouterr().out)
    assert out['repaired'] and out['recovered'] == out['recorded']   # a 99 % cut loses nothing
    assert main(['repair', str(bag)]) == 0
    assert capfd.readouterr().out.startswith(f'{bag}: nothing to repair')


def test_a_session_with_only_currents_is_not_an_air_cut(capfd, tmp_path):
    bag = rewrite(REFERENCE, tmp_path / 'currents', keep=lambda t: t == '/servo/currents')
    assert main(['report', str(bag), '--out', str(tmp_path / 'r.png')]) == 2
    assert one_line(capfd) == (
        f'turning-force: {bag}: no force/estimate and no sim/cutting_state in the session: no '
        'force to measure (`turning-force replay` estimates it from the currents)')


def test_report_of_a_session_missing_its_last_answer_prints_numbers(capfd, tmp_path):
    # As a wall-clock session stopped between a block's currents and its answers: the last
    # block has currents only. That made every mean NaN, printed with exit 0.
    last = read_session(REFERENCE).answer_stamps_ns[-1]

    def drop_last_answers(topic, msg):
        stamp = getattr(msg, 'header', None)
        if topic != '/servo/currents' and stamp is not None and (
                stamp.stamp.sec * 1_000_000_000 + stamp.stamp.nanosec) == last:
            return None
        return msg

    bag = rewrite(REFERENCE, tmp_path / 'wall', change=drop_last_answers)
    assert main(['report', str(bag), '--out', str(tmp_path / 'r.png')]) == 0
    printed = capfd.readouterr().out.splitlines()[1:]
    values = {line.split()[0]: float(line.split()[1]) for line in printed}
    assert set(values) == {*METRIC_NAMES, 'estimate_error_rms_n'}   # the truth is recorded
    assert all(math.isfinite(v) for v in values.values()), values


# Runs as a shop stops them: a signal, a kill, a full disk. Each is a real `turning-force run`
# process; the test waits on the process (with a deadline) until the session is under way.
LONG = ['--set', 'experiment.duration_s=60.0']


def start_run(bag: Path, *prefix: str) -> subprocess.Popen[str]:
    return subprocess.Popen([*prefix, str(COMMAND), 'run', str(FIG8), '--out', str(bag), *LONG],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def wait_until(condition: Callable[[], bool], process: subprocess.Popen[str],
               timeout_s: float = 60.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not condition():
        assert process.poll() is None, process.communicate()
        assert time.monotonic() < deadline, 'the run never got under way'
        with contextlib.suppress(subprocess.TimeoutExpired):
            process.wait(timeout=0.05)


def chunk_written(bag: Path) -> Callable[[], bool]:
    """The recorder has flushed a chunk (it does once a wall second)."""
    return lambda: (bag / 'metadata.yaml').is_file() and mcap_of(bag).stat().st_size > 10_000


@pytest.mark.parametrize('signum', [signal.SIGINT, signal.SIGTERM])
def test_a_signal_stops_a_run_with_one_line_and_a_closed_session(tmp_path, signum):
    bag = tmp_path / 'stopped'
    run = start_run(bag)
    try:
        wait_until(chunk_written(bag), run)
        run.send_signal(signum)
        _, err = run.communicate(timeout=60)
    finally:
        run.kill()
    assert run.returncode == 128 + signum
    lines = [line for line in err.splitlines() if not line.startswith('[')]   # node logs
    assert len(lines) == 1 and 'Traceback' not in err, err
    assert lines[0].startswith(f'turning-force: interrupted by {signal.Signals(signum).name} '
                               'after block ')
    assert lines[0].endswith(f'the session {bag} is closed with what ran (ended early)')
    blocks = int(lines[0].split('after block ')[1].split()[0])
    session = read_session(bag)   # closed: counts written, nothing missing, ended early
    assert len(session.blocks) == blocks
    assert session.warning == (f'{bag}: ended early: stopped by {signal.Signals(signum).name} '
                               f'after {blocks} of 6000 planned blocks (closed cleanly)')


def test_a_killed_run_leaves_a_session_that_says_so_and_repairs(capfd, tmp_path):
    bag = tmp_path / 'killed'
    run = start_run(bag)
    try:
        wait_until(chunk_written(bag), run)
    finally:
        run.kill()
        run.communicate(timeout=60)
    metadata = yaml.safe_load((bag / 'metadata.yaml').read_text())
    assert CUSTOM_RECORDING in metadata['rosbag2_bagfile_information']['custom_data']
    assert main(['report', str(bag), '--out', str(tmp_path / 'r.png')]) == 2
    assert 'the recording was never closed' in one_line(capfd)
    assert main(['repair', str(bag)]) == 0
    capfd.readouterr()
    session = read_session(bag)
    assert len(session.blocks) > 0 and session.experiment is not None   # its settings kept
    assert main(['report', str(bag), '--out', str(tmp_path / 'r.png')]) == 0
    assert 'repaired session' in one_line(capfd)


def test_a_full_disk_stops_the_run_with_one_line_and_keeps_what_was_written(tmp_path):
    # A file size limit (RLIMIT_FSIZE, with SIGXFSZ ignored) fails the write as a full disk
    # would. 1 MiB holds at least one chunk (at most 1 MiB uncompressed, a third of that
    # written) and not the 60 s session (about 3 MB).
    bag = tmp_path / 'full'
    limit = 1 << 20
    script = ('import resource, signal, sys; signal.signal(signal.SIGXFSZ, signal.SIG_IGN); '
              f'resource.setrlimit(resource.RLIMIT_FSIZE, ({limit}, {limit})); '
              'from turning_force.cli import main; sys.exit(main(sys.argv[1:]))')
    run = subprocess.run([sys.executable, '-c', script, 'run', str(FIG8), '--out', str(bag),
                          *LONG], capture_output=True, text=True, timeout=300, check=False)
    assert run.returncode == 2
    lines = [line for line in run.stderr.splitlines() if not line.startswith('[')]
    assert lines == [f'turning-force: {bag}: cannot write the session: File too large; what '
                     f'was written before stays readable (`turning-force repair {bag}`)'], \
        run.stderr
    session = read_session(bag, partial=True)
    assert 'never closed' in session.warning
    assert 100 <= len(session.blocks) < 6000
    assert session.blocks[0].t0_s == 0.0
