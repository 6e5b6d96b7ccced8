"""Issue 17's unsafe findings U1-U8, checked by behaviour through what every version since
3638a43 has: `python -m turning_force.nodes.pmc_bridge` as a process (`--ros-args -p ...`), its
topics and `~/arm`, signals to it, `python -m turning_force.cli` (pmc-check, run --core, repair,
report), machine files in a temp folder, session folders, and an independent Modbus/TCP module
(pyModbusTCP's server, test/faultproxy.py) on 127.0.0.1 recording every coil write in order.

A plain script (pytest does not collect it): it runs against the source first on PYTHONPATH,
so it shows a regression against an old commit (docs/safety.md):

    PYTHONPATH=<old checkout>/src/turning_force .venv/bin/python test/safety_regressions.py [U1 ..]

The machine file is the shipped config/machines/fanuc_0t.yaml of the source under test (found
from turning_force.__file__), moved to the module; the reference session is its
bags/reference/park1998_fig8. One line per U: PASS or FAIL and the evidence; exit code: the
number of FAILs. U5 steps the bridge's wall clock with libfaketime (Debian package `faketime`,
the steady clock untouched); without it U5 is NOT RUN, counted as a FAIL.
"""

from __future__ import annotations

import hashlib
import itertools
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import rclpy
import yaml
import zstandard
from mcap.records import Chunk
from mcap.stream_reader import StreamReader
from std_srvs.srv import Trigger
from turning_force_msgs.msg import FeedCommand

import turning_force

sys.path.insert(0, str(Path(__file__).resolve().parent))
from faultproxy import FaultProxy, Module

ROOT = Path(turning_force.__file__).resolve().parents[3]   # the checkout under test
SHIPPED = ROOT / 'config' / 'machines' / 'fanuc_0t.yaml'
REFERENCE = ROOT / 'bags' / 'reference' / 'park1998_fig8'
FAKETIME = Path('/usr/lib/x86_64-linux-gnu/faketime/libfaketime.so.1')
DIAL_INPUTS = 2            # fanuc_0t.yaml: the operator's dial on discrete inputs 2-5
REQUEST_PCT = 60.0         # what the stand-in controller asks (below the dial and hand-back)
HAND_BACK_PCT = 100.0      # the hand-back level (docs/safety.md), both versions' default
WATCHDOG_S = 0.3           # the bridge's command watchdog: long against a loaded machine
START_TIMEOUT_S = 60.0     # a bridge's first write (rclpy and numba imports, a loaded machine)
WORK = Path(tempfile.mkdtemp(prefix='safety_regressions_'))
ENV = {**os.environ, 'ROS_DOMAIN_ID': os.environ.get('TURNING_FORCE_TEST_DOMAIN', '45'),
       'ROS_AUTOMATIC_DISCOVERY_RANGE': 'LOCALHOST', 'PYTHONUNBUFFERED': '1'}
os.environ.update(ENV)
Result = tuple[bool, str]


def level_pct(coils: tuple[bool, ...], logic: str) -> float:
    """The 0-T's four-bit table: *FV0..*FV3 active low, code k is 10 k % (signals off: 150 %)."""
    signals = coils[:4] if logic == 'direct' else tuple(not c for c in coils[:4])
    return 10.0 * (15 - sum(1 << k for k, s in enumerate(signals) if s))


def dial_signals(pct: float) -> list[bool]:
    return [bool((15 - round(pct / 10.0)) >> k & 1) for k in range(4)]


def changes(levels: list[float]) -> int:
    return sum(a != b for a, b in itertools.pairwise(levels))


def tail(text: str, width: int = 110) -> str:
    """The last line said, the temp folder shortened to <tmp>."""
    lines = [line for line in text.strip().splitlines() if line.strip()]
    return (lines[-1] if lines else '(no output)').replace(str(WORK), '<tmp>')[:width]


def cli(*args: str) -> tuple[int, str]:
    done = subprocess.run([sys.executable, '-m', 'turning_force.cli', *args], env=ENV,
                          capture_output=True, text=True, timeout=300, cwd=ROOT)
    return done.returncode, done.stdout + done.stderr


