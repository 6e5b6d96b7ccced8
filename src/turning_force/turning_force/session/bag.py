"""rosbag2 (MCAP) sessions written and read with rosbags, our message types included.

A session is a rosbag2 folder (``metadata.yaml`` + one ``.mcap``) holding every topic of the
graph, with ``ros2msg`` schemas, so that ``ros2 bag``, Foxglove, rosbags and the mcap reader all
read it. The experiment file, the resolved parameters and the software versions are embedded as
rosbag2 custom data (in ``metadata.yaml`` and in the MCAP file's ``rosbag2`` metadata record).

So that a session survives what a shop does to it:

- ``metadata.yaml`` is written when the session opens (topics, custom data, and
  ``turning_force.recording`` saying the counts are not final) and rewritten with the counts
  when it closes; a recorder killed with SIGKILL leaves a folder that says what it is.
- The same custom data is recorded as a topic too (``session/settings``, ``std_msgs/String``
  holding YAML, transient-local, the way robot descriptions are): once before the first message
  and once more as the session closes, with how it ended (:data:`CUSTOM_END`: stopped by whom,
  after how many of the planned blocks). A bag tool that rewrites ``metadata.yaml`` or drops
  its custom data (``rosbags-convert``) keeps them; ``metadata.yaml`` is a convenience copy.
- Every chunk carries the CRC-32 of its records (MCAP's ``uncompressed_crc``, which rosbags
  leaves at 0), so a reader finds a changed byte instead of decoding it.
- A write that fails (disk full, file size limit) is one :class:`BagError` naming the session;
  the chunks written before stay readable (``turning-force repair``).
"""

from __future__ import annotations

import contextlib
import datetime
import importlib.util
import json
import os
import platform
import struct
import threading
import time
import zlib
from collections import defaultdict
from functools import cache
from importlib.metadata import PackageNotFoundError, version
from io import BytesIO
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
import yaml
from rosbags.interfaces import (
    Qos,
    QosDurability,
    QosHistory,
    QosLiveliness,
    QosReliability,
    QosTime,
)
from rosbags.rosbag2 import CompressionFormat, CompressionMode, StoragePlugin, Writer
from rosbags.rosbag2.errors import WriterError
from rosbags.rosbag2.storage_mcap import McapWriter, PendingChunk, write_record
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.store import Typestore

from turning_force.core.errors import ConfigError, TurningForceError

__all__ = ['CUSTOM_END', 'CUSTOM_EXPERIMENT', 'CUSTOM_PARAMETERS', 'CUSTOM_PLANNED',
           'CUSTOM_RECORDING', 'CUSTOM_REPAIR', 'CUSTOM_STARTED', 'CUSTOM_VERSIONS', 'GRAPH_TYPES',
           'SETTINGS_TOPIC', 'SETTINGS_TYPE', 'BagError', 'SessionWriter', 'schema',
           'settings_message', 'settings_text', 'software_versions', 'stopped_by', 'typestore']

