"""Sessions that survive kills and cuts: what a killed recorder leaves says what it is, and
``repair`` rebuilds a whole session from every complete chunk of a torn or damaged file."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml
from builtin_interfaces.msg import Time
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from rclpy.node import Node
from rosbags.highlevel import AnyReader
from turning_force_msgs.msg import ServoCurrents

from bagfaults import (
    FIRST_CHUNK_BLOCKS,
    REFERENCE_BLOCKS,
    assert_blocks_equal,
    copy_reference,
    mcap_of,
    random_middle,
    truncate,
)
from turning_force.session.bag import CUSTOM_RECORDING, CUSTOM_REPAIR, BagError, typestore
from turning_force.session.reader import read_session
from turning_force.session.repair import repair


@pytest.mark.parametrize(('fraction', 'blocks'), [(0.99, REFERENCE_BLOCKS),
                                                  (0.50, FIRST_CHUNK_BLOCKS)])
def test_a_cut_file_is_repaired_to_every_complete_chunk(tmp_path, reference, fraction, blocks):
    # The 99 % cut takes the summary and footer only: every block is still there. The 50 %
    # cut ends inside the second chunk: the first one's 593 blocks remain.
    bag = truncate(copy_reference(tmp_path / 'cut'), fraction)
    if blocks < REFERENCE_BLOCKS:
        with pytest.raises(BagError, match=f'{blocks} of {REFERENCE_BLOCKS} blocks read'):
            read_session(bag)
    result = repair(bag)
    assert result.repaired and result.recovered['/servo/currents'] == blocks
    session = read_session(bag)   # no longer an error: a repaired session says what it lacks
    assert_blocks_equal(session.blocks, reference.blocks[:blocks])
    for name, values in reference.signals.items():   # answers decoded as they were recorded
        np.testing.assert_array_equal(session.signals[name], values[:blocks], err_msg=name)
    assert session.warning.startswith(f'{bag}: repaired session: ')
    assert f'servo/currents {blocks} blocks' in session.warning
    info = yaml.safe_load((bag / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    counts = {t['topic_metadata']['name']: t['message_count']
              for t in info['topics_with_message_count']}
    assert counts == result.recovered == session.message_counts
    assert json.loads(info['custom_data'][CUSTOM_REPAIR])['recorded']['/servo/currents'] == 1200
    assert session.custom_data.items() >= reference.custom_data.items()   # the settings kept
    # The rebuilt file is a whole MCAP again, for rosbags and for Foxglove's reader, CRCs on.
    with AnyReader([bag], default_typestore=typestore()) as reader:
        assert sum(c.msgcount for c in reader.connections) == sum(counts.values())
    with mcap_of(bag).open('rb') as stream:
        decoded = list(make_reader(stream, validate_crcs=True, decoder_factories=[
            DecoderFactory()]).iter_decoded_messages(topics=['/servo/currents']))
    assert len(decoded) == blocks
    assert (bag / 'park1998_fig8.mcap.damaged').is_file()
    assert not repair(bag).repaired   # a repaired session needs nothing more




def test_a_killed_recorder_leaves_a_session_that_repair_completes(context, executor,
                                                                   spin_until, tmp_path):
    bag = tmp_path / 'killed'
    namespace = f'/killed_{os.getpid()}'
    recorder = subprocess.Popen(
        [str(Path(sys.prefix) / 'bin' / 'session_recorder'), '--ros-args',
         '-r', f'__ns:={namespace}', '-p', f'output_dir:={bag}'],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        node = Node('killer', context=context)
        executor.add_node(node)
        publisher = node.create_publisher(ServoCurrents, f'{namespace}/servo/currents', 100)
        sent = [0]

        def send() -> None:   # a 10-sample block every 10 ms, stamped as a DAQ would
            k = sent[0]
            msg = ServoCurrents(sample_period_s=1e-3, phase_u_a=[float(k)] * 10,
                                phase_v_a=[0.0] * 10, rotor_angle_rad=[0.0] * 10,
                                feed_rate_mm_min=[100.0] * 10)
            msg.header.stamp = Time(sec=k // 100, nanosec=(k % 100) * 10_000_000)
            publisher.publish(msg)
            sent[0] += 1

        assert spin_until(lambda: publisher.get_subscription_count() > 0, 20.0)
        node.create_timer(0.01, send)                   # 100 blocks a second
        spin_until(lambda: sent[0] >= 300, 30.0)        # three seconds of cutting
    finally:
        recorder.send_signal(signal.SIGKILL)
        recorder.wait(timeout=10)
    # metadata.yaml as written at the start: every topic, the versions, and the mark that
    # its counts are not final.
    info = yaml.safe_load((bag / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    assert f'{namespace}/servo/currents' in {
        t['topic_metadata']['name'] for t in info['topics_with_message_count']}
    assert CUSTOM_RECORDING in info['custom_data']
    with pytest.raises(BagError, match=f'^{bag}: .*the recording was never closed'):
        read_session(bag)
    result = repair(bag)
    assert result.recorded is None   # nothing counted it: the recorder never closed
    session = read_session(bag)
    assert 'from a recording that was never closed' in session.warning
    assert session.wholeness is not None   # what it was, after the repair
    assert (session.wholeness.state, session.wholeness.repaired) == ('killed', True)
    assert f'{bag}: killed: never closed' in session.warning
    # Flushed at least once a second: what is lost is the last second or so (100 blocks), plus
    # the ones still in flight when the kill came. What is there is in order, without a gap.
    first = int(session.blocks[0].phase_u_a[0])
    assert len(session.blocks) >= sent[0] - 150, (len(session.blocks), sent[0])
    assert [int(b.phase_u_a[0]) for b in session.blocks] == list(
        range(first, first + len(session.blocks)))


def test_a_repaired_session_still_says_it_was_damaged(tmp_path):
    bag = random_middle(copy_reference(tmp_path / 'middle'))
    assert repair(bag).repaired
    state = read_session(bag).wholeness
    assert state is not None
    assert (state.state, state.repaired, state.blocks, state.planned) == (
        'damaged', True, FIRST_CHUNK_BLOCKS, 1200)
