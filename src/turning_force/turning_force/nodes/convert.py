"""Message <-> core conversion, in one place (the core never sees a message or a ``Time``).

The ``*_to_msg`` functions fill a message given to them (``out``), so that a node publishing
once per control period reuses one message object instead of building one (and its header and
stamp) each time: rclpy serialises a message when it is published, so the next period may
overwrite it.
"""

from __future__ import annotations

import array
import dataclasses
import math

import numpy as np
import numpy.typing as npt
from builtin_interfaces.msg import Time as TimeMsg
from turning_force_msgs.msg import CutRecord as CutRecordMsg
from turning_force_msgs.msg import ForceEstimate as ForceEstimateMsg
from turning_force_msgs.msg import MachineInputs, ServoCurrents

from turning_force.core.estimation.settings import EstimateStatus, ForceEstimate
from turning_force.core.plant.drive import CurrentBlock
from turning_force.core.pmc.shopfloor import CutRecord, InputValues

__all__ = ['block_to_servo_currents', 'cut_to_msg', 'estimate_from_msg', 'estimate_to_msg',
           'from_tristate', 'inputs_from_msg', 'inputs_to_msg', 'last_sample_ns', 'ns_to_stamp',
           'seconds_to_stamp', 'servo_currents_to_block', 'set_stamp', 'stamp_to_ns',
           'stamp_to_seconds', 'tristate']

FloatArray = npt.NDArray[np.float64]


def stamp_to_seconds(stamp: TimeMsg) -> float:
    return float(stamp.sec + stamp.nanosec * 1e-9)


def seconds_to_stamp(seconds: float) -> TimeMsg:
    return ns_to_stamp(round(seconds * 1e9))


def stamp_to_ns(stamp: TimeMsg) -> int:
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


def ns_to_stamp(nanoseconds: int) -> TimeMsg:
    return TimeMsg(sec=nanoseconds // 1_000_000_000, nanosec=nanoseconds % 1_000_000_000)


def set_stamp(stamp: TimeMsg, nanoseconds: int) -> None:
    """Set ``stamp`` in place to ``nanoseconds`` (no new message)."""
    stamp.sec, stamp.nanosec = divmod(nanoseconds, 1_000_000_000)


def _doubles(values: FloatArray) -> array.array[float]:
    """A float64 array as the messages hold it (array.array 'd'), copied as bytes, not
    element by element."""
    return array.array('d', np.ascontiguousarray(values, dtype=np.float64).tobytes())


def last_sample_ns(msg: ServoCurrents) -> int:
    """Time of a block's last sample, in integer nanoseconds: the stamp of everything that
    answers the block (estimate, command, override). Integer, so that it is exact at any epoch
    (float seconds near 1.8e9 s resolve only 0.24 us)."""
    period_ns = round((len(msg.phase_u_a) - 1) * float(msg.sample_period_s) * 1e9)
    return stamp_to_ns(msg.header.stamp) + period_ns


def servo_currents_to_block(msg: ServoCurrents) -> CurrentBlock:
    return CurrentBlock(
        t0_s=stamp_to_seconds(msg.header.stamp),
        sample_period_s=msg.sample_period_s,
        phase_u_a=np.asarray(msg.phase_u_a, dtype=float),
        phase_v_a=np.asarray(msg.phase_v_a, dtype=float),
        rotor_angle_rad=np.asarray(msg.rotor_angle_rad, dtype=float),
        feed_rate_mm_min=np.asarray(msg.feed_rate_mm_min, dtype=float),
    )


def block_to_servo_currents(block: CurrentBlock, frame_id: str = '',
                            out: ServoCurrents | None = None) -> ServoCurrents:
    msg = ServoCurrents() if out is None else out
    set_stamp(msg.header.stamp, round(block.t0_s * 1e9))
    msg.header.frame_id = frame_id
    msg.sample_period_s = float(block.sample_period_s)
    msg.phase_u_a = _doubles(block.phase_u_a)
    msg.phase_v_a = _doubles(block.phase_v_a)
    msg.rotor_angle_rad = _doubles(block.rotor_angle_rad)
    msg.feed_rate_mm_min = _doubles(block.feed_rate_mm_min)
    return msg


def estimate_to_msg(estimate: ForceEstimate,
                    out: ForceEstimateMsg | None = None) -> ForceEstimateMsg:
    msg = ForceEstimateMsg() if out is None else out
    set_stamp(msg.header.stamp, round(estimate.t_s * 1e9))
    msg.force_n = estimate.force_n
    msg.force_rate_n_s = estimate.force_rate_n_s
    msg.current_q_a = estimate.current_q_a
    msg.friction_current_a = estimate.friction_current_a
    msg.status = int(estimate.status)
    msg.detail = estimate.detail
    msg.feed_rate_mm_min = estimate.feed_rate_mm_min
    return msg


def estimate_from_msg(msg: ForceEstimateMsg) -> ForceEstimate:
    """The core's estimate from a message; an unknown status is taken as invalid input."""
    try:
        status = EstimateStatus(msg.status)
    except ValueError:
        status = EstimateStatus.INVALID_INPUT
    return ForceEstimate(stamp_to_seconds(msg.header.stamp), msg.force_n, msg.force_rate_n_s,
                         msg.current_q_a, msg.friction_current_a, status, msg.detail,
                         msg.feed_rate_mm_min)


def tristate(value: bool | None) -> int:
    """An optional input as the messages carry it: 1 set, 0 clear, -1 not wired."""
    return MachineInputs.NOT_WIRED if value is None else int(value)


def from_tristate(value: int) -> bool | None:
    return None if value < 0 else bool(value)


def inputs_to_msg(inputs: InputValues, out: MachineInputs | None = None) -> MachineInputs:
    """The inputs into ``out``: a MachineInputs, or a FeedOverride (which carries the inputs
    its decision saw in the same fields)."""
    dial = inputs.operator_dial_pct
    msg = MachineInputs() if out is None else out
    msg.program_enable = tristate(inputs.program_enable)
    msg.threading = tristate(inputs.threading)
    msg.operator_dial_pct = math.nan if dial is None else float(dial)
    return msg


def inputs_from_msg(msg: MachineInputs) -> InputValues:
    dial = float(msg.operator_dial_pct)
    return InputValues(from_tristate(msg.program_enable), from_tristate(msg.threading),
                       dial if math.isfinite(dial) else None)


def cut_to_msg(record: CutRecord) -> CutRecordMsg:
    msg = CutRecordMsg(**dataclasses.asdict(record), duration_s=record.duration_s)
    msg.header.stamp = seconds_to_stamp(record.end_s)
    return msg