CUSTOM_EXPERIMENT = 'turning_force.experiment_yaml'
CUSTOM_PARAMETERS = 'turning_force.parameters_json'
CUSTOM_VERSIONS = 'turning_force.versions_json'
# When the recording began, UTC, ISO 8601 (a lock-step session's stamps are simulated time).
CUSTOM_STARTED = 'turning_force.started_utc'
# Present in the metadata.yaml of a session still being recorded (or never closed): its message
# counts are not final.
CUSTOM_RECORDING = 'turning_force.recording'
# What ``turning-force repair`` recovered and what was lost (JSON).
CUSTOM_REPAIR = 'turning_force.repair_json'
# The control blocks a simulated run planned (duration / control period), set at its start.
CUSTOM_PLANNED = 'turning_force.planned_blocks'
# How the recording ended, set as it closes (JSON): ``stopped_by`` (the signal or error that
# stopped the run early; null: it ran to its end, or a recorder with no plan was stopped),
# ``blocks`` (servo/currents blocks recorded) and ``planned`` (null where there is no plan).
CUSTOM_END = 'turning_force.end_json'
# The topic the custom data is recorded on (relative: a namespaced graph's own).
SETTINGS_TOPIC = 'session/settings'
SETTINGS_TYPE = 'std_msgs/msg/String'
# The graph's topics (relative: a namespaced graph's own; /diagnostics is global) and their
# types: what session_recorder subscribes and a session holds.
GRAPH_TYPES: dict[str, str] = {
    'servo/currents': 'turning_force_msgs/msg/ServoCurrents',
    'servo/joint_state': 'sensor_msgs/msg/JointState',
    'sim/cutting_state': 'turning_force_msgs/msg/CuttingState',
    'force/estimate': 'turning_force_msgs/msg/ForceEstimate',
    'force/reference': 'std_msgs/msg/Float64',
    'control/feed_command': 'turning_force_msgs/msg/FeedCommand',
    'pmc/feed_override': 'turning_force_msgs/msg/FeedOverride',
    'machine/inputs': 'turning_force_msgs/msg/MachineInputs',
    'machine/spindle_speed': 'std_msgs/msg/Float64',
    'pmc/cuts': 'turning_force_msgs/msg/CutRecord',
    '/diagnostics': 'diagnostic_msgs/msg/DiagnosticArray',
    'force/measured': 'geometry_msgs/msg/WrenchStamped',
}
# Latched, as rosbag2 records a transient-local publisher (``ros2 bag play`` republishes it so).
LATCHED = Qos(QosHistory.UNKNOWN, 0, QosReliability.RELIABLE, QosDurability.TRANSIENT_LOCAL,
              QosTime(2147483647, 4294967295), QosTime(2147483647, 4294967295),
              QosLiveliness.AUTOMATIC, QosTime(2147483647, 4294967295),
              avoid_ros_namespace_conventions=False)
MSG_PACKAGE = 'turning_force_msgs'


class BagError(TurningForceError):
    """A session folder cannot be written or read."""


def _msg_dir() -> Path:
    """Our .msg files: installed with the messages (share/), or the source tree's."""
    try:
        from ament_index_python.packages import get_package_share_directory

        installed = Path(get_package_share_directory(MSG_PACKAGE)) / 'msg'
        if installed.is_dir():
            return installed
    except (ImportError, LookupError, OSError, ValueError):  # no ament index here
        pass
    # The generated package sits in the prefix beside share/: found, not imported (the session
    # layer reads .msg text and never loads ROS).
    spec = importlib.util.find_spec(MSG_PACKAGE)
    if spec is None or spec.origin is None:
        raise ConfigError(f'{MSG_PACKAGE}: not installed (make setup builds it)')
    prefix = Path(spec.origin).resolve().parents[4]
    return prefix / 'share' / MSG_PACKAGE / 'msg'


@cache
def typestore() -> Typestore:
    """The ROS 2 Kilted type store with ``turning_force_msgs`` registered from its .msg text."""
    store = get_typestore(Stores.ROS2_KILTED)
    types = {}
    for path in sorted(_msg_dir().glob('*.msg')):
        types.update(get_types_from_msg(path.read_text(), f'{MSG_PACKAGE}/msg/{path.stem}'))
    if not types:
        raise BagError(f'no {MSG_PACKAGE} .msg files found under {_msg_dir()}')
    store.register(types)
    return store


def schema(msgtype: str) -> tuple[str, str]:
    """The ``ros2msg`` definition of ``msgtype`` (its fields, then those of every type it uses,
    as rosbag2 writes them) and its RIHS01 hash, from :func:`typestore`: the schema a session's
    MCAP file holds for a topic, and the one the live view advertises to Foxglove."""
    store = typestore()
    msgdef, _ = store.generate_msgdef(msgtype, ros_version=2)
    return msgdef, store.hash_rihs01(msgtype)


def software_versions() -> dict[str, str]:
    out = {'python': platform.python_version()}
    for dist in ('turning_force', 'ros-rclpy', 'numpy', 'scipy', 'rosbags'):
        try:
            out[dist] = version(dist)
        except PackageNotFoundError:
            out[dist] = 'not installed'
    return out


