"""``servo_daq``: the feed drive's currents from an NI-DAQ, published as ``servo/currents``.

On the machine PC the DAQ stands where ``lathe_sim`` stands on a desk: two analog inputs take
the u and v phase currents from Hall-effect sensors (Park 1998, Sec. 3), and a counter the motor
encoder (or a third analog input an angle output of the drive), all on one hardware sample
clock. Blocks of ``samples_per_block`` samples are read in a thread of their own and published
as turning_force_msgs/ServoCurrents, stamped with the time of their first sample by the
hardware's clock. The arithmetic is :class:`turning_force.core.plant.daq.DaqConverter`; parameters:
:class:`turning_force.core.plant.daq.DaqSettings`. Through NI's ``nidaqmx`` package (``pip install
'turning_force[daq]'``) and NI-DAQmx driver; where either is missing the node stops at start
with one line saying which.
"""

from __future__ import annotations

import contextlib
import sys
import threading
from typing import Any

import numpy as np
import numpy.typing as npt
from rclpy.node import Node
from turning_force_msgs.msg import ServoCurrents

from turning_force.core.errors import TurningForceError
from turning_force.core.plant.daq import DaqConverter, DaqSettings
from turning_force.core.plant.drive import CurrentBlock
from turning_force.nodes.convert import block_to_servo_currents, ns_to_stamp
from turning_force.nodes.diagnostics import Diagnostics
from turning_force.nodes.parameters import SettingsParameters
from turning_force.nodes.spin import STREAM_DEPTH, node_main

__all__ = ['DaqError', 'NiDaq', 'ServoDaqNode', 'block_message', 'main']

# How long a read may wait beyond one block's duration before the DAQ is declared stalled [s].
READ_MARGIN_S = 1.0


class DaqError(TurningForceError):
    """The DAQ cannot be opened or read (driver or package absent, device missing, overrun)."""


def block_message(converter: DaqConverter, t0_ns: int, u_volts: npt.ArrayLike,
                  v_volts: npt.ArrayLike, angle_samples: npt.ArrayLike) -> ServoCurrents:
    """One DAQ block as the ``servo/currents`` message, its first sample at ``t0_ns`` [ns]
    (pure: no driver, no node)."""
    block: CurrentBlock = converter.convert(t0_ns * 1e-9, u_volts, v_volts, angle_samples)
    message = block_to_servo_currents(block, converter.settings.frame_id)
    message.header.stamp = ns_to_stamp(t0_ns)   # integer: exact at any epoch
    return message


def _nidaqmx() -> Any:
    try:
        import nidaqmx
    except ImportError as exc:
        raise DaqError('servo_daq: the nidaqmx package is not installed: pip install '
                       "'turning_force[daq]', and NI-DAQmx from NI") from exc
    return nidaqmx


