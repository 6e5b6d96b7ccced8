"""Fault injection on sessions: what a shop does to a bag (damage, cuts, kills, foreign files),
and what reading, repairing and measuring it must then do: a BagError that names the bag and
what is missing, or exactly the data with a warning that says how much is missing; never a
traceback, never silently fewer messages, never NaN metrics."""

from __future__ import annotations

import dataclasses
import math

import pytest
import zstandard
from mcap.stream_reader import CRCValidationError, StreamReader

from bagfaults import (
    FIRST_CHUNK_BLOCKS,
    REFERENCE,
    REFERENCE_BLOCKS,
    assert_blocks_equal,
    chunks,
    copy_reference,
    flip,
    foreign_bag,
    mcap_of,
    random_middle,
    rewrite,
    wrong_type_bag,
)
from turning_force.session.bag import BagError
from turning_force.session.reader import read_session, recorded_metrics


def test_random_bytes_in_the_middle_are_an_error_naming_what_is_missing(tmp_path):
    # Issue 8: 4 KiB of random bytes over the middle of the file replayed 593 of 1200 blocks
    # with no word. They wreck the second of the two chunks.
    bag = random_middle(copy_reference(tmp_path / 'middle'))
    with pytest.raises(BagError) as error:
        read_session(bag)
    message = str(error.value)
    assert message.startswith(f'{bag}: damaged: servo/currents {FIRST_CHUNK_BLOCKS} of '
                              f'{REFERENCE_BLOCKS} blocks read')
    assert f'chunk at byte {chunks(REFERENCE)[1][0]}' in message
    assert '\n' not in message


def test_partial_reads_what_is_there_and_says_how_much_is_missing(tmp_path, reference):
    bag = random_middle(copy_reference(tmp_path / 'middle'))
    session = read_session(bag, partial=True)
    assert_blocks_equal(session.blocks, reference.blocks[:FIRST_CHUNK_BLOCKS])
    assert session.warning.startswith(f'partial session: {bag}: damaged: servo/currents '
                                      f'{FIRST_CHUNK_BLOCKS} of {REFERENCE_BLOCKS} blocks read')
    assert '4888 of 9663 recorded messages missing' in session.warning