def settings_text(custom: dict[str, str]) -> str:
    """The ``session/settings`` message's text: ``custom`` as YAML."""
    return yaml.safe_dump({k: v for k, v in sorted(custom.items()) if k != CUSTOM_RECORDING},
                          width=100)


def settings_message(custom: dict[str, str]) -> bytes:
    """The ``session/settings`` message (CDR) holding ``custom`` as YAML."""
    store = typestore()
    message = store.types[SETTINGS_TYPE](data=settings_text(custom))
    return bytes(store.serialize_cdr(message, SETTINGS_TYPE))


class _CrcMcapWriter(McapWriter):
    """rosbags' MCAP storage, with each chunk's CRC-32 filled in where rosbags writes 0."""

    # The message index entries (log time, offset) of write_many, by channel, until the chunk
    # closes.
    _bulk: dict[int, list[npt.NDArray[np.uint64]]]

    def __init__(self, path: Path, compression: CompressionMode) -> None:
        super().__init__(path, compression)
        self._bulk = {}

    def close_chunk(self) -> None:
        """rosbags' ``close_chunk`` with the CRC filled in, and the message indexes written as
        arrays (a chunk holds thousands of messages)."""
        chunk = self.chunk
        size, name = chunk.bio.tell(), self.compression.encode()
        times = (chunk.message_start_time, chunk.message_end_time)
        compressed = self.compressor(chunk.bio.getvalue())
        rec = BytesIO()   # the chunk: times, sizes and CRC, compression, the records
        rec.write(struct.pack('<QQQII', *times, size, zlib.crc32(chunk.bio.getbuffer()),
                              len(name)) + name + struct.pack('<Q', len(compressed)))
        rec.write(compressed)
        chunk_start = self.bio.tell()
        write_record(self.bio, 0x06, rec)
        chunk_end = self.bio.tell()
        offsets: list[tuple[int, int]] = []
        bulk = self._bulk
        for cid in sorted(set(chunk.msgs) | set(bulk)):
            pairs = [np.asarray(chunk.msgs.get(cid, []), dtype=np.uint64).reshape(-1, 2),
                     *bulk.get(cid, [])]
            entries = np.concatenate(pairs)
            entries = entries[np.argsort(entries[:, 1], kind='stable')]   # in file order
            offsets.append((cid, self.bio.tell()))
            rec = BytesIO()
            rec.write(struct.pack('<HI', cid, entries.size * 8) + entries.astype('<u8').tobytes())
            write_record(self.bio, 0x07, rec)
        rec = BytesIO()   # its index entry, for the summary
        rec.write(struct.pack('<QQQQI', *times, chunk_start, chunk_end - chunk_start,
                              len(offsets) * 10))
        rec.write(b''.join(struct.pack('<HQ', cid, offset) for cid, offset in offsets))
        rec.write(struct.pack('<QI', self.bio.tell() - chunk_end, len(name)) + name
                  + struct.pack('<QQ', len(compressed), size))
        self.chunks.append(rec)
        self.chunk = PendingChunk(2**63 - 1, 0, BytesIO(), defaultdict(list))
        self._bulk = {}

    def write_many(self, channels: npt.NDArray[np.int64], timestamps: npt.NDArray[np.int64],
                   data: npt.NDArray[np.uint8], offsets: npt.NDArray[np.int64]) -> None:
        """Messages ``data[offsets[i]:offsets[i + 1]]`` on channel ``channels[i]`` at
        ``timestamps[i]`` [ns], in that order: their records built at once, as :meth:`write`
        builds each (sequence 0, published when logged), into the open chunk."""
        n = int(channels.size)
        if not n:
            return
        sizes = np.diff(offsets)
        header = np.dtype([('op', 'u1'), ('length', '<u8'), ('channel', '<u2'),
                           ('sequence', '<u4'), ('log', '<u8'), ('publish', '<u8')])
        heads = np.zeros(n, dtype=header)
        heads['op'] = 0x05
        heads['length'] = 22 + sizes
        heads['channel'] = channels
        heads['log'] = heads['publish'] = timestamps
        starts = np.concatenate([[0], np.cumsum(sizes + header.itemsize)])
        out = np.empty(int(starts[-1]), dtype=np.uint8)
        edges = np.zeros(out.size + 1, dtype=np.int8)
        edges[starts[:-1]] = 1
        edges[starts[:-1] + header.itemsize] -= 1
        in_header = np.cumsum(edges[:-1], dtype=np.int8).view(np.bool_)
        out[in_header] = heads.view(np.uint8)
        out[~in_header] = data[int(offsets[0]):int(offsets[-1])]
        chunk = self.chunk
        base = chunk.bio.tell()
        chunk.bio.write(out.tobytes())
        first, last = int(timestamps.min()), int(timestamps.max())
        self.message_start_time = min(first, self.message_start_time)
        self.message_end_time = max(last, self.message_end_time)
        chunk.message_start_time = min(first, chunk.message_start_time)
        chunk.message_end_time = max(last, chunk.message_end_time)
        at = (starts[:-1] + base).astype(np.uint64)
        for channel in np.unique(channels).tolist():
            picked = channels == channel
            self.channel_stats[channel] += int(np.count_nonzero(picked))
            self._bulk.setdefault(channel, []).append(
                np.stack([timestamps[picked].astype(np.uint64), at[picked]], axis=1))
        if chunk.bio.tell() > 2**20:
            self.close_chunk()


