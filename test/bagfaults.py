"""Damaged, foreign and odd sessions made from the committed reference session, for the
fault-injection and property tests of test/session and test/cli. Each builder writes a new
session folder and returns it; the reference itself is never touched."""

from __future__ import annotations

import random
import shutil
import signal
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from mcap.reader import make_reader
from rosbags.highlevel import AnyReader
from rosbags.rosbag2 import StoragePlugin, Writer

from turning_force.session.bag import SessionWriter, typestore

REFERENCE = Path(__file__).resolve().parents[1] / 'bags' / 'reference' / 'park1998_fig8'
REFERENCE_BLOCKS = 1200
# The first of the reference's two chunks holds the blocks up to 5.93 s.
FIRST_CHUNK_BLOCKS = 593


def mcap_of(bag: Path) -> Path:
    return next(bag.glob('*.mcap'))


def copy_reference(out: Path) -> Path:
    shutil.copytree(REFERENCE, out)
    return out


def overwrite(bag: Path, offset: int, data: bytes) -> Path:
    raw = bytearray(mcap_of(bag).read_bytes())
    raw[offset:offset + len(data)] = data
    mcap_of(bag).write_bytes(bytes(raw))
    return bag


def truncate(bag: Path, fraction: float) -> Path:
    raw = mcap_of(bag).read_bytes()
    mcap_of(bag).write_bytes(raw[:int(len(raw) * fraction)])
    return bag


def flip(bag: Path, offsets: list[int], mask: int = 0xFF) -> Path:
    raw = bytearray(mcap_of(bag).read_bytes())
    for offset in offsets:
        raw[offset] ^= mask
    mcap_of(bag).write_bytes(bytes(raw))
    return bag


def random_middle(bag: Path, size: int = 4096, seed: int = 0) -> Path:
    """``size`` random bytes over the middle of the file (issue 8's case)."""
    length = mcap_of(bag).stat().st_size
    return overwrite(bag, length // 2, random.Random(seed).randbytes(size))


def chunks(bag: Path) -> list[tuple[int, int, int]]:
    """(record start, compressed data start, compressed data end) of each chunk, from the
    file's summary (read with mcap's seeking reader)."""
    with mcap_of(bag).open('rb') as stream:
        summary = make_reader(stream).get_summary()
    assert summary is not None
    out = []
    for index in summary.chunk_indexes:
        # opcode, length, start and end time, size, CRC, compression name, compressed size
        data = index.chunk_start_offset + 9 + 8 + 8 + 8 + 4 + 4 + len(index.compression) + 8
        out.append((index.chunk_start_offset, data, data + index.compressed_size))
    return out


def custom_data(bag: Path) -> dict[str, str]:
    info = yaml.safe_load((bag / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    return {str(k): str(v) for k, v in (info.get('custom_data') or {}).items()}


def rewrite(bag: Path, out: Path, keep: Callable[[str], bool] = lambda topic: True,
            change: Callable[[str, Any], Any] | None = None) -> Path:
    """The session's messages written again with today's SessionWriter (chunk CRCs
    included), each topic with the message definition it was recorded with: the topics
    ``keep`` keeps, each message through ``change(topic, msg)`` if given (None drops it).
    ``bag`` must be whole: it is read with rosbags."""
    writer = SessionWriter(out)
    for key, value in custom_data(bag).items():
        writer.set_custom_data(key, value)
    with AnyReader([bag], default_typestore=typestore()) as reader:
        store = reader.typestore   # the session's own definitions
        kept = [c for c in reader.connections if keep(c.topic)]
        for connection in kept:
            writer.add_topic(connection.topic, connection.msgtype,
                             (connection.msgdef.data, store.hash_rihs01(connection.msgtype)))
        for connection, timestamp, raw in reader.messages(connections=kept):
            data = bytes(raw)
            if change is not None:
                msg = change(connection.topic, store.deserialize_cdr(data, connection.msgtype))
                if msg is None:
                    continue
                data = bytes(store.serialize_cdr(msg, connection.msgtype))
            writer.write(connection.topic, timestamp, data)
    writer.close()
    return out


def foreign_bag(out: Path) -> Path:
    """A rosbag2 MCAP session of someone else's graph: only ``/chatter`` (std_msgs/String)."""
    store = typestore()
    string = store.types['std_msgs/msg/String']
    with Writer(out, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        chatter = writer.add_connection('/chatter', 'std_msgs/msg/String', typestore=store)
        for k in range(10):
            writer.write(chatter, k * 100_000_000,
                         bytes(store.serialize_cdr(string(data=f'hello {k}'),
                                                   'std_msgs/msg/String')))
    return out


def wrong_type_bag(out: Path) -> Path:
    """The reference's settings, with ``/servo/currents`` carrying std_msgs/Float64."""
    store = typestore()
    value = store.types['std_msgs/msg/Float64']
    writer = SessionWriter(out)
    for key, text in custom_data(REFERENCE).items():
        writer.set_custom_data(key, text)
    writer.add_topic('/servo/currents', 'std_msgs/msg/Float64')
    for k in range(10):
        writer.write('/servo/currents', k * 10_000_000,
                     bytes(store.serialize_cdr(value(data=float(k)), 'std_msgs/msg/Float64')))
    writer.close()
    return out


FIELDS = ('phase_u_a', 'phase_v_a', 'rotor_angle_rad', 'feed_rate_mm_min')


def assert_blocks_equal(blocks, expected):
    """Two lists of current blocks hold the same samples, stamps and periods."""
    assert len(blocks) == len(expected)
    for a, b in zip(blocks, expected, strict=True):
        assert (a.t0_s, a.sample_period_s) == (b.t0_s, b.sample_period_s)
        for name in FIELDS:
            np.testing.assert_array_equal(getattr(a, name), getattr(b, name))


def stopped_by(signum: int) -> Callable[[int, int], None]:
    """A run's progress callback that stops it at its first call, as the command's handler
    of ``signum`` does (``turning-force run`` stops between two steps or batches)."""
    from turning_force.cli import Interrupted

    def stop(done: int, total: int) -> None:
        raise Interrupted(f'interrupted by {signal.Signals(signum).name} after block {done} '
                          f'of {total}', signum)

    return stop
