"""An independent Modbus/TCP module behind a fault-injecting proxy, for the fault suite.

:class:`Module` is pyModbusTCP's server (not our code, and not pymodbus, the client under
test) on 127.0.0.1; it keeps the whole history of the coils it was written. :class:`FaultProxy`
(asyncio, 127.0.0.1) passes requests through untouched and, answer by answer, as its plan says:
passes, drops, delays, truncates, shortens (a well-formed frame with too few bits), changes the
function code, empties, replaces with an exception code, corrupts a byte, sends out of range
(coils read back other than written, registers at 0xFFFF), holds back to reorder, or closes the
connection. A plan is a function of the answer's index and function code, so a seeded random
plan replays the same faults.
"""

from __future__ import annotations

import asyncio
import random
import struct
import threading
import time
from collections.abc import Callable
from concurrent.futures import Future
from dataclasses import dataclass, field

from pyModbusTCP.server import DataBank, ModbusServer

FAULTS = ('pass', 'drop', 'delay', 'truncate', 'short', 'wrong_function', 'empty',
          'exception', 'corrupt', 'out_of_range', 'reorder', 'close')
Plan = Callable[[int, int], str]   # (answer index, function code) -> fault


@dataclass
class CoilWrite:
    """One coil write the module took: first address, values, and when (monotonic s)."""

    address: int
    values: tuple[bool, ...]
    t_s: float = field(default=0.0, compare=False)


class _RecordingBank(DataBank):  # type: ignore[misc]
    def __init__(self) -> None:
        super().__init__(coils_size=1024, d_inputs_size=64, h_regs_size=64, i_regs_size=64)
        self.history: list[CoilWrite] = []
        self._history_lock = threading.Lock()

    def set_coils(self, address: int, bit_list: list[bool], srv_info: object = None) -> bool:
        with self._history_lock:
            self.history.append(CoilWrite(address, tuple(bool(b) for b in bit_list),
                                          time.monotonic()))
        return bool(super().set_coils(address, bit_list, srv_info))


class Module:
    """pyModbusTCP's server on 127.0.0.1 (port chosen by the OS), with its coils' history."""

    def __init__(self) -> None:
        self.bank = _RecordingBank()
        self.server = ModbusServer('127.0.0.1', 0, no_block=True, data_bank=self.bank)

    def start(self) -> int:
        self.server.start()
        return int(self.server._service.server_address[1])

    def stop(self) -> None:
        self.server.stop()

    def writes(self, address: int) -> list[CoilWrite]:
        """The coil writes that began at ``address``, in order."""
        return [w for w in self.bank.history if w.address == address]


def random_plan(seed: int, rate: float, faults: tuple[str, ...] = FAULTS[1:],
                first: int = 0) -> Plan:
    """Each answer from the ``first`` on faulted with probability ``rate``, the fault drawn
    from ``faults``; the same seed gives the same faults answer by answer."""
    def plan(index: int, function_code: int) -> str:
        draw = random.Random(seed * 1_000_003 + index)
        return draw.choice(faults) if index >= first and draw.random() < rate else 'pass'
    return plan


def _frame(tid: bytes, unit: int, pdu: bytes) -> bytes:
    return tid + struct.pack('>HHB', 0, len(pdu) + 1, unit) + pdu


def _out_of_range(pdu: bytes) -> bytes:
    function = pdu[0]
    if function in (1, 2) and len(pdu) > 2:
        return pdu[:2] + bytes(b ^ 0xFF for b in pdu[2:])   # every bit other than it is
    if function in (3, 4) and len(pdu) > 2:
        return pdu[:2] + b'\xff' * (len(pdu) - 2)
    return pdu


