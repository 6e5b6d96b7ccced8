"""``turning-force pmc-check MACHINE.yaml``: commissioning of the override wiring.

With the spindle off and the operator watching the override display, every level of the
machine's table is written to the module, held a moment, and read back; the check stops at the
first level that fails, with a line naming it. Then it leaves the programmed feed (100 %) on
the PMC, and prints what the module's fieldbus watchdog must be set to (the coil pattern of
``fail_safe_pct``) and what the PMC reads with every output off (the module unpowered).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import TextIO

import numpy as np

from turning_force.core.pmc.machine import Machine
from turning_force.io.modbus_pmc import ModbusPmc, PmcIoError, pattern_text

__all__ = ['check_pmc']


def check_pmc(machine: Machine, out: TextIO, control_period_s: float = 0.01,
              dwell_s: float = 0.5, sleep: Callable[[float], None] = time.sleep) -> bool:
    """Step ``machine``'s module through every level and read each back; True when all
    read back as written. :class:`PmcIoError` when the module cannot be reached at all."""
    pmc = ModbusPmc(machine, control_period_s)
    config, table = pmc.config, machine.table
    coils = f'coils {config.first_coil}-{config.first_coil + len(config.override_coils) - 1}'
    print(f'{machine.name}: {pmc.where}, table {table.name} ({len(table.levels_pct)} levels), '
          f'{coils}, read back from {config.readback_first}', file=out)
    fault = pmc.connect()
    if fault:
        raise PmcIoError(fault)
    print(f'spindle off, the operator watching the override display: each level held '
          f'{dwell_s:g} s', file=out)
    print(f'  {"level":>7s} {"code":>5s}  {"coils":>{max(5, len(config.override_coils))}s}  '
          f'{"read back":>9s}  {"round trip":>10s}', file=out)
    trips: list[float] = []
    ok = True
    try:
        for level in table.levels_pct:
            code, bits = table.encode(level)
            result = pmc.write(code, bits)
            if not result.ok:
                print(f'FAILED at level {level:g} % (code {code}, coils '
                      f'{pattern_text(config.coils_for(bits))}): {result.fault}', file=out)
                ok = False
                break
            trips.append(result.round_trip_s)
            print(f'  {level:5g} % {code:5d}  {pattern_text(config.coils_for(bits)):>5s}  '
                  f'{pattern_text(config.coils_for(result.bits)):>9s}  '
                  f'{result.round_trip_s * 1e3:7.2f} ms  ok', file=out)
            sleep(dwell_s)
        inputs = pmc.inputs
        if ok:
            print(f'all {len(trips)} levels read back as written; round trip p50 '
                  f'{np.median(trips) * 1e3:.2f} ms, max {max(trips) * 1e3:.2f} ms (timeout '
                  f'{pmc.timeout_s * 1e3:.1f} ms)', file=out)
    finally:
        if not pmc.connected:
            pmc.connect()
        if pmc.connected:
            code, bits = table.encode(100.0 if 100.0 in table.levels_pct else table.min_pct)
            left = pmc.write(code, bits)
            print(f'left at {table.decode(bits):g} % (the programmed feed)' if left.ok
                  else f'could not leave the programmed feed: {left.fault}', file=out)
        pmc.close()
    safe = pattern_text(config.coils_for(table.encode(config.fail_safe_pct)[1]))
    print(f"module's watchdog: set its fail-safe outputs to {safe} ({coils}): the PMC then "
          f'reads {config.fail_safe_pct:g} % (fail_safe_pct)', file=out)
    off = config.bits_from([False] * len(config.override_coils))
    try:
        off_text = f'{table.decode(off):g} %'
    except ValueError:
        off_text = 'no level'
    warning = ('  <- not the fail-safe level: set the watchdog, and see the README'
               if off_text != f'{config.fail_safe_pct:g} %' else '')
    print(f'every output off (module unpowered): the PMC reads {off_text}{warning}', file=out)
    if ok:
        values = [f'{name} {getattr(inputs, name)}' for name in
                  ('program_enable', 'threading', 'operator_dial_pct')
                  if getattr(inputs, name) is not None]
        if values:
            print(f'inputs: {", ".join(values)}', file=out)
    return ok
