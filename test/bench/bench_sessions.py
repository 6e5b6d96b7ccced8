"""Benchmark: a one-hour session (fig8 at 3600 s), written by ``run --core --out``, then read,
reported and replayed, each in its own process, timed (wall) with its peak memory (the child's
``ru_maxrss``).

Side by side, in one run: reading it the old way (every message kept as bytes, deserialised one by
one with rosbags' pure-Python CDR, a :class:`CurrentBlock` per block: the reader before issue 9,
kept here as :func:`read_old`); with the libraries alone, as well as they allow
(:func:`read_libraries`: mcap's reader, rosbags' typestore, numpy); and with ours (scan.py's
record scan, codec.py's array-level CDR chunk by chunk); and the scan alone, mcap's reader beside
ours. Issue 14 keeps our scan and codec only where they are at least 10x faster than the
libraries on this session (the in-process times); every message they read is checked equal to
rosbags' in test/session/test_streaming_reader.py. The writing side too: codec.encode (which
``run --core --out`` serialises with) beside rosbags' serialize_cdr, message by message, on
every message of the session's fixed-layout topics, a chunk at a time as ``run --core --out``
writes them, the bytes checked equal (the message objects rosbags needs are built before the
clock starts, so its figure is a lower bound).
Targets (issue 9): replay <= 10 s, report <= 10 s, peak memory reading back <= 400 MB.

    .venv/bin/python test/bench/bench_sessions.py [--hours H] [--keep DIR]
"""

from __future__ import annotations

import argparse
import math
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


def read_libraries(bag: Path) -> int:
    """The same signals read with the libraries alone, as well as they allow: mcap's reader
    (its chunk index, decompression and CRC checks, the topics read only, no merge into
    log-time order), rosbags' typestore deserialisation (its generated CDR code, the session's
    own definitions), each message's fields taken as it is decoded (no message object kept),
    numpy stacking and the same vectorised stamp matching as ours. Returns the number of
    blocks."""
    import numpy as np
    from mcap.reader import make_reader

    from turning_force.session.reader import READ, SIGNALS, _topic, session_typestore

    samples = ('phase_u_a', 'phase_v_a', 'rotor_angle_rad', 'feed_rate_mm_min')
    taken = {'servo/currents': ('sample_period_s', *samples)}
    for topic, path in SIGNALS.values():
        taken[topic] = (*taken.get(topic, ()), path)
    columns: dict[str, dict[str, list[object]]] = {
        t: {f: [] for f in ('stamp', *fields)} for t, fields in taken.items()}
    with next(bag.glob('*.mcap')).open('rb') as stream:
        reader = make_reader(stream, validate_crcs=True)
        summary = reader.get_summary()
        assert summary is not None
        channels = [c for c in summary.channels.values() if _topic(c.topic) in READ]
        schemas = {s.id: s for s in summary.schemas.values()}
        store = session_typestore(tuple(sorted(
            {(schemas[c.schema_id].name, schemas[c.schema_id].encoding,
              schemas[c.schema_id].data.decode()) for c in channels})))
        for schema, channel, message in reader.iter_messages(
                topics=[c.topic for c in channels], log_time_order=False):
            assert schema is not None
            kept = columns.get(_topic(channel.topic))
            if kept is None:   # pmc/cuts: none in a simulated session without a cut log
                continue
            msg = store.deserialize_cdr(message.data, schema.name)
            stamp = msg.header.stamp  # type: ignore[attr-defined]
            kept['stamp'].append(stamp.sec * 1_000_000_000 + stamp.nanosec)
            for field, values in kept.items():
                if field != 'stamp':
                    values.append(getattr(msg, field))
    currents = columns['servo/currents']
    first = np.array(currents['stamp'], dtype=np.int64)
    order = np.argsort(first, kind='stable')
    period = np.array(currents['sample_period_s'])[order]
    rows = {f: np.stack(currents[f])[order] for f in samples}
    last = first[order] + np.round((rows['phase_u_a'].shape[1] - 1) * period * 1e9).astype(
        np.int64)
    for topic, path in SIGNALS.values():
        unique, at_first = np.unique(np.array(columns[topic]['stamp'], dtype=np.int64),
                                     return_index=True)
        values = np.array(columns[topic][path], dtype=np.float64)
        at = np.clip(np.searchsorted(unique, last), 0, max(unique.size - 1, 0))
        found = unique[at] == last if unique.size else np.zeros(last.size, dtype=bool)
        out = np.full(last.size, np.nan)
        out[found] = values[at_first[at[found]]]
    return int(first.size)