def test_a_changed_byte_in_a_written_chunk_is_found_by_its_crc(tmp_path):
    # zstd keeps no checksum here: most bytes changed in a chunk's compressed data decode to
    # other values of the same size. The CRC-32 our writer puts on each chunk finds them.
    bag = rewrite(REFERENCE, tmp_path / 'today')
    raw = bytearray(mcap_of(bag).read_bytes())
    start, data, end = chunks(bag)[0]
    payload = bytes(raw[data:end])
    silent = next(k for k in range(len(payload) // 2, len(payload))
                  if _decodes_to_other_bytes(payload, k))
    raw[data + silent] ^= 0x01
    mcap_of(bag).write_bytes(bytes(raw))
    with pytest.raises(BagError, match=f'chunk at byte {start} .*CRC-32 of its records'):
        read_session(bag)
    with mcap_of(bag).open('rb') as stream, pytest.raises(CRCValidationError):
        for _ in StreamReader(stream, validate_crcs=True).records:
            pass


def _decodes_to_other_bytes(payload: bytes, k: int) -> bool:
    changed = bytearray(payload)
    changed[k] ^= 0x01
    try:
        out = zstandard.ZstdDecompressor().decompress(bytes(changed))
    except zstandard.ZstdError:
        return False
    return len(out) == len(zstandard.ZstdDecompressor().decompress(payload)) and \
        out != zstandard.ZstdDecompressor().decompress(payload)


@pytest.mark.parametrize('offset', [13, 16])
def test_a_damaged_record_length_loses_nothing_and_says_so(tmp_path, reference, offset):
    # The header record's length, its high bytes flipped: rosbags tried to allocate (a
    # MemoryError) or to seek (an OverflowError) past any file. The chunks are intact.
    bag = flip(copy_reference(tmp_path / 'flipped'), [offset])
    session = read_session(bag)
    assert_blocks_equal(session.blocks, reference.blocks)
    assert session.warning.startswith(f'{bag}: park1998_fig8.mcap is damaged (')
    assert 'every recorded message was read' in session.warning


def test_a_corrupt_zstd_chunk_is_an_error_naming_the_chunk(tmp_path):
    # Bytes early in the first chunk's zstd frame: the frame no longer decodes (ZstdError).
    start, data, _ = chunks(REFERENCE)[0]
    bag = flip(copy_reference(tmp_path / 'zstd'), [data + 50, data + 51])
    with pytest.raises(BagError, match=rf'^{bag}: damaged: servo/currents 607 of 1200 blocks '
                                       r'read.*'
                                       rf'chunk at byte {start} \(\d+ bytes\): '):
        read_session(bag)


def test_a_foreign_bag_is_named_as_such(tmp_path):
    bag = foreign_bag(tmp_path / 'chatter')
    with pytest.raises(BagError, match=rf'^{bag}: no servo/currents topic \(/chatter\): not a '
                                       'turning_force session$'):
        read_session(bag)


def test_servo_currents_of_another_type_is_named(tmp_path):
    bag = wrong_type_bag(tmp_path / 'float')
    with pytest.raises(BagError, match=f'^{bag}: /servo/currents is std_msgs/msg/Float64, not '
                                       'turning_force_msgs/msg/ServoCurrents'):
        read_session(bag)


def test_a_session_with_only_currents_says_what_the_metrics_lack(tmp_path):
    bag = rewrite(REFERENCE, tmp_path / 'currents', keep=lambda t: t == '/servo/currents')
    session = read_session(bag)
    assert len(session.blocks) == REFERENCE_BLOCKS
    with pytest.raises(BagError, match='no force/estimate and no sim/cutting_state in the '
                                       'session: no force to measure'):
        recorded_metrics(session)


# 2026-11-19 07:33:20 UTC: a wall-clock session is stamped in epoch time.
EPOCH_S = 1_795_000_000


def test_a_wall_clock_session_has_real_metrics(tmp_path, reference):
    # The simulator run in real time: stamps in epoch time from its start, and (as when the
    # recorder is stopped between the currents of the last block and the simulator's state
    # for it) one block without an answer. That block made every mean NaN, and the depth
    # changes were looked for at 4 s and 8 s after 1970.
    last = int(reference.answer_stamps_ns[-1])

    def wall_clock(topic, msg):
        if topic == '/sim/cutting_state' and _ns(msg.header.stamp) == last:
            return None
        if not hasattr(msg, 'header'):
            return msg
        stamp = dataclasses.replace(msg.header.stamp, sec=msg.header.stamp.sec + EPOCH_S)
        return dataclasses.replace(msg, header=dataclasses.replace(msg.header, stamp=stamp))

    bag = rewrite(REFERENCE, tmp_path / 'wall', change=wall_clock)
    session = read_session(bag)
    assert session.t_s[0] == pytest.approx(EPOCH_S + 0.01, abs=1e-6)
    assert math.isnan(session.signals['force_n'][-1])
    metrics = recorded_metrics(session)
    expected = recorded_metrics(reference)
    assert all(math.isfinite(v) for v in metrics.values()), metrics
    # One block of 1200 left out, and the settle windows found from the recorded depth: the
    # same figures to a few hundredths of a newton (the last block's error is a few N, in a
    # mean over about 900 samples), the same settling time to a sample.
    for name in ('mean_abs_error_n', 'steady_mean_abs_error_n', 'max_abs_error_n',
                 'overshoot_n', 'ripple_p2p_n'):
        assert metrics[name] == pytest.approx(expected[name], abs=0.05), name
    assert metrics['settling_time_s'] == pytest.approx(expected['settling_time_s'], abs=0.011)


def _ns(stamp):
    return stamp.sec * 1_000_000_000 + stamp.nanosec
