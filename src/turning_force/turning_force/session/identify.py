"""``turning-force identify`` and ``calibrate --map``: recorded sessions to the machine's model.

A session becomes a :class:`~turning_force.core.identify.Recording`: the DAQ's blocks (feed
rate, q-axis current from the phase currents), the override the PMC applied during each block
(the ``FeedOverride`` answering the block before; 100 %, the programmed feed, before the first
answer), the recorded force estimate and its status, and the dynamometer's ``force/measured``
where one was recorded. Nothing of the simulator's truth is used: a session from the lathe
identifies the same way. The result is written as a ROS 2 parameters file that the controller
and the estimator load (``turning-force run EXP --params FILE``, or a second
``--params-file`` after the experiment's under ``ros2 run``).
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
from rosbags.highlevel import AnyReader, AnyReaderError
from rosbags.rosbag2 import ReaderError

from turning_force.core.estimation.settings import EstimateStatus
from turning_force.core.identify import (
    Identification,
    IdentifySettings,
    MapCalibration,
    Recording,
    calibrate_map,
    identify,
    program_depths_mm,
)
from turning_force.core.overlay import with_parameters_file
from turning_force.core.plant.drive import clarke_park
from turning_force.core.pmc.overrides import get_table
from turning_force.core.yamlfile import yaml_text
from turning_force.session.bag import BagError, typestore
from turning_force.session.reader import Session, applied_overrides, read_session

__all__ = ['MEASURED_FORCE_TOPIC', 'calibrate_map_sessions', 'cut_depth_mm', 'format_parameters',
           'identify_sessions', 'recording_from_session']

FloatArray = npt.NDArray[np.float64]

MEASURED_FORCE_TOPIC = 'force/measured'


def _measured_messages(path: Path, axis: str) -> Iterator[tuple[float, float]]:
    """(time [s], force [N]) of every dynamometer reading: a WrenchStamped's stamp and
    ``wrench.force.<axis>``, or a Float64 at the time it was recorded."""
    try:
        with AnyReader([path], default_typestore=typestore()) as reader:
            wanted = [c for c in reader.connections
                      if c.topic == MEASURED_FORCE_TOPIC
                      or c.topic.endswith('/' + MEASURED_FORCE_TOPIC)]
            if not wanted:   # (no connections given, rosbags reads them all)
                return
            for connection, log_ns, raw in reader.messages(connections=wanted):
                msg: Any = reader.deserialize(raw, connection.msgtype)
                if connection.msgtype.endswith('WrenchStamped'):
                    stamp = msg.header.stamp
                    yield (int(stamp.sec) + int(stamp.nanosec) * 1e-9,
                           float(getattr(msg.wrench.force, axis)))
                elif connection.msgtype.endswith('Float64'):
                    yield log_ns * 1e-9, float(msg.data)
                else:
                    raise BagError(f'{path}: {connection.topic} is {connection.msgtype}; '
                                   'expected geometry_msgs/WrenchStamped or std_msgs/Float64')
    except (AnyReaderError, ReaderError, OSError) as exc:
        raise BagError(f'{path}: cannot read {MEASURED_FORCE_TOPIC}: {exc}') from exc


def _measured_per_block(session: Session, axis: str) -> FloatArray | None:
    """The dynamometer's mean over each block's span, NaN where it read nothing; None if the
    session has no reading at all."""
    readings = list(_measured_messages(session.path, axis))
    if not readings:
        return None
    times = np.array([t for t, _ in readings])
    values = np.array([v for _, v in readings])
    order = np.argsort(times)
    times, values = times[order], values[order]
    starts, ends = session.block_starts_s, session.t_s
    period = session.blocks[0].sample_period_s
    # Half a sample of slack: a stamp on the block's last sample is inside it.
    first = np.searchsorted(times, starts - 0.5 * period, side='left')
    last = np.searchsorted(times, ends - 0.5 * period, side='left')
    sums = np.concatenate([[0.0], np.cumsum(values)])
    counts = last - first
    out = np.full(starts.size, np.nan)
    have = counts > 0
    out[have] = (sums[last[have]] - sums[first[have]]) / counts[have]
    return out


def _first_level(session: Session) -> float:
    """The level the PMC held until the bridge first answered: the one the feed the DAQ
    measured in the first block implies (the axis approached the work at it; at rest, none), a
    level of the machine's table. A session does not say it otherwise: the PMC's dial, the
    entry feed, an older version's programmed feed."""
    assert session.experiment is not None and session.currents is not None
    e = session.experiment
    feed = float(np.mean(np.abs(session.currents.feed_rate_mm_min[0])))
    if not math.isfinite(feed):   # a corrupt first block: the level the file's approach says
        return e.plant.approach_override_pct
    table = get_table(e.bridge.override_table)
    return table.quantise(100.0 * feed / e.controller.programmed_feed_rate_mm_min)