def serialised(bag: Path, ours: bool) -> tuple[int, float]:
    """Every message of the session's fixed-layout topics serialised again, chunk by chunk
    (about the 2048 blocks ``run --core --out`` serialises at once), with codec.encode
    (``ours``) or rosbags' serialize_cdr one message at a time: (messages, in-process time of
    the serialisation alone [s]). The bytes must equal the recorded ones."""
    import numpy as np

    from turning_force.session import codec
    from turning_force.session.bag import typestore
    from turning_force.session.scan import McapScan, scan_mcap

    store = typestore()
    done = {'messages': 0, 'seconds': 0.0}

    def sink(scan: McapScan, data: np.ndarray, channels: np.ndarray, log_times: np.ndarray,
             offsets: np.ndarray, sizes: np.ndarray) -> None:
        for channel in np.unique(channels).tolist():
            msgtype = scan.schemas[scan.channels[channel].schema_id].name
            if msgtype == 'std_msgs/msg/String' or not codec.supports(store, msgtype):
                continue   # session/settings (twice a session), /diagnostics: rosbags's
            picked = channels == channel
            at, size = offsets[picked].tolist(), sizes[picked].tolist()
            recorded = b''.join(data[o:o + n].tobytes() for o, n in zip(at, size, strict=True))
            table, _ = codec.decode(store, msgtype, data, offsets[picked], sizes[picked])
            if ours:
                columns = {p: (v, table.lengths[p]) if p in table.lengths else v
                           for p, v in table.columns.items()}
                start = time.perf_counter()
                written = codec.encode(store, msgtype, columns, table.count)[0]
            else:
                objects = [store.deserialize_cdr(data[o:o + n].tobytes(), msgtype)
                           for o, n in zip(at, size, strict=True)]
                start = time.perf_counter()
                written = b''.join(bytes(store.serialize_cdr(m, msgtype)) for m in objects)
            done['seconds'] += time.perf_counter() - start
            assert written == recorded, scan.channels[channel].topic
            done['messages'] += table.count

    scan_mcap(next(bag.glob('*.mcap')), sink)
    return int(done['messages']), done['seconds']


def _child(which: str, bag: str) -> None:
    if which in ('encode', 'serialize'):
        count, spent = serialised(Path(bag), which == 'encode')
        print(f'{count} {spent:.3f}')
        return
    start = time.perf_counter()
    if which == 'old':
        n = read_old(Path(bag))
    elif which == 'libraries':
        n = read_libraries(Path(bag))
    elif which == 'scan':   # our scan alone: every chunk read and checked, nothing decoded
        from turning_force.session.scan import scan_mcap

        n = sum(scan_mcap(next(Path(bag).glob('*.mcap')), lambda *_: None).counts.values())
    elif which == 'mcap':   # mcap's reader alone: every message's bytes, CRCs checked
        from mcap.reader import make_reader

        with next(Path(bag).glob('*.mcap')).open('rb') as stream:
            n = sum(1 for _ in make_reader(stream, validate_crcs=True).iter_messages(
                log_time_order=False))
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
    rows: list[tuple[str, float, float, float]] = []
    if not bag.exists():
        wall, mb, _ = timed([*CLI, 'run', str(FIG8), '--core', '--out', str(bag), '--json',
                             '--set', f'experiment.duration_s={seconds}'])
        rows.append((f'run --core --out ({seconds} s of fig8)', wall, mb, math.nan))
    size_mb = next(bag.glob('*.mcap')).stat().st_size / 1e6
    me = [sys.executable, str(Path(__file__).resolve()), '--child']
    reads = {}
    for which, what in (('old', 'read, old (rosbags per message, as before issue 9)'),
                        ('libraries', 'read, libraries (mcap reader + rosbags + numpy)'),
                        ('new', 'read, ours (scan.py + codec.py, arrays)'),
                        ('mcap', '  scan only, mcap reader (CRCs checked)'),
                        ('scan', '  scan only, ours (scan.py, CRCs checked)'),
                        ('serialize', 'write, rosbags (serialize_cdr per message)'),
                        ('encode', 'write, ours (codec.encode, arrays)')):
        wall, mb, out = timed([*me, which, str(bag)])
        inner = float(out.split()[1])
        reads[which] = inner
        rows.append((what, wall, mb, inner))
    report = timed([*CLI, 'report', str(bag), '--out', str(folder / 'fig8_hour.png')])
    rows.append(('turning-force report', report[0], report[1], math.nan))
    replay = timed([*CLI, 'replay', str(bag), '--json'])
    rows.append(('turning-force replay', replay[0], replay[1], math.nan))
    print(f'one session of {seconds} s of fig8 ({seconds * 100} blocks, {size_mb:.0f} MB MCAP), '
          f'{bag}')
    print(f'  {"what":50s} {"wall [s]":>9s} {"peak [MB]":>10s} {"in-process [s]":>15s}')
    for what, wall, mb, inner in rows:
        print(f'  {what:50s} {wall:9.2f} {mb:10.0f} {inner:15.2f}')
    print(f'  in-process, libraries / ours: read {reads["libraries"] / reads["new"]:.1f}x, '
          f'scan {reads["mcap"] / reads["scan"]:.1f}x, decode (read less scan) '
          f'{(reads["libraries"] - reads["mcap"]) / (reads["new"] - reads["scan"]):.1f}x; '
          f'old / ours {reads["old"] / reads["new"]:.1f}x; '
          f'serialising {reads["serialize"] / reads["encode"]:.1f}x '
          '(keep ours where >= 10x; targets: replay <= 10 s, report <= 10 s, '
          'reading back <= 400 MB)')

if __name__ == '__main__':
    main()
