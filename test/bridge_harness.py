"""pmc_bridge on an independent Modbus/TCP module (pyModbusTCP's server, behind the fault proxy),
driven as the controller would, with the wall clock under the test's hand; and the safety
contract (docs/safety.md) checked against the whole history of the module's coils."""

from __future__ import annotations

import itertools
import os
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pytest
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.node import Node
from rclpy.parameter import Parameter
from turning_force_msgs.msg import FeedCommand, FeedOverride

from faultproxy import FaultProxy, Module, Plan
from modbus_helpers import local_machine, write_machine
from turning_force.core.pmc.machine import Machine
from turning_force.nodes.pmc_bridge import PmcBridgeNode

DIAL_INPUTS = 2   # config/machines/fanuc_0t.yaml: the operator's dial on discrete inputs 2-5
_RIGS = itertools.count()


class WallClock:
    """The wall clock as Python code reads it (``time.time``, ``time.time_ns``), stepped by
    the test as NTP or an operator setting the date would: the bridge must not read it."""

    def __init__(self, monkeypatch: pytest.MonkeyPatch) -> None:
        self.offset_s = 0.0
        real, real_ns = time.time, time.time_ns
        monkeypatch.setattr(time, 'time', lambda: real() + self.offset_s)
        monkeypatch.setattr(time, 'time_ns', lambda: real_ns() + int(self.offset_s * 1e9))

    def step(self, seconds: float) -> None:
        self.offset_s += seconds


class Driver:
    """A node in the controller's place: commands, and what the bridge publishes."""

    def __init__(self, context: Any, executor: Any, namespace: str = '') -> None:
        self.node = Node('driver', context=context)
        executor.add_node(self.node)
        self.executor = executor
        self.overrides: list[FeedOverride] = []
        self.diagnostics: list[str] = []
        self._status = f'{namespace}/pmc_bridge'
        self.node.create_subscription(FeedOverride, f'{namespace}/pmc/feed_override',
                                      self.overrides.append, 100)
        self.node.create_subscription(DiagnosticArray, '/diagnostics', self._on_diagnostics, 10)
        self.commands = self.node.create_publisher(FeedCommand, f'{namespace}/control/'
                                                   'feed_command', 10)

    def _on_diagnostics(self, msg: DiagnosticArray) -> None:
        for status in msg.status:
            if status.name == self._status:
                self.diagnostics.append(status.message)
                self.diagnostics.extend(f'{v.key}={v.value}' for v in status.values)

    def command(self, pct: float) -> None:
        self.commands.publish(FeedCommand(override_pct=float(pct), controller='smc'))

    def run(self, seconds: float, pct: Callable[[], float] | float = 60.0,
            each: Callable[[], object] | None = None) -> None:
        """Command ``pct`` and spin for ``seconds`` (monotonic), calling ``each`` per spin."""
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            self.command(pct() if callable(pct) else pct)
            self.executor.spin_once(timeout_sec=0.005)
            if each is not None:
                each()

    def until(self, condition: Callable[[], bool], pct: float | None = 60.0,
              timeout_s: float = 10.0) -> bool:
        """Command ``pct`` (nothing: ``None``) and spin until ``condition()`` holds."""
        end = time.monotonic() + timeout_s
        while time.monotonic() < end:
            if condition():
                return True
            if pct is not None:
                self.command(pct)
            self.executor.spin_once(timeout_sec=0.005)
        return condition()

    def last(self) -> FeedOverride:
        return self.overrides[-1]


@dataclass
class Rig:
    """The module, the proxy in front of it, the machine file pointed at the proxy."""

    module: Module
    proxy: FaultProxy
    machine: Machine
    path: Path
    namespace: str   # of this rig's graph: another test's graph on the domain is not heard
    bridges: list[PmcBridgeNode] = field(default_factory=list)

    def set_dial(self, pct: float) -> None:
        """The operator's dial (its four *OV signals on discrete inputs 2-5, as wired)."""
        dial = self.machine.inputs.operator_dial
        assert dial is not None and dial.table is not None
        self.module.bank.set_discrete_inputs(DIAL_INPUTS, list(dial.table.encode(pct)[1]))

    def override_writes(self) -> list[tuple[float, float]]:
        """Every override the module was written: (monotonic s, the level the PMC reads)."""
        config = self.machine.modbus
        assert config is not None
        return [(w.t_s, self.machine.table.decode(config.bits_from(w.values)))
                for w in self.module.writes(config.first_coil)]

    def driver(self, context: Any, executor: Any, namespace: str = '') -> Driver:
        """A driver for the bridge in ``namespace`` (under the rig's own)."""
        return Driver(context, executor, self.namespace + namespace)

    def bridge(self, context: Any, executor: Any, namespace: str = '',
               **parameters: Any) -> PmcBridgeNode:
        # No force comes in: the entry feed off, so the coils show the request as the gate
        # passed it (the contract's bounds are on the request and the dial).
        values = {'machine_file': str(self.path), 'backend': 'modbus_tcp',
                  'air_cut_override_pct': 0.0, **parameters}
        node = PmcBridgeNode(autostart=True, context=context,
                             namespace=self.namespace + namespace,
                             parameter_overrides=[Parameter(k, value=v)
                                                  for k, v in values.items()])
        executor.add_node(node)
        self.bridges.append(node)
        return node


@contextmanager
def rig(tmp_path: Path, plan: Plan | None = None, **backend: Any) -> Iterator[Rig]:
    """pyModbusTCP's server behind a fault proxy (``plan``: every answer passes when None),
    and the 0-T's machine file pointed at the proxy."""
    module = Module()
    port = module.start()
    proxy = FaultProxy(port, plan or (lambda index, function_code: 'pass'))
    try:
        proxy_port = proxy.start()
        settings = {'timeout_s': 0.1, 'readback_address': None, 'max_missed_periods': 3,
                    **backend}
        path = write_machine(tmp_path / 'm.yaml', port=proxy_port, **settings)
        the_rig = Rig(module, proxy, local_machine(port=proxy_port, **settings), path,
                      f'/rig_{os.getpid()}_{next(_RIGS)}')
        yield the_rig
    finally:
        for node in the_rig.bridges if 'the_rig' in locals() else ():
            node.stop()   # the hand-back, while the module still answers
        proxy.stop()
        module.stop()