class NiDaq:
    """The NI-DAQmx tasks: u, v (and an analog angle) on the AI sample clock, the encoder
    counter clocked by it. ``read()`` blocks for one block of samples."""

    def __init__(self, settings: DaqSettings) -> None:
        nidaqmx = _nidaqmx()
        from nidaqmx.constants import AcquisitionType, AngleUnits, EncoderType

        self.settings = s = settings
        self._errors = nidaqmx.errors
        self._tasks: list[Any] = []
        buffer = max(10 * s.samples_per_block, int(s.sample_rate_hz))
        try:
            ai = nidaqmx.Task()
            self._tasks.append(ai)
            channels = [s.current_u_channel, s.current_v_channel]
            if s.angle_input == 'analog':
                channels.append(s.angle_channel)
            for channel in channels:
                ai.ai_channels.add_ai_voltage_chan(f'{s.device}/{channel}',
                                                   min_val=-s.input_range_v,
                                                   max_val=s.input_range_v)
            ai.timing.cfg_samp_clk_timing(s.sample_rate_hz,
                                          sample_mode=AcquisitionType.CONTINUOUS,
                                          samps_per_chan=buffer)
            self._ai = ai
            self._ci = None
            if s.angle_input == 'encoder':
                ci = nidaqmx.Task()
                self._tasks.append(ci)
                ci.ci_channels.add_ci_ang_encoder_chan(
                    f'{s.device}/{s.encoder_counter}', decoding_type=EncoderType.X_4,
                    units=AngleUnits.TICKS, pulses_per_rev=max(s.encoder_counts_per_rev // 4, 1))
                ci.timing.cfg_samp_clk_timing(s.sample_rate_hz,
                                              source=f'/{s.device}/ai/SampleClock',
                                              sample_mode=AcquisitionType.CONTINUOUS,
                                              samps_per_chan=buffer)
                ci.start()   # armed first: it counts from the AI task's first clock edge
                self._ci = ci
            ai.start()
        except self._errors.Error as exc:
            self.close()
            raise DaqError(self.describe(exc)) from exc

    def describe(self, exc: Exception) -> str:
        """One line for a driver error: which device, and what NI-DAQmx said first."""
        if isinstance(exc, self._errors.DaqNotFoundError):
            return ('servo_daq: NI-DAQmx (the driver) is not installed on this PC: '
                    'install it from NI; the nidaqmx package alone cannot reach a device')
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        return f'servo_daq: {self.settings.device}: {first}'

    def read(self) -> tuple[list[float], list[float], list[float]]:
        """One block: u volts, v volts, encoder counts (or angle volts)."""
        s = self.settings
        timeout = s.samples_per_block / s.sample_rate_hz + READ_MARGIN_S
        try:
            data = self._ai.read(number_of_samples_per_channel=s.samples_per_block,
                                 timeout=timeout)
            angle = (data[2] if self._ci is None else
                     self._ci.read(number_of_samples_per_channel=s.samples_per_block,
                                   timeout=timeout))
        except self._errors.Error as exc:
            raise DaqError(self.describe(exc)) from exc
        return data[0], data[1], angle

    def close(self) -> None:
        for task in self._tasks:
            with contextlib.suppress(self._errors.Error):   # a task that failed to start
                task.close()
        self._tasks = []


class ServoDaqNode(Node):
    """Hardware-timed blocks of phase currents and rotor angle to ``servo/currents``."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__('servo_daq', **kwargs)
        self.parameters = SettingsParameters(self, DaqSettings)
        settings = self.parameters.current
        self._converter = DaqConverter(settings)
        self.diagnostics = Diagnostics(self)
        self._publisher = self.create_publisher(ServoCurrents, 'servo/currents', STREAM_DEPTH)
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._daq: NiDaq | None = None
        self._daq = NiDaq(settings)   # DaqError: the driver, package or device is missing
        self._t0_ns = self.get_clock().now().nanoseconds
        self._samples = 0
        self._thread = threading.Thread(target=self._acquire, name='servo_daq', daemon=True)
        self._thread.start()

    def _acquire(self) -> None:
        s = self.parameters.current
        daq = self._daq
        assert daq is not None
        while not self._stop.is_set():
            try:
                u, v, angle = daq.read()
            except DaqError as exc:
                self.diagnostics.error(str(exc), log=True)
                return
            t0_ns = self._t0_ns + round(self._samples * 1e9 / s.sample_rate_hz)
            self._samples += len(u)
            message = block_message(self._converter, t0_ns, np.asarray(u), np.asarray(v),
                                    np.asarray(angle))
            self._publisher.publish(message)
            self.diagnostics.published('servo/currents')

    def destroy_node(self) -> None:
        # Also called by the context's cleanup on a node whose DAQ never opened.
        stop = getattr(self, '_stop', None)
        if stop is not None:
            stop.set()
        if getattr(self, '_thread', None) is not None:
            self._thread.join(timeout=READ_MARGIN_S + 1.0)   # type: ignore[union-attr]
        if getattr(self, '_daq', None) is not None:
            self._daq.close()   # type: ignore[union-attr]
        super().destroy_node()


main = node_main(ServoDaqNode)


if __name__ == '__main__':
    sys.exit(main())