class Bridge:
    """pmc_bridge as its own process in namespace ``ns``, its output in WORK/<ns>.log."""

    def __init__(self, ns: str, machine: Path, env: dict[str, str], **params: Any) -> None:
        values = {'machine_file': machine, 'backend': 'modbus_tcp', 'air_cut_override_pct': 0.0,
                  'watchdog_period_s': WATCHDOG_S, **params}
        args = [sys.executable, '-m', 'turning_force.nodes.pmc_bridge', '--ros-args',
                '-r', f'__ns:=/{ns}']
        for key, value in values.items():
            args += ['-p', f'{key}:={str(value).lower() if isinstance(value, bool) else value}']
        self.log = WORK / f'{ns}.log'
        with self.log.open('w') as out:
            self.process = subprocess.Popen(args, env={**ENV, **env}, stdout=out,
                                            stderr=subprocess.STDOUT)

    def text(self) -> str:
        return self.log.read_text(errors='replace')

    def alive(self) -> bool:
        return self.process.poll() is None

    def stop(self) -> int:
        """SIGINT (Ctrl-C), as an operator stops it; killed after 20 s."""
        if self.alive():
            self.process.send_signal(signal.SIGINT)
        try:
            return self.process.wait(timeout=20.0)
        except subprocess.TimeoutExpired:
            self.process.kill()
            return self.process.wait(timeout=10.0)


class Rig:
    """The module (a fault proxy before it if a plan is given), the machine file, the bridges,
    and the controller's place (the script's node: feed commands, ~/arm)."""

    def __init__(self, node: Any, name: str, plan: Callable[[int, int], str] | None = None,
                 dial_pct: float | None = None, **backend: Any) -> None:
        self.node, self.name, self.bridges = node, name, list[Bridge]()
        self.module = Module()
        port = self.module.start()
        self.proxy = FaultProxy(port, plan) if plan is not None else None
        if self.proxy is not None:
            port = self.proxy.start()
        if dial_pct is not None:
            self.module.bank.set_discrete_inputs(DIAL_INPUTS, dial_signals(dial_pct))
        # No read-back image on pyModbusTCP's server: the override coils themselves are read.
        data = yaml.safe_load(SHIPPED.read_text())
        data['backend'].pop('readback_address', None)
        data['backend'].update({'host': '127.0.0.1', 'port': port, 'timeout_s': 0.1,
                                'reconnect_max_s': 0.5, **backend})
        self.logic = str(data['backend']['logic'])
        self.machine = WORK / f'{name}.yaml'
        self.machine.write_text(yaml.safe_dump(data))
        self.publisher = node.create_publisher(FeedCommand, f'/{name}/control/feed_command', 10)

    def __enter__(self) -> Rig:
        return self

    def __exit__(self, *exc: object) -> None:
        for bridge in self.bridges:
            bridge.stop()
        if self.proxy is not None:
            self.proxy.stop()
        self.module.stop()

    def bridge(self, ns: str, pct: float | None = REQUEST_PCT, env: dict[str, str] | None = None,
               **params: Any) -> Bridge:
        """A bridge, once it has written its first level (commanding ``pct`` meanwhile)."""
        count = len(self.levels())
        self.bridges.append(bridge := Bridge(ns, self.machine, env or {}, **params))
        if not self.spin(START_TIMEOUT_S, pct, lambda: len(self.levels()) > count
                         or not bridge.alive()) or not bridge.alive():
            raise RuntimeError(f'{bridge.log}: did not start:\n{bridge.text()[-2000:]}')
        return bridge

    def spin(self, seconds: float, pct: float | None = REQUEST_PCT,
             until: Callable[[], bool] = lambda: False) -> bool:
        """Command ``pct`` (None: nothing) for up to ``seconds``, or until ``until()``."""
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            if until():
                return True
            if pct is not None:
                self.publisher.publish(FeedCommand(override_pct=pct, controller='smc'))
            rclpy.spin_once(self.node, timeout_sec=0.01)
        return until()

    def arm(self) -> str:
        client = self.node.create_client(Trigger, f'/{self.name}/pmc_bridge/arm')
        if not client.wait_for_service(timeout_sec=10.0):
            return 'no ~/arm service'
        future = client.call_async(Trigger.Request())
        self.spin(10.0, until=future.done)
        answer = future.result()
        return 'no answer' if answer is None else f'success={answer.success} {answer.message!r}'

    def writes(self, since_s: float = 0.0) -> list[tuple[float, float]]:
        """(monotonic s, level the PMC reads) of every override write, in order."""
        return [(w.t_s, level_pct(w.values, self.logic)) for w in self.module.writes(0)
                if w.t_s >= since_s]

    def levels(self, since_s: float = 0.0) -> list[float]:
        return [pct for _, pct in self.writes(since_s)]


