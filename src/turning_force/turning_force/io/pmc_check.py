"""``turning-force pmc-check MACHINE.yaml``: commissioning of the override wiring.

First the wiring itself: a machine file whose outputs, all off (the module's watchdog tripped,
the PC or the 24 V lost), would give the PMC a level above the hand-back level is refused, as
is a miss budget the module's watchdog would not outlast (docs/safety.md). Then, with the spindle
off and the operator watching the override display, every level of the machine's table is
written to the module, held a moment, and read back; the check stops at the first level that
fails, with a line naming it (and saying so when the module is lost in the middle). Then it
leaves the programmed feed (at most the hand-back level) on the PMC, and prints the module's
watchdog settings for this wiring: its time, outputs off, and what the PMC then reads.
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
              dwell_s: float = 0.5, sleep: Callable[[float], None] = time.sleep,
              hand_back_pct: float = 100.0) -> bool:
    """Step ``machine``'s module through every level and read each back; True when all
    read back as written. :class:`~turning_force.core.errors.ConfigError` for wiring that is
    not safe de-energised; :class:`PmcIoError` when the module cannot be reached at all."""
    machine.check_de_energised(hand_back_pct)
    pmc = ModbusPmc(machine, control_period_s)
    config, table = pmc.config, machine.table
    config.check_miss_budget(control_period_s, machine.source)
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
    last_pct: float | None = None
    try:
        for level in table.levels_pct:
            code, bits = table.encode(level)
            result = pmc.write(code, bits)
            if not result.ok:
                print(f'FAILED at level {level:g} % (code {code}, coils '
                      f'{pattern_text(config.coils_for(bits))}): '
                      f'{result.fault or result.missed}', file=out)
                if not pmc.connected:
                    held = ('nothing written yet' if last_pct is None
                            else f'the last level read back, {last_pct:g} %,')
                    print(f'the module was lost in the middle of the check: the PMC holds '
                          f"{held} until the module's watchdog turns the outputs off "
                          f'({machine.all_off_pct():g} %)', file=out)
                ok = False
                break
            last_pct = level
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
        if not pmc.connected and not pmc.refused:
            pmc.connect()
        leave = table.level_at_most(min(100.0, hand_back_pct))
        if pmc.connected:
            left = pmc.write(*table.encode(leave))
            print(f'left at {leave:g} % (the programmed feed, at most the hand-back level)'
                  if left.ok else 'could not leave the programmed feed: '
                  f'{left.fault or left.missed}', file=out)
        else:
            print(f'could not leave the programmed feed: {pmc.fault}', file=out)
        pmc.close()
    _print_watchdog(machine, out, control_period_s, hand_back_pct)
    if ok:
        values = [f'{name} {getattr(inputs, name)}' for name in
                  ('program_enable', 'threading', 'operator_dial_pct')
                  if getattr(inputs, name) is not None]
        if values:
            print(f'inputs: {", ".join(values)}', file=out)
    return ok


def _print_watchdog(machine: Machine, out: TextIO, control_period_s: float,
                    hand_back_pct: float) -> None:
    """The module's own watchdog for this wiring: its time, outputs off, what the PMC reads
    then (never a pattern above the hand-back level: the file was checked first)."""
    config, table = machine.modbus, machine.table
    assert config is not None
    n = len(config.override_coils)
    off = machine.all_off_pct()
    assert off is not None   # check_de_energised refused it otherwise
    budget_ms = config.max_missed_periods * control_period_s * 1e3
    print(f"module's watchdog: set its fieldbus timeout to {config.module_watchdog_s * 1e3:g} "
          f'ms (module_watchdog_s) with every output off on timeout ({"0" * n}): the PMC then '
          f'reads {off:g} %, at or below the hand-back level ({hand_back_pct:g} %); the bridge '
          f'faults first, after {config.max_missed_periods} missed periods ({budget_ms:g} ms)',
          file=out)
    safe_bits = table.encode(config.fail_safe_pct)[1]
    pattern = pattern_text(config.coils_for(safe_bits))
    if pattern != '0' * n:
        print(f'  a module that holds a fail-safe pattern instead: {pattern} (fail_safe_pct '
              f'{config.fail_safe_pct:g} %)', file=out)
    register = config.owner_register
    print(f'one owner: token in holding register {register}' if register is not None else
          'one owner: no owner_register; a second bridge is found by the override coils '
          'changing under this one', file=out)