def recording_from_session(session: Session, axis: str = 'z') -> Recording:
    """What identification reads from a session (see the module's text)."""
    if session.experiment is None:
        raise BagError(f'{session.path}: no recorded parameters or experiment file: the '
                       'programmed feed, spindle speed and current map (Eq. 26) are needed')
    e = session.experiment
    c = session.currents
    if c is None:   # the reader keeps blocks as blocks only where they differ
        lengths = {len(b) for b in session.blocks}
        periods = {b.sample_period_s for b in session.blocks}
        raise BagError(f'{session.path}: blocks of {sorted(lengths)} samples at '
                       f'{sorted(periods)} s: identification needs one block size and rate')
    applied = applied_overrides(session.signals['answered_override_pct'], _first_level(session))
    status = session.signals['estimate_status']
    currents = clarke_park(c.phase_u_a, c.phase_v_a, c.rotor_angle_rad)[1]
    return Recording(
        name=str(session.path),
        sample_period_s=c.sample_period_s,
        programmed_feed_rate_mm_min=e.controller.programmed_feed_rate_mm_min,
        spindle_speed_rpm=e.controller.spindle_speed_rpm,
        current_map=e.estimator.current_map,
        block_start_s=c.t0_s.copy(),
        override_pct=applied,
        estimated_force_n=session.signals['estimated_force_n'],
        saturated=status == int(EstimateStatus.SATURATED),
        feed_rate_mm_min=c.feed_rate_mm_min,
        current_q_a=currents,
        measured_force_n=_measured_per_block(session, axis),
        depth_mm=program_depths_mm(e.plant.depth_profile, c.t0_s, c.feed_rate_mm_min.shape[1],
                                   c.sample_period_s))


def identify_sessions(bags: Sequence[str | Path], settings: IdentifySettings | None = None,
                      prior: Sequence[str | Path] | None = None,
                      ) -> tuple[Identification, list[Session]]:
    """Identify the machine from the sessions in ``bags``. With ``prior`` (parameters files,
    e.g. the earlier commissioning's ``identify`` file; empty: the settings the first session
    ran with), what a production session cannot identify is kept from them (the friction
    curve, without an air move)."""
    sessions = [read_session(bag) for bag in bags]
    friction = None
    if prior is not None and sessions[0].experiment is not None:
        experiment = sessions[0].experiment
        for file in prior:
            experiment = with_parameters_file(experiment, file)
        friction = experiment.estimator.friction
    return identify([recording_from_session(s) for s in sessions], settings,
                    friction), sessions


def calibrate_map_sessions(bags: Sequence[str | Path], axis: str = 'z') -> MapCalibration:
    """Park Eq. 26 from sessions with a dynamometer, each compensated with its recorded
    friction (Eq. 25)."""
    recordings, frictions = [], []
    for bag in bags:
        session = read_session(bag)
        recordings.append(recording_from_session(session, axis))
        assert session.experiment is not None   # recording_from_session checked it
        frictions.append(session.experiment.estimator.friction)
    if len({(f.a_a_per_mm_min2, f.b_a, f.min_feed_mm_min, f.max_feed_mm_min)
            for f in frictions}) > 1:
        raise BagError(f'{", ".join(map(str, bags))}: recorded with different friction '
                       'curves; calibrate them one at a time')
    return calibrate_map(recordings, friction=frictions[0].current_a)


def cut_depth_mm(sessions: Sequence[Session]) -> float | None:
    """The depth of the commissioning cut where the sessions know it (the simulator's truth);
    None for sessions from the machine."""
    depths = [float(np.nanmax(s.signals['depth_mm'])) for s in sessions if s.has_truth]
    return max(depths) if depths else None


def format_parameters(sections: Mapping[str, Mapping[str, Any]], header: Sequence[str]) -> str:
    """A ROS 2 parameters file (``/**/<node>: ros__parameters: ...``) with a comment header."""
    lines = [f'# {line}' if line else '#' for line in header]
    for node, params in sections.items():
        lines += [f'/**/{node}:', '  ros__parameters:' + ('' if params else ' {}')]
        for name, value in params.items():   # numbers to 6 digits
            text = (value if isinstance(value, str) else yaml_text(value)
                    if isinstance(value, bool) else yaml_text(float(f'{float(value):.6g}')))
            lines.append(f'    {name}: {text}')
    return '\n'.join(lines) + '\n'
