"""The streaming reader against an independent one: the committed reference session read chunk by
chunk as arrays gives what rosbags' AnyReader (message by message, its own CDR) gives, every
field of every message of every topic; a chunk's
message index that does not hold is passed over for a walk through its records, losing nothing;
and the file is never held whole (nothing is kept of the messages but the signals)."""

from __future__ import annotations

import numpy as np
from rosbags.highlevel import AnyReader
from test_codec import check_table

from bagfaults import REFERENCE, REFERENCE_BLOCKS, chunks, copy_reference, mcap_of
from turning_force.session import codec
from turning_force.session.bag import typestore
from turning_force.session.reader import read_recording, read_session, session_typestore
from turning_force.session.scan import scan_mcap


def by_rosbags(bag):
    """Each topic's messages, deserialised by rosbags, in file order."""
    out: dict[str, list] = {}
    with AnyReader([bag], default_typestore=typestore()) as reader:
        for connection, _, raw in reader.messages():
            if connection.topic == '/diagnostics':
                continue
            out.setdefault(connection.topic, []).append(
                reader.deserialize(raw, connection.msgtype))
    return out


def ns(stamp):
    return stamp.sec * 1_000_000_000 + stamp.nanosec


def test_the_reference_reads_as_rosbags_reads_it():
    session = read_session(REFERENCE)
    messages = by_rosbags(REFERENCE)
    currents = sorted(messages['/servo/currents'], key=lambda m: ns(m.header.stamp))
    assert len(session.currents) == len(currents) == REFERENCE_BLOCKS
    for name in ('phase_u_a', 'phase_v_a', 'rotor_angle_rad', 'feed_rate_mm_min'):
        np.testing.assert_array_equal(getattr(session.currents, name),
                                      np.stack([getattr(m, name) for m in currents]))
    np.testing.assert_array_equal(session.currents.t0_s,
                                  [ns(m.header.stamp) * 1e-9 for m in currents])
    for topic, field, signal in (('/force/estimate', 'force_n', 'estimated_force_n'),
                                 ('/control/feed_command', 'override_pct',
                                  'requested_override_pct'),
                                 ('/pmc/feed_override', 'applied_pct', 'answered_override_pct'),
                                 ('/pmc/feed_override', 'reason', 'override_reason'),
                                 ('/sim/cutting_state', 'force_n', 'force_n')):
        first: dict[int, float] = {}
        for m in messages[topic]:
            first.setdefault(ns(m.header.stamp), float(getattr(m, field)))
        expected = [first.get(int(s), np.nan) for s in session.answer_stamps_ns]
        np.testing.assert_array_equal(session.signals[signal], expected, err_msg=signal)


def test_every_message_decodes_as_rosbags_decodes_it():
    """Our scan and codec (kept for speed: test/bench/bench_sessions.py) against rosbags'
    reader and CDR on every message of every topic of the reference session, every field: the
    topics the codec reads as arrays give the same values; the one type it has no fixed layout
    for (diagnostics, nested sequences) is left to rosbags by the reader. Both decode with the
    session's own message definitions (a message may have gained a field since it was
    recorded), as the reader does."""
    found: dict[int, list[tuple[int, bytes]]] = {}

    def sink(scan, data, channels, log_times, offsets, sizes):
        for c, t, o, n in zip(channels.tolist(), log_times.tolist(), offsets.tolist(),
                              sizes.tolist(), strict=True):
            found.setdefault(c, []).append((t, bytes(data[o:o + n])))

    scan = scan_mcap(mcap_of(REFERENCE), sink)
    store = session_typestore(tuple(sorted(
        {(s.name, s.encoding, s.data.decode()) for s in scan.schemas.values()})))
    theirs: dict[str, list] = {}
    with AnyReader([REFERENCE], default_typestore=store) as reader:
        for connection, _, raw in reader.messages():
            theirs.setdefault(connection.topic, []).append(
                (connection.msgtype, reader.deserialize(raw, connection.msgtype)))
    checked = set()
    for index, records in found.items():
        topic = scan.channels[index].topic
        msgtype = theirs[topic][0][0]
        assert len(records) == len(theirs[topic]), topic
        if not codec.supports(store, msgtype):
            assert msgtype == 'diagnostic_msgs/msg/DiagnosticArray'
            continue
        raws = [raw for _, raw in sorted(records, key=lambda r: r[0])]
        data = np.frombuffer(b''.join(raws), dtype=np.uint8)
        sizes = np.array([len(r) for r in raws], dtype=np.int64)
        table, read = codec.decode(store, msgtype, data,
                                   np.concatenate([[0], np.cumsum(sizes)[:-1]]), sizes)
        np.testing.assert_array_equal(read, np.arange(len(raws)))
        check_table(store, msgtype, table, [m for _, m in theirs[topic]])
        checked.add(topic)
    assert checked == set(theirs) - {'/diagnostics'} and len(checked) == 9


def test_a_message_index_that_does_not_hold_is_walked_past(tmp_path):
    reference = read_session(REFERENCE)
    bag = copy_reference(tmp_path / 'index')
    raw = bytearray(mcap_of(bag).read_bytes())
    _, _, end = chunks(REFERENCE)[0]
    # The first message index record after the first chunk: opcode, length, channel, the
    # entries' length, then (log time, offset) pairs. Its first offset, off by one.
    assert raw[end] == 0x07
    raw[end + 9 + 2 + 4 + 8] ^= 0x01
    mcap_of(bag).write_bytes(bytes(raw))
    session = read_session(bag)
    assert session.warning == ''
    assert session.message_counts == reference.message_counts
    for name, values in reference.signals.items():
        np.testing.assert_array_equal(session.signals[name], values, err_msg=name)
    np.testing.assert_array_equal(session.currents.phase_u_a, reference.currents.phase_u_a)


def test_streaming_keeps_no_message():
    taken: list[int] = []
    scan = scan_mcap(next(REFERENCE.glob('*.mcap')),
                     lambda scan, data, channels, *_: taken.append(channels.size))
    assert scan.messages == [] and sum(taken) == sum(scan.counts.values())
    kept = read_recording(REFERENCE)   # without a sink, as repair reads it: every message
    assert sum(len(m) for m in kept.messages.values()) == sum(taken)
