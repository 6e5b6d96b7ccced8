"""servo_daq: a recorded block to the servo/currents message (the conversion on the reference
session's arrays), and the one line a PC without NI's driver or the nidaqmx package gives."""

from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path

import numpy as np

from turning_force.core.plant.daq import DaqConverter, DaqSettings
from turning_force.nodes.convert import stamp_to_ns
from turning_force.nodes.servo_daq import block_message
from turning_force.session.reader import read_session

REFERENCE = Path(__file__).resolve().parents[2] / 'bags' / 'reference' / 'park1998_fig8'
BIN = Path(sys.prefix) / 'bin'


def test_a_recorded_block_becomes_the_message_it_was():
    settings = DaqSettings(hall_scale_a_per_v=5.0, current_u_offset_v=2.5,
                           current_v_offset_v=2.5, angle_input='analog',
                           angle_v_per_rad=1.0, frame_id='z_axis')
    converter = DaqConverter(settings)
    t0_ns = 1_795_000_000_123_000_000   # an epoch stamp: kept to the nanosecond
    for block in read_session(REFERENCE).blocks[:50]:
        message = block_message(converter, t0_ns, block.phase_u_a / 5.0 + 2.5,
                                block.phase_v_a / 5.0 + 2.5, block.rotor_angle_rad)
        assert stamp_to_ns(message.header.stamp) == t0_ns
        assert message.header.frame_id == 'z_axis' and message.sample_period_s == 1e-3
        np.testing.assert_allclose(message.phase_u_a, block.phase_u_a, rtol=0, atol=1e-12)
        np.testing.assert_allclose(message.phase_v_a, block.phase_v_a, rtol=0, atol=1e-12)
        np.testing.assert_allclose(np.mod(message.rotor_angle_rad, 2 * math.pi),
                                   block.rotor_angle_rad, rtol=0, atol=1e-9)
        assert len(message.feed_rate_mm_min) == len(block)
        t0_ns += 10_000_000


def one_line(argv: list[str]) -> tuple[int, str]:
    done = subprocess.run(argv, capture_output=True, text=True, timeout=60)
    return done.returncode, done.stderr


def test_without_nis_driver_it_says_so_in_one_line():
    code, err = one_line([str(BIN / 'servo_daq'), '--ros-args', '-p', 'device:=Dev7'])
    assert code == 2
    assert err.strip().splitlines() == [
        'turning_force: servo_daq: NI-DAQmx (the driver) is not installed on this PC: install '
        'it from NI; the nidaqmx package alone cannot reach a device']


def test_without_the_nidaqmx_package_it_says_so_in_one_line():
    code, err = one_line([sys.executable, '-c',
                          'import sys; sys.modules["nidaqmx"] = None\n'
                          'from turning_force.nodes.servo_daq import main; sys.exit(main())'])
    assert code == 2
    assert err.strip().splitlines() == [
        "turning_force: servo_daq: the nidaqmx package is not installed: pip install "
        "'turning_force[daq]', and NI-DAQmx from NI"]
