"""Benchmark: a one-hour session (fig8 at 3600 s), written by ``run --core --out``, then read,
reported and replayed, each in its own process, timed (wall) with its peak memory (the child's
``ru_maxrss``).

Side by side: reading it the old way (every message kept as bytes, deserialised one by one with
rosbags' pure-Python CDR, a :class:`CurrentBlock` per block: the reader before issue 9, kept
here as :func:`read_old`) and with today's streaming reader (array-level CDR chunk by chunk).
Targets (issue 9): replay <= 10 s, report <= 10 s, peak memory reading back <= 400 MB.

    .venv/bin/python test/bench/bench_sessions.py [--hours H] [--keep DIR]
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
FIG8 = ROOT / 'config' / 'experiments' / 'park1998_fig8.yaml'
CLI = [sys.executable, '-m', 'turning_force.cli']


def read_old(bag: Path) -> int:
    """The reader before issue 9, for comparison: every message of the file as bytes, each one
    deserialised by rosbags, a block object per block, the answers matched in dicts. Returns
    the number of blocks."""
    import numpy as np

    from turning_force.core.plant.drive import CurrentBlock
    from turning_force.session.reader import (
        ANSWERS,
        READ,
        _topic,
        read_recording,
        session_typestore,
    )

    recording = read_recording(bag)   # scan without a sink: every message kept
    wanted = {name: topic for name, topic in recording.topics.items()
              if _topic(name) in READ and name in recording.definitions}
    store = session_typestore(tuple(sorted({recording.definitions[n] for n in wanted})))
    decoded: dict[str, list[object]] = {t: [] for t in READ}
    for name, topic in wanted.items():
        for _, raw in recording.messages.get(name, []):
            decoded[_topic(name)].append(store.deserialize_cdr(raw, topic.msgtype))
    blocks = []
    for msg in decoded['servo/currents']:
        m: object = msg
        stamp = m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec  # type: ignore
        blocks.append((stamp, CurrentBlock(stamp * 1e-9, float(m.sample_period_s),  # type: ignore
                                           *(np.asarray(getattr(m, f), dtype=float) for f in (
                                               'phase_u_a', 'phase_v_a', 'rotor_angle_rad',
                                               'feed_rate_mm_min')))))
    answers: dict[str, dict[int, object]] = {t: {} for t in ANSWERS}
    for topic in ANSWERS:
        for msg in decoded[topic]:
            s = msg.header.stamp  # type: ignore[attr-defined]
            answers[topic].setdefault(s.sec * 1_000_000_000 + s.nanosec, msg)
    for topic in ANSWERS:
        np.array([float(answers[topic][s].header.stamp.sec)
                  if s in answers[topic] else np.nan for s, _ in blocks])
    return len(blocks)


def _child(which: str, bag: str) -> None:
    start = time.perf_counter()
    if which == 'old':
        n = read_old(Path(bag))
    else:
        from turning_force.session.reader import read_session

        n = len(read_session(bag).t_s)
    print(f'{n} {time.perf_counter() - start:.3f}')


def timed(command: list[str]) -> tuple[float, float, str]:
    """(wall [s], peak resident memory of the child [MB], its stdout)."""
    start = time.perf_counter()
    with tempfile.TemporaryFile() as out:
        process = subprocess.Popen(command, stdout=out, stderr=subprocess.PIPE, cwd=ROOT)
        _, status, usage = os.wait4(process.pid, 0)
        wall = time.perf_counter() - start
        process.returncode = os.waitstatus_to_exitcode(status)
        err = process.stderr.read().decode() if process.stderr else ''
        out.seek(0)
        text = out.read().decode()
    if process.returncode:
        raise SystemExit(f'{" ".join(command)}: exit {process.returncode}: {err[-2000:]}')
    return wall, usage.ru_maxrss / 1024.0, text


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--hours', type=float, default=1.0)
    parser.add_argument('--keep', help='folder to write the session in (kept)')
    parser.add_argument('--child', nargs=2, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        _child(*args.child)
        return
    folder = Path(args.keep or tempfile.mkdtemp(prefix='bench_sessions_'))
    folder.mkdir(parents=True, exist_ok=True)
    bag = folder / 'fig8_hour'
    seconds = round(3600 * args.hours)
    rows = []
    if not bag.exists():
        wall, mb, _ = timed([*CLI, 'run', str(FIG8), '--core', '--out', str(bag), '--json',
                             '--set', f'experiment.duration_s={seconds}'])
        rows.append((f'run --core --out ({seconds} s of fig8)', wall, mb))
    size_mb = next(bag.glob('*.mcap')).stat().st_size / 1e6
    me = [sys.executable, str(Path(__file__).resolve()), '--child']
    old = timed([*me, 'old', str(bag)])
    new = timed([*me, 'new', str(bag)])
    rows.append(('read, old (rosbags per message)', old[0], old[1]))
    rows.append(('read, new (streaming, arrays)', new[0], new[1]))
    report = timed([*CLI, 'report', str(bag), '--out', str(folder / 'fig8_hour.png')])
    rows.append(('turning-force report', report[0], report[1]))
    replay = timed([*CLI, 'replay', str(bag), '--json'])
    rows.append(('turning-force replay', replay[0], replay[1]))
    print(f'one session of {seconds} s of fig8 ({seconds * 100} blocks, {size_mb:.0f} MB MCAP), '
          f'{bag}')
    print(f'  {"what":44s} {"wall [s]":>9s} {"peak [MB]":>10s}')
    for what, wall, mb in rows:
        print(f'  {what:44s} {wall:9.2f} {mb:10.0f}')
    print(f'  read old/new: {old[0] / new[0]:.1f}x the time, {old[1] / new[1]:.1f}x the memory '
          '(targets: replay <= 10 s, report <= 10 s, reading back <= 400 MB)')


if __name__ == '__main__':
    main()