# --- the cases ------------------------------------------------------------------------------

def u1(node: Any) -> Result:
    with Rig(node, 'u1') as rig:   # every dial input off: the code for 150 %, as if unwired
        bridge = rig.bridge('u1', None)
        rig.spin(1.5, None)
        stop_s = time.monotonic()
        bridge.stop()
        at_stop, levels = rig.levels(stop_s), rig.levels()
    return (max(levels) <= HAND_BACK_PCT, f'never armed, dial inputs all off: written '
            f'{sorted(set(levels))} %, at stop (SIGINT) {at_stop} %')


def u2(node: Any) -> Result:
    dead = [False]
    with Rig(node, 'u2', lambda index, fc: 'close' if dead[0] else 'pass', 100.0) as rig:
        rig.bridge('u2', armed=True)
        if not rig.spin(10.0, until=lambda: REQUEST_PCT in rig.levels()):
            return False, f'never wrote the request: {rig.levels()[-5:]}'
        dead[0] = True            # the module closes every connection
        rig.spin(1.5)
        answer = rig.arm()
        dead[0] = False
        back_s = time.monotonic()
        rig.spin(3.0)
        after = rig.levels(back_s)
    return (bool(after) and REQUEST_PCT not in after, f'arm during the fault: {answer}; module '
            f'back: written {sorted(set(after))} % (the request: {REQUEST_PCT:g} %)')


def u3(node: Any) -> Result:
    windows = {'short': range(60, 63), 'wrong_function': range(400, 403),
               'empty': range(800, 803)}

    def plan(index: int, function_code: int) -> str:
        return next((f for f, answers in windows.items() if index in answers), 'pass')

    with Rig(node, 'u3', plan, 100.0) as rig:
        bridge = rig.bridge('u3', armed=True)
        assert rig.proxy is not None
        proxy = rig.proxy
        rig.spin(15.0, until=lambda: not bridge.alive() or proxy.answers > 830)
        rig.spin(1.0)
        alive = bridge.alive()
        rc = bridge.stop()
    text = bridge.text()
    error = next((line for line in text.splitlines()
                  if line.startswith(('IndexError', 'KeyError'))), tail(text))
    ok = alive and 'Traceback' not in text and 'IO_FAULT' in text
    return ok, (f'faults {proxy.faults} in {proxy.answers} answers: '
                + ('alive, IO_FAULT logged, no traceback' if ok else
                   f'{"alive" if alive else "exited"} rc={rc}: {error}'))


def u4(node: Any) -> Result:
    with Rig(node, 'u4a', dial_pct=100.0) as rig:
        first = rig.bridge('u4a', armed=True)
        rig.spin(10.0, until=lambda: REQUEST_PCT in rig.levels())
        second_s = time.monotonic()
        second = rig.bridge('u4b')
        rig.spin(5.0)
        last_s = time.monotonic() - 1.0
        levels, late = rig.levels(second_s), rig.levels(last_s)
    refused = [b.log.stem for b in (first, second) if 'another' in b.text()]
    # A refusal leaves at most: the first's level, the second's configure, the first's
    # last write before it saw the mismatch, the second's next hand-back.
    ok = bool(refused) and changes(levels) <= 4 and changes(late) == 0
    return ok, (f'second bridge on the module: {len(levels)} writes, {changes(levels)} level '
                f'changes ({sorted(set(levels))} %), {changes(late)} in the last 1 s; '
                f'"another ..." logged by {refused or "neither"}')