class _Writer(Writer):
    STORAGE_PLUGINS = {**Writer.STORAGE_PLUGINS,  # noqa: RUF012 (as rosbags declares it)
                       StoragePlugin.MCAP: _CrcMcapWriter}


class SessionWriter:
    """Writes serialized messages to a new rosbag2 MCAP folder.

    rosbags closes an MCAP chunk once it holds 1 MiB; at our rates that is minutes. So that a
    killed process loses at most ``flush_period_s`` of data, the open chunk is also closed and
    the file flushed once that much wall time has passed since the last flush.
    ``metadata.yaml`` is there from the start (see the module docstring).

    With ``background``, :meth:`write` only queues the message: a writer thread does the disk
    work (MCAP records, the zstd chunk, the flush with fsync), so that a recorder on a control
    graph's executor never waits for the disk. The queue holds at most ``queue_limit``
    messages; a write to a full queue waits for the thread (nothing is dropped). A write that
    fails on the thread stops it; the :class:`BagError` is :attr:`failure`, and the next
    :meth:`write`, :meth:`flush` or :meth:`close` raises it. :meth:`close` writes what is
    queued first. ``custom_data`` is in the session from its first ``metadata.yaml`` (a run's
    settings and plan: a kill at any time leaves a session that has them).
    """

    # How long the writer thread lets messages gather before it writes them [s]: batches keep
    # its share of the interpreter lock in few, short turns.
    BATCH_PERIOD_S = 0.02
    # Messages the thread writes between two turns it gives back to the interpreter lock, so
    # that a control callback waiting for it is not held up by a whole batch.
    YIELD_EVERY = 16

    def __init__(self, path: Path, flush_period_s: float = 1.0, background: bool = False,
                 queue_limit: int = 20_000, custom_data: dict[str, str] | None = None) -> None:
        if path.exists():
            raise BagError(f'{path}: exists already; a session is never overwritten')
        self._typestore = typestore()  # before anything is created on disk
        self.path = path
        self._writer = _Writer(path, version=9, storage_plugin=StoragePlugin.MCAP)
        # zstd per chunk (rosbag2's "storage" compression): a third of the size, and every
        # MCAP reader decompresses it.
        self._writer.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
        self._writer.set_custom_data(CUSTOM_RECORDING, 'open: the message counts are written '
                                     'when the session closes')
        for key, value in (custom_data or {}).items():   # in the first metadata.yaml already
            self._writer.set_custom_data(key, value)
        if CUSTOM_STARTED not in (custom_data or {}):   # a rewrite keeps the session's own
            self._writer.set_custom_data(CUSTOM_STARTED, datetime.datetime.now(datetime.UTC)
                                         .isoformat(timespec='seconds'))
        self._connections: dict[str, Any] = {}
        self._flush_period_s = flush_period_s
        self._last_flush = time.monotonic()
        self.counts: dict[str, int] = {}
        self.failure: BagError | None = None
        self._closed = False
        self._queue_limit = max(int(queue_limit), 1)
        self._pending: list[tuple[Any, int, bytes]] = []
        self._wake = threading.Condition()   # guards the queue
        self._disk = threading.Lock()        # guards the file: one writer at a time
        self._stopping = False
        self._told = False   # the failure has been raised to a caller
        self.queue_high_water = 0   # the most messages ever waiting for the thread
        self._thread: threading.Thread | None = None
        self._settings: str | None = None   # the settings topic, once it is recorded
        self._settings_due = False   # its first message not written yet
        self._last_ns = 0   # the latest log time written [ns]
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            self._writer.open()
            self._write_open_metadata()
        except (OSError, WriterError) as exc:
            self._fail(exc, opening=True)
        if background:
            self._thread = threading.Thread(target=self._drain, name=f'session {path.name}',
                                            daemon=True)
            self._thread.start()

    @property
    def background(self) -> bool:
        """Whether a writer thread does the disk work."""
        return self._thread is not None

    def _failed(self, exc: Exception, opening: bool = False) -> BagError:
        """Stop writing for good; the one line that says so (kept in :attr:`failure`)."""
        reason = exc.strerror if isinstance(exc, OSError) and exc.strerror else str(exc)
        self.failure = BagError(
            f'{self.path}: cannot create the session: {reason}' if opening else
            f'{self.path}: cannot write the session: {reason}; what was written before stays '
            f'readable (`turning-force repair {self.path}`)')
        storage, self._writer.storage = self._writer.storage, None
        if storage is not None:
            with contextlib.suppress(OSError):   # it is failing already: say it once
                storage.abort()
        return self.failure

    def _fail(self, exc: Exception, opening: bool = False) -> None:
        """Stop writing for good and raise the one line that says so."""
        raise self._failed(exc, opening) from exc

    def _write_open_metadata(self) -> None:
        """metadata.yaml of the open session: topics and custom data, no counts yet."""
        topics = [{'topic_metadata': {'name': c.topic, 'type': c.msgtype,
                                      'serialization_format': 'cdr',
                                      'offered_qos_profiles': [],
                                      'type_description_hash': c.digest},
                   'message_count': 0} for c in self._writer.connections]
        name = f'{self.path.name}.mcap'
        info: dict[str, Any] = {
            'version': 9, 'storage_identifier': 'mcap', 'relative_file_paths': [name],
            'duration': {'nanoseconds': 0}, 'starting_time': {'nanoseconds_since_epoch': 0},
            'message_count': 0, 'topics_with_message_count': topics,
            'compression_format': '', 'compression_mode': '',
            'files': [{'path': name, 'starting_time': {'nanoseconds_since_epoch': 0},
                       'duration': {'nanoseconds': 0}, 'message_count': 0}],
            'custom_data': dict(self._writer.custom_data), 'ros_distro': 'rosbags'}
        metadata = self.path / 'metadata.yaml'
        temporary = metadata.with_suffix('.yaml.tmp')
        temporary.write_text(yaml.safe_dump({'rosbag2_bagfile_information': info}))
        temporary.replace(metadata)

    def _guarded(self, action: Any, *args: Any) -> Any:
        if self.failure is not None:
            raise self.failure
        if self._closed:
            raise BagError(f'{self.path}: the session is closed')
        try:
            return action(*args)
        except (OSError, WriterError) as exc:
            self._fail(exc)

    def _quiet(self, action: Any) -> Any:
        """``action()`` while the writer thread is between batches (metadata, flush)."""
        with self._disk:
            return self._guarded(action)

    def add_topic(self, topic: str, msgtype: str,
                  definition: tuple[str, str] | None = None, latched: bool = False) -> None:
        """A topic of ``msgtype``, as our type store defines it, or as ``definition`` (message
        definition text, RIHS01 hash) does: a session rewritten keeps the definitions it was
        recorded with. ``latched``: offered transient-local."""
        msgdef, rihs01 = definition if definition is not None else schema(msgtype)
        self._connections[topic] = self._quiet(
            lambda: self._writer.add_connection(topic, msgtype, typestore=self._typestore,
                                                msgdef=msgdef, rihs01=rihs01,
                                                offered_qos_profiles=[LATCHED] if latched else []))
        self.counts[topic] = 0
        self._quiet(self._write_open_metadata)

    def record_settings(self, topic: str = f'/{SETTINGS_TOPIC}') -> None:
        """Record the custom data on ``topic`` too (the module docstring): before the first
        message, and as the session closes."""
        self.add_topic(topic, SETTINGS_TYPE, latched=True)
        self._settings, self._settings_due = topic, True

    def end(self, stopped_by: str | None) -> None:
        """Say how the recording ends (:data:`CUSTOM_END`), before :meth:`close`:
        ``stopped_by`` what stopped the run before its planned end (None: it ran to it, or
        there was no plan); the servo/currents blocks recorded are counted here."""
        if self.failure is not None or self._closed:   # nothing more is written
            return
        planned = self._writer.custom_data.get(CUSTOM_PLANNED)
        blocks = sum(n for t, n in self.counts.items() if t.endswith('servo/currents'))
        self.set_custom_data(CUSTOM_END, json.dumps({
            'stopped_by': stopped_by, 'blocks': blocks,
            'planned': None if planned is None else int(planned)}))

    @property
    def custom_data(self) -> dict[str, str]:
        """The session's custom data so far."""
        return dict(self._writer.custom_data)

    def set_custom_data(self, key: str, value: str) -> None:
        with self._disk:
            self._writer.set_custom_data(key, value)
        if self._writer.storage is not None:
            self._quiet(self._write_open_metadata)

    def write(self, topic: str, timestamp_ns: int, data: bytes) -> None:
        if self._settings_due:
            self._settings_first(timestamp_ns)
        self._last_ns = max(self._last_ns, timestamp_ns)
        if self._thread is None:
            self._guarded(self._writer.write, self._connections[topic], timestamp_ns, data)
            self.counts[topic] += 1
            if time.monotonic() - self._last_flush >= self._flush_period_s:
                self.flush()
            return
        if self.failure is not None:
            self._told = True
            raise self.failure
        if self._closed:
            raise BagError(f'{self.path}: the session is closed')
        connection = self._connections[topic]
        with self._wake:
            pending = self._pending
            if len(pending) >= self._queue_limit:   # the disk is behind: wait for it
                self._wake.notify()
                while (len(self._pending) >= self._queue_limit and self.failure is None
                       and self._thread.is_alive()):
                    self._wake.wait(0.1)
                if self.failure is not None:
                    self._told = True
                    raise self.failure
                pending = self._pending
            pending.append((connection, timestamp_ns, data))
            self.queue_high_water = max(self.queue_high_water, len(pending))
        self.counts[topic] += 1

    def _settings_first(self, timestamp_ns: int) -> None:
        """The settings message, before the first message (logged with it)."""
        self._settings_due = False
        if self._settings is not None:
            self.write(self._settings, timestamp_ns, settings_message(self._writer.custom_data))

    def _drain(self) -> None:
        """The writer thread: batches to the file, the flush when due, until closed."""
        write, flush_period_s = self._writer.write, self._flush_period_s
        while True:
            with self._wake:
                if not self._stopping:   # woken early by a full queue or by close()
                    self._wake.wait(self.BATCH_PERIOD_S)
                batch, self._pending = self._pending, []
                stopping = self._stopping
                self._wake.notify_all()   # a write waiting on a full queue
            try:
                with self._disk:
                    for n, (connection, timestamp_ns, data) in enumerate(batch, 1):
                        write(connection, timestamp_ns, data)
                        if n % self.YIELD_EVERY == 0:
                            time.sleep(0)
                    if time.monotonic() - self._last_flush >= flush_period_s:
                        self._flush()
            except Exception as exc:
                with self._disk:
                    self._failed(exc)
                with self._wake:
                    self._pending = []
                    self._wake.notify_all()
                return
            if stopping:
                return

    def _stop_thread(self) -> None:
        thread = self._thread
        if thread is None or not thread.is_alive():
            return
        with self._wake:
            self._stopping = True
            self._wake.notify_all()
        thread.join()

    def write_indexed(self, topics: list[str], topic_index: npt.NDArray[np.int64],
                      timestamps_ns: npt.NDArray[np.int64], data: npt.NDArray[np.uint8],
                      offsets: npt.NDArray[np.int64]) -> None:
        """Many messages at once, in order: message ``i`` (``data[offsets[i]:offsets[i +
        1]]``, CDR) on ``topics[topic_index[i]]``, logged at ``timestamps_ns[i]``. What
        :meth:`write` does for each, without a Python call per message (no wall-time flush:
        a batch is written as fast as it is made; chunks close at rosbags' 1 MiB). Not with a
        writer thread (``background``): its queue would be overtaken."""
        if self._thread is not None:
            raise RuntimeError(f'{self.path}: write_indexed on a session written by a thread')
        if self._settings_due and timestamps_ns.size:
            self._settings_first(int(timestamps_ns[0]))
        connections = [self._connections[t] for t in topics]
        channel_of = np.array([c.id for c in connections], dtype=np.int64)
        channels = channel_of[topic_index]

        def write() -> None:
            storage = self._writer.storage
            assert isinstance(storage, _CrcMcapWriter)
            storage.write_many(channels, timestamps_ns, data, offsets)
            for k, connection in enumerate(connections):
                count = int(np.count_nonzero(topic_index == k))
                self._writer.counts[connection.id] += count
                self.counts[topics[k]] += count
            if timestamps_ns.size:
                self._last_ns = max(self._last_ns, int(timestamps_ns.max()))
                self._writer.min_timestamp = min(self._writer.min_timestamp,
                                                 int(timestamps_ns.min()))
                self._writer.max_timestamp = max(self._writer.max_timestamp,
                                                 int(timestamps_ns.max()))

        self._guarded(write)

    def flush(self) -> None:
        """Close the open chunk and push it to the disk (with a writer thread: what it has
        written so far)."""
        self._quiet(self._flush)

    def _flush(self) -> None:
        storage = self._writer.storage
        if storage is not None and storage.chunk.bio.tell():  # type: ignore[attr-defined]
            storage.close_chunk()  # type: ignore[attr-defined]
            storage.bio.flush()  # type: ignore[attr-defined]
            os.fsync(storage.bio.fileno())  # type: ignore[attr-defined]
        self._last_flush = time.monotonic()

    def close(self) -> None:
        """Write what is queued, finish the file (summary, index) and rewrite metadata.yaml
        with the counts. Idempotent; after a failed write it only lets go of the file, and
        raises that write's :class:`BagError` (once)."""
        self._stop_thread()
        with self._wake:
            late, self._pending = self._pending, []   # queued while the thread stopped
        for connection, timestamp_ns, data in late:
            if self.failure is None:
                self._guarded(self._writer.write, connection, timestamp_ns, data)
        if self._closed or self.failure is not None:
            self._closed = True
            if self.failure is not None and not self._told and self._thread is not None:
                self._told = True   # the thread's failure, not yet raised to anyone
                raise self.failure
            return
        if CUSTOM_END not in self._writer.custom_data and self._settings is not None:
            self.end(None)   # a recording that records its settings says it closed
        self._writer.custom_data.pop(CUSTOM_RECORDING, None)
        if self._settings is not None:   # the settings again, with how the recording ended
            self._settings_due = False
            self._guarded(self._writer.write, self._connections[self._settings], self._last_ns,
                          settings_message(self._writer.custom_data))
            self.counts[self._settings] += 1
        self._guarded(self._writer.close)
        self._closed = True


def stopped_by(exc: BaseException) -> str:
    """What stopped a run, for :meth:`SessionWriter.end`: the signal's name, or the error's
    first line (shortened)."""
    name = getattr(exc, 'signal_name', None)
    if isinstance(name, str):
        return name
    if isinstance(exc, KeyboardInterrupt):
        return 'SIGINT'
    text = f'{type(exc).__name__}: {exc}'.splitlines()[0]
    return text if len(text) <= 120 else text[:117] + '...'


def dumps(value: object) -> str:
    return json.dumps(value, indent=1, sort_keys=True)
