"""The DAQ's raw samples to feed-drive currents (core/daq.py), on the reference session's arrays:
Hall-sensor volts and encoder counts made from the recorded currents and rotor angle convert
back to them, within what a count and the differencing window allow."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from turning_force.core.plant.daq import DaqConverter, DaqSettings
from turning_force.session.reader import read_session

REFERENCE = Path(__file__).resolve().parents[2] / 'bags' / 'reference' / 'park1998_fig8'
SCALE_A_PER_V, U_OFFSET_V, V_OFFSET_V = 10.0, 0.1, -0.05
COUNTS_PER_REV, POLE_PAIRS, PITCH_MM, WINDOW = 10000, 4, 12.0, 10


@pytest.fixture(scope='module')
def recorded():
    """The reference session's blocks, and their samples end to end."""
    blocks = read_session(REFERENCE).blocks
    joined = {name: np.concatenate([getattr(b, name) for b in blocks])
              for name in ('phase_u_a', 'phase_v_a', 'rotor_angle_rad', 'feed_rate_mm_min')}
    return blocks, joined


def settings(**changes) -> DaqSettings:
    return DaqSettings().replace(
        hall_scale_a_per_v=SCALE_A_PER_V, current_u_offset_v=U_OFFSET_V,
        current_v_offset_v=V_OFFSET_V, encoder_counts_per_rev=COUNTS_PER_REV,
        pole_pairs=POLE_PAIRS, ball_screw_pitch_mm=PITCH_MM, feed_rate_window=WINDOW,
        **changes)


def raw_samples(joined):
    """What the DAQ would have read: sensor volts and encoder counts (the motor's position;
    an offset of whole electrical periods, so count 0 is at electrical angle 0)."""
    u_volts = joined['phase_u_a'] / SCALE_A_PER_V + U_OFFSET_V
    v_volts = joined['phase_v_a'] / SCALE_A_PER_V + V_OFFSET_V
    revs = np.unwrap(joined['rotor_angle_rad']) / (2.0 * math.pi * POLE_PAIRS)
    counts = np.round(revs * COUNTS_PER_REV) + 37 * COUNTS_PER_REV // POLE_PAIRS
    return u_volts, v_volts, counts


def convert_blocks(converter, blocks, *columns):
    out, start = [], 0
    for block in blocks:
        n = len(block)
        out.append(converter.convert(block.t0_s, *(c[start:start + n] for c in columns)))
        start += n
    return out


def angle_error(a, b):
    return np.abs(np.angle(np.exp(1j * (np.asarray(a) - np.asarray(b)))))


def test_encoder_blocks_give_back_the_recorded_currents_angle_and_feed(recorded):
    blocks, joined = recorded
    converted = convert_blocks(DaqConverter(settings()), blocks, *raw_samples(joined))
    assert [c.t0_s for c in converted] == [b.t0_s for b in blocks]
    assert all(c.sample_period_s == 1e-3 for c in converted)
    got = {name: np.concatenate([getattr(c, name) for c in converted]) for name in joined}
    # Currents: volts and back, exact to float rounding.
    np.testing.assert_allclose(got['phase_u_a'], joined['phase_u_a'], rtol=0, atol=1e-12)
    np.testing.assert_allclose(got['phase_v_a'], joined['phase_v_a'], rtol=0, atol=1e-12)
    # Angle: within half a count of electrical angle, 2 pi pole_pairs / counts / 2.
    half_count_rad = math.pi * POLE_PAIRS / COUNTS_PER_REV
    assert angle_error(got['rotor_angle_rad'], joined['rotor_angle_rad']).max() <= (
        half_count_rad + 1e-12)
    # Feed: the position difference over WINDOW samples is the mean feed over the window; it
    # differs from the instant's feed by at most max|acceleration| * W T / 2, and the counts'
    # rounding adds at most one count over the window: pitch / counts / (W T) * 60 mm/min.
    period = 1e-3
    feed = joined['feed_rate_mm_min']
    max_accel = np.abs(np.diff(feed)).max() / period                     # mm/min per s
    bound = max_accel * WINDOW * period / 2 + PITCH_MM / COUNTS_PER_REV / (WINDOW * period) * 60
    error = np.abs(got['feed_rate_mm_min'] - feed)[WINDOW:]   # the first window is short
    assert error.max() <= bound
    assert np.mean(got['feed_rate_mm_min'][WINDOW:]) == pytest.approx(np.mean(feed[WINDOW:]),
                                                                      rel=1e-3)


def test_blocks_convert_as_one_long_block(recorded):
    # The window reaches into the previous block: cutting the stream into blocks changes
    # nothing.
    blocks, joined = recorded
    raw = raw_samples(joined)
    per_block = convert_blocks(DaqConverter(settings()), blocks, *raw)
    whole = DaqConverter(settings()).convert(0.0, *raw)
    np.testing.assert_array_equal(np.concatenate([b.feed_rate_mm_min for b in per_block]),
                                  whole.feed_rate_mm_min)
    np.testing.assert_array_equal(np.concatenate([b.rotor_angle_rad for b in per_block]),
                                  whole.rotor_angle_rad)


def test_an_analog_angle_is_unwrapped_across_blocks(recorded):
    blocks, joined = recorded
    volts_per_rad = 10.0 / (2.0 * math.pi)
    u_volts, v_volts, _ = raw_samples(joined)
    converter = DaqConverter(settings(angle_input='analog', angle_v_per_rad=volts_per_rad))
    converted = convert_blocks(converter, blocks, u_volts, v_volts,
                               joined['rotor_angle_rad'] * volts_per_rad)
    angle = np.concatenate([c.rotor_angle_rad for c in converted])
    assert angle_error(angle, joined['rotor_angle_rad']).max() < 1e-9
    feed = np.concatenate([c.feed_rate_mm_min for c in converted])
    # No counts to round: only the window's lag.
    max_accel = np.abs(np.diff(joined['feed_rate_mm_min'])).max() / 1e-3
    assert np.abs(feed - joined['feed_rate_mm_min'])[WINDOW:].max() <= (
        max_accel * WINDOW * 1e-3 / 2)


def test_a_block_with_unequal_channels_is_refused():
    with pytest.raises(ValueError, match='10 u, 10 v and 9 angle samples'):
        DaqConverter(settings()).convert(0.0, np.zeros(10), np.zeros(10), np.zeros(9))