def u5_step(node: Any, ns: str, step_s: float) -> Result:
    """The bridge's wall clock stepped ``step_s`` while commands flow (nothing may change);
    then the commands stop: the safe 0 % within the watchdog (a loaded machine: +1 s)."""
    offset = WORK / f'{ns}.faketime'
    offset.write_text('+0\n')
    env = {'LD_PRELOAD': str(FAKETIME), 'FAKETIME_TIMESTAMP_FILE': str(offset),
           'FAKETIME_DONT_FAKE_MONOTONIC': '1', 'FAKETIME_CACHE_DURATION': '1'}
    with Rig(node, ns, dial_pct=100.0) as rig:
        rig.bridge(ns, env=env, armed=True)
        rig.spin(10.0, until=lambda: REQUEST_PCT in rig.levels())
        offset.write_text(f'{step_s:+.0f}\n')
        step_at = time.monotonic()
        seen = subprocess.run([sys.executable, '-c', 'import time; print(time.time())'],
                              env={**ENV, **env}, capture_output=True, text=True, timeout=60)
        stepped = float(seen.stdout) - time.time()   # the wall clock as the bridge's reads it
        rig.spin(max(0.0, 2.0 - (time.monotonic() - step_at)))   # past the 1 s cache
        flowing = rig.levels(step_at)
        quiet_s = time.monotonic()
        rig.spin(2.5, None)
        safe = [t - quiet_s for t, pct in rig.writes(quiet_s) if pct == 0.0]
        held = rig.levels()[-1]
    tripped = 0.0 in flowing
    ok = abs(stepped - step_s) < 2.0 and not tripped and bool(safe) and safe[0] < WATCHDOG_S + 1
    return ok, (f'wall clock {stepped:+.1f} s: ' + ('0 % while commands flowed; ' if tripped
                                                     else '') +
                (f'0 % {safe[0]:.2f} s after the commands stopped' if safe else
                 f'no 0 % in 2.5 s without commands ({held:g} % held)'))


def u5(node: Any) -> Result | None:
    if not FAKETIME.exists():
        return None
    results = [u5_step(node, 'u5_back', -30.0), u5_step(node, 'u5_forward', 30.0)]
    return all(ok for ok, _ in results), '; '.join(text for _, text in results)


def u6(node: Any) -> Result:
    with Rig(node, 'u6', dial_pct=100.0, fail_safe_pct=150.0) as rig:
        rc, text = cli('pmc-check', str(rig.machine), '--dwell-s', '0.02')
    advice = next((line.strip() for line in text.splitlines() if 'watchdog' in line), '')
    ok = rc != 0 and 'Traceback' not in text and 'fail_safe_pct' in text
    return ok, f'fail_safe_pct: 150: pmc-check rc={rc}: ' + (tail(text) if ok else advice[:110])


def chunks(mcap: Path) -> list[Chunk]:
    with mcap.open('rb') as stream:
        return [r for r in StreamReader(stream, emit_chunks=True).records if isinstance(r, Chunk)]


