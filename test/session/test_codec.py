"""The array-level CDR codec against rosbags' own: every message type a session holds, messages
drawn at random (strings and sequences of any length, so that one batch holds several layouts),
decoded as columns equal to what rosbags' deserialize_cdr gives, and encoded to the bytes its
serialize_cdr gives; a session's older definition decodes with its own layout; damaged messages
are left out, never misread."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from rosbags.interfaces import Nodetype

from turning_force.session import codec
from turning_force.session.bag import typestore
from turning_force.session.reader import session_typestore

OURS = ['turning_force_msgs/msg/ServoCurrents', 'turning_force_msgs/msg/ForceEstimate',
        'turning_force_msgs/msg/FeedCommand', 'turning_force_msgs/msg/FeedOverride',
        'turning_force_msgs/msg/CuttingState', 'turning_force_msgs/msg/MachineInputs',
        'turning_force_msgs/msg/CutRecord']
STD = ['sensor_msgs/msg/JointState', 'rosgraph_msgs/msg/Clock', 'std_msgs/msg/Float64',
       'geometry_msgs/msg/WrenchStamped']
SETTINGS = settings(max_examples=25, derandomize=True, deadline=None,
                    suppress_health_check=[HealthCheck.too_slow])

INTS = {'int8': (-128, 127), 'uint8': (0, 255), 'byte': (0, 255), 'char': (0, 255),
        'int16': (-2**15, 2**15 - 1), 'uint16': (0, 2**16 - 1), 'int32': (-2**31, 2**31 - 1),
        'uint32': (0, 2**32 - 1), 'int64': (-2**63, 2**63 - 1), 'uint64': (0, 2**64 - 1)}
TEXT = st.text(st.characters(codec='utf-8', exclude_characters='\x00'), max_size=12)


def primitive(base: str) -> st.SearchStrategy[Any]:
    if base == 'bool':
        return st.booleans()
    if base in INTS:
        return st.integers(*INTS[base])
    if base == 'float32':
        return st.floats(width=32, allow_nan=False)
    return st.floats(allow_nan=True)


def message(store: Any, msgtype: str, draw: Any) -> Any:
    """A message of ``msgtype`` with every field drawn."""
    msgdef = store.get_msgdef(msgtype)
    values = []
    for _, (kind, detail) in msgdef.fields:
        if kind == Nodetype.NAME:
            values.append(message(store, detail, draw))
        elif kind == Nodetype.BASE:
            values.append(draw(TEXT) if detail[0] == 'string' else draw(primitive(detail[0])))
        else:
            (_, (base, _)), length = detail
            n = length if kind == Nodetype.ARRAY else draw(st.integers(0, 4))
            if base == 'string':
                values.append([draw(TEXT) for _ in range(n)])
            else:
                items = [draw(primitive(base)) for _ in range(n)]
                dtype = codec.Field('', 'value', base).dtype
                values.append(np.array(items, dtype=dtype))
    return msgdef.cls(*values)


def leaf_value(msg: Any, path: str) -> Any:
    for part in path.split('.'):
        msg = getattr(msg, part)
    return msg


def same(a: Any, b: Any) -> bool:
    a, b = np.asarray(a), np.asarray(b)
    if a.dtype.kind == 'f' or b.dtype.kind == 'f':
        return a.shape == b.shape and np.array_equal(a.astype(float), b.astype(float),
                                                     equal_nan=True)
    return a.shape == b.shape and np.array_equal(a, b)


def decode_all(store: Any, msgtype: str, raws: list[bytes], pad: int = 0
               ) -> tuple[codec.Table, np.ndarray]:
    """Decode ``raws`` laid one after the other with ``pad`` bytes of other records between."""
    gap = b'\xee' * pad
    data = np.frombuffer(gap.join(raws) if raws else b'', dtype=np.uint8)
    sizes = np.array([len(r) for r in raws], dtype=np.int64)
    offsets = np.concatenate([[0], np.cumsum(sizes + pad)[:-1]]).astype(np.int64) \
        if raws else np.zeros(0, np.int64)
    return codec.decode(store, msgtype, data, offsets, sizes)


def check_table(store: Any, msgtype: str, table: codec.Table, msgs: list[Any]) -> None:
    assert table.count == len(msgs)
    starts: dict[str, int] = {}
    for k, msg in enumerate(msgs):
        for leaf in codec.fields(store, msgtype):
            expected = leaf_value(msg, leaf.path)
            column = table.columns[leaf.path]
            if leaf.kind == 'string':
                assert table.text(leaf.path, k) == expected, leaf.path
            elif leaf.kind in ('sequence', 'strings'):
                n = int(table.lengths[leaf.path][k])
                at = starts.get(leaf.path, 0)
                got = column[at:at + n]
                starts[leaf.path] = at + n
                if leaf.kind == 'strings':
                    assert [bytes(g).decode() for g in got] == list(expected), leaf.path
                else:
                    assert same(got, expected), leaf.path
            else:
                assert same(column[k], expected), leaf.path


@pytest.mark.parametrize('msgtype', OURS + STD)
def test_every_recorded_type_takes_the_array_path(msgtype):
    assert codec.supports(typestore(), msgtype)


def test_types_with_nested_sequences_go_to_rosbags():
    assert not codec.supports(typestore(), 'diagnostic_msgs/msg/DiagnosticArray')


@SETTINGS
@given(msgtype=st.sampled_from(OURS + STD), data=st.data(), pad=st.sampled_from([0, 3, 31]))
def test_decode_and_encode_agree_with_rosbags(msgtype, data, pad):
    store = typestore()
    msgs = [message(store, msgtype, data.draw) for _ in range(data.draw(st.integers(0, 6)))]
    # Repeats: the same layout several times, read through one view.
    msgs += msgs[:2] * 3
    raws = [bytes(store.serialize_cdr(m, msgtype)) for m in msgs]
    table, index = decode_all(store, msgtype, raws, pad)
    np.testing.assert_array_equal(index, np.arange(len(msgs)))
    check_table(store, msgtype, table, [store.deserialize_cdr(r, msgtype) for r in raws])
    columns: dict[str, Any] = dict(table.columns)
    columns.update({p: (table.columns[p], table.lengths[p]) for p in table.lengths})
    encoded, offsets = codec.encode(store, msgtype, columns, table.count)
    assert [encoded[offsets[k]:offsets[k + 1]] for k in range(len(raws))] == raws


def test_a_batch_of_blocks_encodes_from_two_dimensional_arrays():
    store = typestore()
    n, m = 5, 10
    samples = np.arange(n * m, dtype=float).reshape(n, m)
    encoded, offsets = codec.encode(store, 'turning_force_msgs/msg/ServoCurrents', {
        'header.stamp.sec': np.arange(n), 'header.stamp.nanosec': np.full(n, 7),
        'header.frame_id': 'z_axis', 'sample_period_s': 1e-3, 'phase_u_a': samples,
        'phase_v_a': -samples, 'rotor_angle_rad': samples * 2, 'feed_rate_mm_min': samples + 1,
    }, n)
    for k in range(n):
        msg = store.deserialize_cdr(encoded[offsets[k]:offsets[k + 1]],
                                    'turning_force_msgs/msg/ServoCurrents')
        assert (msg.header.stamp.sec, msg.header.stamp.nanosec) == (k, 7)
        assert msg.header.frame_id == 'z_axis'
        np.testing.assert_array_equal(msg.phase_v_a, -samples[k])
        np.testing.assert_array_equal(msg.feed_rate_mm_min, samples[k] + 1)


def test_padding_after_a_message_is_read_as_rosbags_reads_it():
    # rmw's CDR ends a message on a 4-byte boundary; rosbags accepts up to 3 bytes after it.
    store = typestore()
    msgtype = 'turning_force_msgs/msg/ForceEstimate'
    msg = store.get_msgdef(msgtype).cls(
        store.get_msgdef('std_msgs/msg/Header').cls(
            store.get_msgdef('builtin_interfaces/msg/Time').cls(3, 4), 'z'),
        1.0, 2.0, 3.0, 4.0, 0, 'ok', 5.0)
    raw = bytes(store.serialize_cdr(msg, msgtype))
    padded = raw + b'\x00' * (-len(raw) % 4)
    table, index = decode_all(store, msgtype, [padded, padded, raw + b'\x00' * 8])
    assert index.tolist() == [0, 1]   # 8 bytes after it: not the message's
    assert table.columns['force_n'].tolist() == [1.0, 1.0]
    assert table.text('detail', 1) == 'ok'
    assert table.columns['feed_rate_mm_min'].tolist() == [5.0, 5.0]


def test_an_older_definition_decodes_with_its_own_layout():
    # ServoCurrents before the feed rate was recorded: its sessions carry this definition.
    older = ('turning_force_msgs/msg/ServoCurrents', 'ros2msg',
             'std_msgs/Header header\nfloat64 sample_period_s\nfloat64[] phase_u_a\n'
             'float64[] phase_v_a\nfloat64[] rotor_angle_rad\n')
    store = session_typestore((older,))
    msgtype = older[0]
    header = store.get_msgdef('std_msgs/msg/Header').cls(
        store.get_msgdef('builtin_interfaces/msg/Time').cls(1, 2), 'z_axis')
    msg = store.get_msgdef(msgtype).cls(header, 1e-3, np.ones(3), np.zeros(3), np.arange(3.0))
    raws = [bytes(store.serialize_cdr(msg, msgtype))] * 4
    table, _ = decode_all(store, msgtype, raws)
    assert 'feed_rate_mm_min' not in table.columns
    np.testing.assert_array_equal(table.rows('rotor_angle_rad'), np.tile(np.arange(3.0), (4, 1)))


def test_a_damaged_message_is_left_out_and_its_neighbours_read():
    store = typestore()
    msgtype = 'turning_force_msgs/msg/ServoCurrents'
    header = store.get_msgdef('std_msgs/msg/Header').cls(
        store.get_msgdef('builtin_interfaces/msg/Time').cls(1, 2), 'z_axis')
    raws = []
    for k in range(6):
        msg = store.get_msgdef(msgtype).cls(header, 1e-3, *(np.full(10, float(k))
                                                             for _ in range(4)))
        raws.append(bytes(store.serialize_cdr(msg, msgtype)))
    broken = bytearray(raws[2])
    broken[4 + 8] = 0xff   # the frame_id's length: past the end of the message
    raws[2] = bytes(broken)
    shifted = bytearray(raws[4])
    shifted[4 + 32] = 9     # phase_u_a's count: 9 of 10, the rest no longer adds up
    raws[4] = bytes(shifted)
    table, index = decode_all(store, msgtype, raws)
    assert index.tolist() == [0, 1, 3, 5]
    assert table.rows('phase_u_a')[:, 0].tolist() == [0.0, 1.0, 3.0, 5.0]


def test_the_table_builder_grows_and_keeps_the_order():
    store = typestore()
    msgtype = 'sensor_msgs/msg/JointState'
    leaves = codec.fields(store, msgtype)
    builder = codec.TableBuilder(leaves, msgtype, expected=2)
    expected = []
    for k in range(7):
        n = k % 3
        columns = {'header.frame_id': 'z' * k, 'name': np.array([[b'ab'] * n]),
                   'position': np.full((1, n), float(k))}
        raw, _ = codec.encode(store, msgtype, columns, 1)
        expected.append(store.deserialize_cdr(raw, msgtype))
        table, _ = decode_all(store, msgtype, [raw])
        builder.append(table)
    check_table(store, msgtype, builder.finish(), expected)
    assert builder.count == 7


def test_decode_gives_the_fields_asked_for():
    store = typestore()
    msgtype = 'turning_force_msgs/msg/FeedOverride'
    raws = []
    for k in range(3):
        columns = {'applied_pct': 10.0 * k, 'detail': 'x' * k, 'pmc_bits': np.ones((1, 4), bool)}
        raw, _ = codec.encode(store, msgtype, columns, 1)
        raws.append(raw)
    data = np.frombuffer(b''.join(raws), dtype=np.uint8)
    sizes = np.array([len(r) for r in raws])
    table, index = codec.decode(store, msgtype, data,
                                np.concatenate([[0], np.cumsum(sizes)[:-1]]), sizes,
                                keep=['applied_pct', 'reason'])
    assert index.tolist() == [0, 1, 2]
    assert set(table.columns) == {'applied_pct', 'reason'}
    assert table.columns['applied_pct'].tolist() == [0.0, 10.0, 20.0]
