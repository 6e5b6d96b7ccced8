"""Nuisance disarms under load (issue 17 item 6): pmc_bridge at 100 Hz on ``modbus_tcp`` against a
pymodbus server in a process of its own (the module), the shipped 0-T wiring (timeout one
control period, ``max_missed_periods`` 3), a controller's command every 10 ms, while two CPU hogs
(``while True`` processes) share the machine's cores. No real-time rights are asked for the
bridge (run with ``TURNING_FORCE_RT_PRIORITY`` set to compare).

The module is a Modbus/TCP device with a processor of its own: its answer time does not depend
on the PC's load. Its stand-in here is a Python process on the same two cores, so, where the
bench may (root, or CAP_SYS_NICE), it raises the stand-in's priority (nice -10) so that the
misses counted are the PC's, not the stand-in's own starvation; it prints which it did
(``--module-nice 0`` leaves the stand-in at the hogs' priority, a harsher test than a machine).

Prints the periods, misses (no answer in time), retries (a fresh connection after a miss),
faults (each a nuisance disarm, needing the operator to re-arm), and the percentiles of the
exchange's round trip and of the interval between override writes.

Measures; asserts nothing. Run: ``.venv/bin/python test/bench/bench_two_hogs.py`` (one minute)
or ``--minutes 30`` (the issue's figure).
"""

from __future__ import annotations

import argparse
import multiprocessing
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import rclpy
from rclpy.context import Context
from rclpy.parameter import Parameter
from turning_force_msgs.msg import FeedCommand

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))   # test/modbus_helpers.py
from modbus_helpers import ServerProcess, write_machine
from turning_force.io.modbus_pmc import IoResult
from turning_force.nodes.pmc_bridge import PmcBridgeNode
from turning_force.nodes.spin import make_executor, real_time_priority, timer_callback


def hog() -> None:
    while True:
        pass


def percentiles(values: list[float]) -> str:
    if not values:
        return 'none'
    p50, p99, p999 = np.percentile(values, [50, 99, 99.9])
    return f'p50 {p50:.2f} ms, p99 {p99:.2f} ms, p99.9 {p999:.2f} ms, max {max(values):.2f} ms'


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--minutes', type=float, default=1.0)
    parser.add_argument('--hogs', type=int, default=2)
    parser.add_argument('--module-nice', type=int, default=-10,
                        help="the module stand-in's nice value (0: the hogs' own)")
    parser.add_argument('--max-missed-periods', type=int, default=0,
                        help="the machine file's (0: the shipped 0-T file's)")
    args = parser.parse_args()
    refused = real_time_priority()
    if refused:
        print(f'warning: {refused}')
    server = ServerProcess()
    module = f'module stand-in (pid {server.process.pid}) at nice 0'
    if args.module_nice:
        try:
            os.setpriority(os.PRIO_PROCESS, server.process.pid, args.module_nice)
            module = f'module stand-in (pid {server.process.pid}) at nice {args.module_nice}'
        except PermissionError:
            module += ' (no right to raise it: its own starvation counts as misses)'
    print(module, flush=True)
    hogs = [multiprocessing.Process(target=hog, daemon=True) for _ in range(args.hogs)]
    for process in hogs:
        process.start()
    context = Context()
    rclpy.init(context=context)
    try:
        with tempfile.TemporaryDirectory() as folder:
            backend = {'readback_address': None}
            if args.max_missed_periods:
                backend['max_missed_periods'] = args.max_missed_periods
            path = write_machine(Path(folder) / 'm.yaml', port=server.port, **backend)
            bridge = PmcBridgeNode(autostart=True, context=context,
                                   namespace=f'/hogs_{os.getpid()}', parameter_overrides=[
                                       Parameter('machine_file', value=str(path)),
                                       Parameter('backend', value='modbus_tcp'),
                                       Parameter('armed', value=True)])
            trips_ms: list[float] = []
            written_at: list[float] = []
            write = bridge.backend.write

            started = time.monotonic()
            missed_at: list[str] = []

            def timed(code: int, bits: tuple[bool, ...]) -> IoResult:
                result = write(code, bits)
                if result.missed:
                    missed_at.append(f'{time.monotonic() - started:.1f} s '
                                     f'({result.round_trip_s * 1e3:.1f} ms)')
                if result.ok:
                    trips_ms.append(result.round_trip_s * 1e3)
                    written_at.append(time.monotonic())
                return result

            bridge.backend.write = timed
            publisher = bridge.create_publisher(FeedCommand, 'control/feed_command', 10)
            step = [0]

            def command() -> None:   # the controller: a staircase over the table
                step[0] += 1
                publisher.publish(FeedCommand(override_pct=float(10 * (step[0] // 50 % 13)),
                                              controller='bench'))

            bridge.create_timer(0.01, timer_callback(command))
            executor = make_executor(context, 'events')
            executor.add_node(bridge)
            faults = 0
            was_faulted = False
            end = time.monotonic() + 60.0 * args.minutes
            while time.monotonic() < end:
                executor.spin_once(timeout_sec=0.1)
                if bridge.io_fault and not was_faulted:
                    faults += 1
                    print(f'  fault (a nuisance disarm): {bridge.io_fault}', flush=True)
                if not bridge.io_fault and was_faulted:
                    bridge.arm()   # the operator re-arms once the module answers again
                was_faulted = bool(bridge.io_fault)
            backend = bridge.backend
            periods = len(trips_ms)
            intervals = list(np.diff(written_at) * 1e3)
            print(f'two-hog bench: {args.minutes:g} min, {args.hogs} CPU hogs on '
                  f'{os.cpu_count()} cores, 100 Hz, timeout {backend.timeout_s * 1e3:g} ms, '
                  f'max_missed_periods {backend.config.max_missed_periods}')
            print(f'  exchanges answered {periods}, misses {backend.misses}, retries '
                  f'{backend.retries}, faults (nuisance disarms) {faults}')
            print(f"  misses at: {', '.join(missed_at) or 'none'}")
            print(f'  round trip: {percentiles(trips_ms)}')
            print(f'  interval between override writes: {percentiles(intervals)}')
            executor.remove_node(bridge)
            bridge.destroy_node()
            executor.shutdown()
    finally:
        rclpy.try_shutdown(context=context)
        for process in hogs:
            process.terminate()
        server.stop()
    return 0


if __name__ == '__main__':
    sys.exit(main())