def flip_a_bit(mcap: Path) -> None:
    """One bit flipped in the first chunk where zstd still decodes it, to other records of the
    same size: a change only a CRC can find (a search of 300 places)."""
    chunk = chunks(mcap)[0]
    raw = bytearray(mcap.read_bytes())
    start = raw.find(chunk.data[:64])
    decode = zstandard.ZstdDecompressor().decompress
    whole = decode(chunk.data, max_output_size=chunk.uncompressed_size)
    for offset in range(len(chunk.data) // 2, len(chunk.data) // 2 + 2100, 7):
        data = bytearray(chunk.data)
        data[offset] ^= 0x10
        try:
            changed = decode(bytes(data), max_output_size=chunk.uncompressed_size)
        except zstandard.ZstdError:
            continue
        if len(changed) == len(whole) and changed != whole:
            raw[start + offset] ^= 0x10
            mcap.write_bytes(raw)
            return
    raise RuntimeError(f'{mcap}: no place found where a flipped bit still decodes')


def strip_crcs(mcap: Path) -> None:
    """Every chunk's CRC field set to 0 (none), as the reference sessions of 3638a43 had."""
    raw = bytearray(mcap.read_bytes())
    for chunk in chunks(mcap):
        # ... uncompressed_crc (4), compression (4 + n), records length (8), the records
        crc_at = raw.find(chunk.data[:64]) - 8 - 4 - len(chunk.compression) - 4
        raw[crc_at:crc_at + 4] = bytes(4)
    mcap.write_bytes(raw)


def u7(node: Any) -> Result:
    out = WORK / 'core_session'
    rc, text = cli('run', '--core', '--out', str(out),
                   str(ROOT / 'config' / 'experiments' / 'air_cut.yaml'))
    if rc != 0:
        return False, f'run --core --out: rc={rc}: {tail(text)}'
    core = [c.uncompressed_crc for c in chunks(next(out.glob('*.mcap')))]
    reference = [c.uncompressed_crc for c in chunks(next(REFERENCE.glob('*.mcap')))]
    said = []
    for name in ('flipped', 'flipped_no_crc'):   # a bit flipped in it, and in a CRC-less copy
        shutil.copytree(REFERENCE, WORK / name)
        if name == 'flipped_no_crc':
            strip_crcs(next((WORK / name).glob('*.mcap')))
        flip_a_bit(next((WORK / name).glob('*.mcap')))
        rc, text = cli('report', str(WORK / name), '--out', str(WORK / f'{name}.png'))
        said.append(f'report rc={rc}, ' + ('damaged' if 'damaged' in text else
                                           'whole, bytes not verifiable' if 'verif' in text
                                           else 'read as whole' if rc == 0 else tail(text)))
    ok = bool(reference) and 0 not in reference and not any('as whole' in s for s in said)
    return ok, (f'run --core --out: {core.count(0)} of {len(core)} chunks without a CRC; '
                f'{REFERENCE.name}: {reference.count(0)} of {len(reference)}; a bit flipped '
                f'in it: {said[0]}; in it without CRCs: {said[1]}')


def u8(node: Any) -> Result:
    """Session folders whose metadata.yaml names ../outside/<file>: report must not read it,
    repair must not rename or rewrite it (there a killed session's cut-short copy)."""
    outside = WORK / 'outside'
    outside.mkdir()
    mcap = next(REFERENCE.glob('*.mcap'))
    shutil.copy(mcap, outside / 'whole.mcap')
    (outside / 'cut.mcap').write_bytes(mcap.read_bytes()[:mcap.stat().st_size * 2 // 3])
    before = {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in outside.iterdir()}
    metadata = yaml.safe_load((REFERENCE / 'metadata.yaml').read_text())
    said = []
    for name, command in (('whole', 'report'), ('cut', 'repair')):
        hostile = WORK / f'hostile_{name}'
        hostile.mkdir()
        info = metadata['rosbag2_bagfile_information']
        info['relative_file_paths'] = [f'../outside/{name}.mcap']
        (hostile / 'metadata.yaml').write_text(yaml.safe_dump(metadata))
        said.append(cli(command, str(hostile),
                        *(('--out', str(WORK / 'hostile.png')) if command == 'report' else ())))
    after = {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in outside.iterdir()}
    (rc_report, report), (rc_repair, repair) = said
    read = 'mean_abs_error_n' in report
    return (after == before and not read, f'metadata naming ../outside/: report rc={rc_report} '
            f'({"the metrics of the file outside" if read else tail(report, 60)}); repair '
            f'rc={rc_repair} ({tail(repair, 60)}), outside: {sorted(after)}')


def main() -> int:
    print(f'source under test: {turning_force.__file__}\nmachine file: {SHIPPED}')
    rclpy.init()
    node = rclpy.create_node('safety_regressions')
    fails = 0
    try:
        for name, check in (('U1', u1), ('U2', u2), ('U3', u3), ('U4', u4), ('U5', u5),
                            ('U6', u6), ('U7', u7), ('U8', u8)):
            if sys.argv[1:] and name not in sys.argv[1:]:   # a few by name, for a quick look
                continue
            result = check(node)
            fails += result is None or not result[0]
            print(f'{name} NOT RUN: no {FAKETIME}: the wall clock cannot be stepped for one '
                  'process' if result is None else
                  f'{name} {"PASS" if result[0] else "FAIL"}: {result[1]}', flush=True)
    finally:
        node.destroy_node()
        rclpy.shutdown()
        shutil.rmtree(WORK, ignore_errors=True)
    return fails


if __name__ == '__main__':
    sys.exit(main())