class FaultProxy:
    """Between the client and ``port`` on 127.0.0.1; answers faulted as ``plan`` says.
    ``delay_s``: how late a delayed answer comes. ``faults`` counts what was done."""

    def __init__(self, port: int, plan: Plan, delay_s: float = 0.03) -> None:
        self.upstream_port = port
        self.plan = plan
        self.delay_s = delay_s
        self.port = 0
        self.answers = 0
        self.faults: dict[str, int] = {}
        self._loop: asyncio.AbstractEventLoop | None = None
        self._server: asyncio.Server | None = None
        self._thread: threading.Thread | None = None
        self._tasks: set[asyncio.Task[None]] = set()

    def start(self) -> int:
        started: Future[int] = Future()
        self._thread = threading.Thread(target=self._run, args=(started,), daemon=True,
                                        name='fault-proxy')
        self._thread.start()
        self.port = started.result(timeout=10.0)
        return self.port

    def stop(self) -> None:
        loop = self._loop
        if loop is not None:
            loop.call_soon_threadsafe(loop.stop)
        if self._thread is not None:
            self._thread.join(timeout=10.0)

    def _run(self, started: Future[int]) -> None:
        loop = asyncio.new_event_loop()
        asyncio.set_event_loop(loop)
        self._loop = loop
        server = loop.run_until_complete(asyncio.start_server(self._client, '127.0.0.1', 0))
        self._server = server
        started.set_result(int(server.sockets[0].getsockname()[1]))
        try:
            loop.run_forever()
        finally:
            server.close()
            tasks = list(self._tasks)
            for task in tasks:
                task.cancel()
            loop.run_until_complete(asyncio.gather(*tasks, return_exceptions=True))
            loop.close()

    async def _client(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        task = asyncio.current_task()
        assert task is not None
        self._tasks.add(task)
        try:
            up_reader, up_writer = await asyncio.open_connection('127.0.0.1',
                                                                 self.upstream_port)
        except OSError:
            writer.close()
            return
        held: bytes | None = None
        try:
            while True:
                header = await reader.readexactly(7)
                (length,) = struct.unpack('>H', header[4:6])
                request = header + await reader.readexactly(length - 1)
                up_writer.write(request)
                await up_writer.drain()
                answer_header = await up_reader.readexactly(7)
                (length,) = struct.unpack('>H', answer_header[4:6])
                pdu = await up_reader.readexactly(length - 1)
                fault = self.plan(self.answers, pdu[0] if pdu else 0)
                self.answers += 1
                self.faults[fault] = self.faults.get(fault, 0) + 1
                tid, unit = answer_header[:2], answer_header[6]
                out = self._faulted(fault, tid, unit, pdu, answer_header + pdu)
                if fault == 'close':
                    break
                if fault == 'reorder':
                    held = out if held is None else held
                    continue
                if fault == 'delay':
                    await asyncio.sleep(self.delay_s)
                if out:
                    writer.write(out)
                if held is not None:
                    writer.write(held)
                    held = None
                await writer.drain()
        except (asyncio.IncompleteReadError, ConnectionError, OSError):
            pass
        finally:
            for w in (writer, up_writer):
                w.close()
            self._tasks.discard(task)

    @staticmethod
    def _faulted(fault: str, tid: bytes, unit: int, pdu: bytes, whole: bytes) -> bytes:
        if fault in ('drop', 'close'):
            return b''
        if fault == 'truncate':
            return whole[:max(1, len(whole) // 2)]
        if fault == 'short' and len(pdu) > 2:
            return _frame(tid, unit, bytes((pdu[0], 0)))   # a byte count of 0: no bits
        if fault == 'wrong_function':
            other = {1: 2, 2: 1, 3: 4, 4: 3, 5: 15, 15: 5, 6: 16, 16: 6}.get(pdu[0], 1)
            return _frame(tid, unit, bytes((other,)) + pdu[1:])
        if fault == 'empty':
            return _frame(tid, unit, b'')
        if fault == 'exception':
            return _frame(tid, unit, bytes((pdu[0] | 0x80, 4)))
        if fault == 'corrupt' and pdu:
            data = bytearray(whole)
            data[7 + random.Random(len(whole)).randrange(len(pdu))] ^= 0x5A
            return bytes(data)
        if fault == 'out_of_range':
            return _frame(tid, unit, _out_of_range(pdu))
        return whole
