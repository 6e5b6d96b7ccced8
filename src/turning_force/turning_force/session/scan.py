"""What an MCAP file holds, whatever state it is in: every complete chunk, and where it is not.

A closed session's MCAP ends with a summary (schemas, channels, an index of its chunks,
statistics) and a footer; a recorder that was killed, or whose disk filled, leaves the chunks it
had written and a torn record at the end. Readers that start from the summary (rosbags, mcap's
seeking reader) refuse such a file, and one that is damaged in the middle can make them skip
chunks without a word. :func:`scan_mcap` reads the data section record by record instead, as
mcap's stream reader does, with the mcap library's record parsers, and

- checks every record's length against the file and every chunk's CRC-32 where it has one
  (our writer sets it; rosbags alone writes 0, "not computed": such chunks are counted in
  :attr:`McapScan.unverified`, their bytes cannot be checked);
- decompresses a chunk only up to the size its record states, so that damaged sizes cannot make
  it allocate gigabytes;
- when a record cannot be read, goes on at the next chunk it knows of (from the summary's chunk
  index, if that is readable, and from the start pattern of our zstd chunks), so that one damaged
  chunk loses only its own messages;
- says what it could not read, naming the bytes, in :attr:`McapScan.damage`.

Whether what was read is everything the session recorded is for the caller to judge against the
session's ``metadata.yaml`` (:mod:`turning_force.session.reader`).

With a ``sink``, messages are not kept: each intact chunk's messages go to the sink at once, as
arrays (channel ids, log times, where each message's bytes lie in the chunk's records), so that
a reader decodes an hour-long session chunk by chunk, never holding its bytes all at once.
"""

from __future__ import annotations

import bisect
import io
import mmap
import struct
import zlib
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

import lz4.frame
import numpy as np
import numpy.typing as npt
import zstandard
from mcap.data_stream import ReadDataStream
from mcap.exceptions import McapError
from mcap.opcode import Opcode
from mcap.records import Channel, Chunk, ChunkIndex, Footer, Message, Metadata, Schema

__all__ = ['MAGIC', 'McapScan', 'MessageSink', 'scan_mcap']

MAGIC = b'\x89MCAP0\r\n'
FOOTER_SIZE = 1 + 8 + 20 + len(MAGIC)   # opcode, length, summary start and offsets, crc; magic
# Our chunks (rosbags' MCAP storage with zstd) start with opcode, record length, start and end
# time, uncompressed size and CRC, then the compression name as a length-prefixed string.
ZSTD_CHUNK_TAG = b'\x04\x00\x00\x00zstd'
ZSTD_CHUNK_TAG_OFFSET = 1 + 8 + 8 + 8 + 8 + 4
# A message record: channel id, sequence, log time, publish time; then the data.
MESSAGE_HEADER = struct.Struct('<HIQQ')
RECORD_HEADER = struct.Struct('<BQ')
# Chunks up to this size whose zstd frame states the size the record does are decompressed in
# one call; others (a damaged size may say anything) a piece at a time, never past the size.
ONE_SHOT_BYTES = 1 << 28
# What a damaged record makes a parser raise: short or garbled fields, bad text, bad compression.
RECORD_ERRORS = (McapError, ValueError, struct.error, EOFError, OverflowError, MemoryError,
                 zstandard.ZstdError, RuntimeError)
# The records that describe the messages, by opcode: in a chunk, in the data section and in
# the summary alike.
DESCRIPTIONS: dict[int, type[Schema] | type[Channel]] = {Opcode.SCHEMA: Schema,
                                                         Opcode.CHANNEL: Channel}


IntArray = npt.NDArray[np.int64]
# A chunk's messages: (the scan so far (its channels and schemas), the chunk's records' bytes,
# channel id, log time [ns], offset of each message's data in those bytes, its size).
MessageSink = Callable[['McapScan', npt.NDArray[np.uint8], IntArray, IntArray, IntArray,
                        IntArray], None]


class _Exact(ReadDataStream):
    """mcap's record stream, strict: a read past the end of the record is an error, where mcap
    returns the short bytes (and a damaged length would swallow the records after it)."""

    def read(self, length: int) -> bytes:
        if length < 0:
            raise McapError(f'negative length {length}')
        data = super().read(length)
        if len(data) != length:
            raise McapError(f'a field of {length} bytes runs past the end of its record')
        return data


def _stream(body: bytes) -> _Exact:
    return _Exact(io.BytesIO(body))


@dataclass
class McapScan:
    """The records read from one MCAP file.

    ``messages`` in file order; ``channels`` and ``schemas`` by id, from the data and from the
    summary; ``metadata`` the metadata records by name (rosbag2 writes one at close);
    ``damage`` one phrase per unreadable stretch, naming its bytes (empty for a whole file).
    """

    path: Path
    size: int
    schemas: dict[int, Schema] = field(default_factory=dict)
    channels: dict[int, Channel] = field(default_factory=dict)
    messages: list[Message] = field(default_factory=list)
    metadata: dict[str, dict[str, str]] = field(default_factory=dict)
    damage: list[str] = field(default_factory=list)
    counts: dict[int, int] = field(default_factory=dict)   # messages read, by channel id
    chunks: int = 0       # chunk records read
    unverified: int = 0   # of them, those without a CRC (0: "not computed"): unverifiable


def _prepared(body: bytes) -> bytes:
    """A chunk record's body to its records, decompressed and checked."""
    return _decompress(Chunk.read(_stream(body)))


def _frame_size(data: bytes) -> int:
    """The content size a zstd frame's header states (-1: none, or not a frame)."""
    try:
        return int(zstandard.frame_content_size(data))
    except zstandard.ZstdError:
        return -1


def _decompress(chunk: Chunk) -> bytes:
    """A chunk's records, no more than its record says they are."""
    size = chunk.uncompressed_size
    if chunk.compression == '':
        data = chunk.data
    elif (chunk.compression == 'zstd' and size <= ONE_SHOT_BYTES
          and _frame_size(chunk.data) == size):
        # The frame says what the record says: decompressed in one go, into one buffer.
        data = zstandard.ZstdDecompressor().decompress(chunk.data, max_output_size=size)
    elif chunk.compression == 'zstd':
        reader = zstandard.ZstdDecompressor().stream_reader(chunk.data, read_across_frames=False)
        pieces: list[bytes] = []
        got = 0
        while got <= size:
            piece = reader.read(min(size + 1 - got, 1 << 20))
            if not piece:
                break
            pieces.append(piece)
            got += len(piece)
        data = b''.join(pieces)
    elif chunk.compression == 'lz4':
        data = lz4.frame.decompress(chunk.data)
    else:
        raise McapError(f'unknown compression {chunk.compression!r}')
    if len(data) != size:
        raise McapError(f'{len(data)} bytes uncompressed where the chunk says {size}')
    if chunk.uncompressed_crc and zlib.crc32(data) != chunk.uncompressed_crc:
        raise McapError('CRC-32 of its records does not match: the bytes were changed')
    return data


def _chunk_messages(data: bytes) -> tuple[list[Schema | Channel], IntArray, IntArray]:
    """The schemas and channels inside a chunk, and where its message records start and how
    long they are (other records are skipped); raises ``McapError`` where a record runs past
    the chunk or is not one a chunk may hold."""
    out: list[Schema | Channel] = []
    starts: list[int] = []
    lengths: list[int] = []
    unpack = RECORD_HEADER.unpack_from
    pos, size = 0, len(data)
    message, header = Opcode.MESSAGE, MESSAGE_HEADER.size
    while pos < size:
        if pos + 9 > size:
            raise McapError(f'a record header at {pos} runs past the end of the chunk')
        opcode, length = unpack(data, pos)
        end = pos + 9 + length
        if end > size:
            raise McapError(f'a record at {pos} runs past the end of the chunk')
        if opcode == message:
            if length < header:
                raise McapError(f'a message record at {pos} of {length} bytes')
            starts.append(pos)
            lengths.append(length)
        elif opcode in DESCRIPTIONS:
            out.append(DESCRIPTIONS[opcode].read(_stream(data[pos + 9:end])))
        elif opcode not in {Opcode.METADATA, Opcode.ATTACHMENT}:
            raise McapError(f'record with opcode {opcode:#04x} at {pos} inside a chunk')
        pos = end
    return out, np.array(starts, dtype=np.int64), np.array(lengths, dtype=np.int64)


def _indexed_messages(data: bytes, offsets: IntArray
                      ) -> tuple[list[Schema | Channel], IntArray, IntArray] | None:
    """:func:`_chunk_messages` from the chunk's message indexes (where each message record
    starts): each must be a message record, and the bytes between them whole records of other
    kinds (walked). None where they do not hold (the caller walks the chunk instead)."""
    raw = np.frombuffer(data, dtype=np.uint8)
    size = raw.size
    starts = np.sort(offsets)
    if starts.size > 1 and np.any(starts[1:] == starts[:-1]):
        starts = np.unique(starts)
    if not starts.size or starts[0] < 0 or starts[-1] + 9 > size:
        return None
    if np.any(raw[starts] != Opcode.MESSAGE):
        return None
    lengths = _little(raw, starts + 1, 8)
    ends = starts + 9 + lengths
    if np.any(lengths < MESSAGE_HEADER.size) or np.any(ends > size):
        return None
    gap_starts = np.concatenate([[0], ends])
    gap_ends = np.concatenate([starts, [size]])
    if np.any(gap_starts > gap_ends):
        return None
    records: list[Schema | Channel] = []
    for k in np.flatnonzero(gap_starts < gap_ends).tolist():
        try:
            found, messages, _ = _chunk_messages(data[int(gap_starts[k]):int(gap_ends[k])])
        except RECORD_ERRORS:
            return None
        if messages.size:   # messages the index does not list
            return None
        records += found
    return records, starts, lengths


def _little(raw: npt.NDArray[np.uint8], at: IntArray, width: int) -> IntArray:
    """The unsigned little-endian integers of ``width`` bytes at ``at`` (read through a view
    of the bytes at each of the ``width`` alignments, not byte by byte)."""
    value: IntArray = np.empty(at.size, dtype=np.int64)
    residue = at % width
    for r in np.flatnonzero(np.bincount(residue, minlength=width)).tolist():
        picked = residue == r
        view = np.frombuffer(raw, dtype=f'<u{width}', offset=r,
                             count=(raw.size - r) // width)
        value[picked] = view[(at[picked] - r) // width]
    return value


class _Scanner:
    def __init__(self, path: Path, data: bytes | mmap.mmap, sink: MessageSink | None) -> None:
        self.data = data
        self.out = McapScan(path, len(data))
        self.sink = sink or self.keep
        self.known_chunks: set[int] = set()   # offsets of chunk records found or indexed
        # The summary's copies of schemas and channels: the data's own (in a chunk, under its
        # CRC) come first; these only stand in for what a lost chunk took with it.
        self.summary_records: list[tuple[Schema | Channel, int]] = []
        self.read_chunks: set[int] = set()
        # The next chunk decompressed on a thread while this one is decoded.
        self._pool = ThreadPoolExecutor(1)
        self._ahead: tuple[int, Future[bytes]] | None = None
        self._chunk_list: list[int] = []
        self._data_end = len(data)

    def add(self, record: Schema | Channel | Message, where: str) -> None:
        out = self.out
        if isinstance(record, Message):
            out.counts[record.channel_id] = out.counts.get(record.channel_id, 0) + 1
            if self.sink == self.keep:   # a message outside a chunk: its record as it is
                out.messages.append(record)
                return
            self.sink(out, np.frombuffer(record.data, dtype=np.uint8),
                      np.array([record.channel_id], dtype=np.int64),
                      np.array([record.log_time], dtype=np.int64), np.zeros(1, dtype=np.int64),
                      np.array([len(record.data)], dtype=np.int64))
            return
        table: dict[int, Schema] | dict[int, Channel] = (
            out.schemas if isinstance(record, Schema) else out.channels)
        known = table.get(record.id)
        if known is None:
            table[record.id] = record  # type: ignore[assignment]
        elif known != record:
            out.damage.append(f'{where}: {type(record).__name__.lower()} {record.id} differs '
                              'from its copy elsewhere in the file')

    def keep(self, out: McapScan, data: npt.NDArray[np.uint8], channels: IntArray,
             log_times: IntArray, offsets: IntArray, sizes: IntArray) -> None:
        """The sink of a scan without one: every message of a chunk kept, as mcap's record
        (its header read from the record before its data)."""
        raw = data.tobytes()
        for offset, size in zip(offsets.tolist(), sizes.tolist(), strict=True):
            channel, sequence, log_time, publish_time = MESSAGE_HEADER.unpack_from(
                raw, offset - MESSAGE_HEADER.size)
            out.messages.append(Message(channel_id=channel, sequence=sequence,
                                        log_time=log_time, publish_time=publish_time,
                                        data=raw[offset:offset + size]))

    def record_at(self, pos: int, limit: int) -> tuple[int, bytes] | None:
        """(opcode, body) of the record at ``pos`` if it lies whole before ``limit``."""
        if pos + 9 > limit:
            return None
        length = int.from_bytes(self.data[pos + 1:pos + 9], 'little')
        if pos + 9 + length > limit:
            return None
        return self.data[pos], bytes(self.data[pos + 9:pos + 9 + length])

    def summary(self) -> int:
        """Read the footer and the summary it points to; return where the data section ends
        (the summary's start), or the file's end if there is no readable summary."""
        data, size = self.data, len(self.data)
        if size < 8 + FOOTER_SIZE or data[size - 8:] != MAGIC:
            self.out.damage.append('no footer at the end of the file: it was cut short or its '
                                   'end is damaged')
            return size
        footer_at = size - FOOTER_SIZE
        found = self.record_at(footer_at, size - 8)
        if found is None or found[0] != Opcode.FOOTER:
            self.out.damage.append(f'bytes {footer_at}-{size}: the footer is unreadable')
            return size
        try:
            footer = Footer.read(_stream(found[1]))
        except RECORD_ERRORS as exc:
            self.out.damage.append(f'bytes {footer_at}-{size}: the footer is unreadable ({exc})')
            return size
        start = int(footer.summary_start)
        if start == 0:   # a file written without a summary
            return footer_at
        if not 8 <= start <= footer_at:
            self.out.damage.append(f'byte {footer_at}: the footer points outside the file')
            return size
        pos = start
        try:
            while pos < footer_at:
                found = self.record_at(pos, footer_at)
                if found is None:
                    raise McapError('a record runs past the footer')
                opcode, body = found
                if opcode in DESCRIPTIONS:
                    self.summary_records.append((DESCRIPTIONS[opcode].read(_stream(body)), pos))
                elif opcode == Opcode.CHUNK_INDEX:
                    index = ChunkIndex.read(_stream(body))
                    if not 8 <= index.chunk_start_offset < start:
                        raise McapError(f'a chunk index points to byte '
                                        f'{index.chunk_start_offset}')
                    self.known_chunks.add(index.chunk_start_offset)
                elif opcode not in Opcode.__members__.values():
                    raise McapError(f'unknown record {opcode:#04x}')
                pos += 9 + len(body)
        except RECORD_ERRORS as exc:
            self.out.damage.append(f'bytes {pos}-{size}: the summary is unreadable ({exc})')
            self.known_chunks.clear()
            self.summary_records.clear()
            return size
        return start

    def find_chunks(self, end: int) -> None:
        """Offsets of our zstd chunk records, by their start pattern (looked for a window at a
        time, each let go of after: the file is not held in memory)."""
        window = 1 << 24
        for low in range(0, end, window):
            high = min(low + window + len(ZSTD_CHUNK_TAG) - 1, end)
            at = self.data.find(ZSTD_CHUNK_TAG, max(low, ZSTD_CHUNK_TAG_OFFSET), high)
            while at >= 0:
                start = at - ZSTD_CHUNK_TAG_OFFSET
                if self.data[start] == Opcode.CHUNK:
                    self.known_chunks.add(start)
                at = self.data.find(ZSTD_CHUNK_TAG, at + 1, high)
            self.release(low, min(low + window, end))

    def release(self, start: int, end: int) -> None:
        """Let the pages of a mapped file from ``start`` to ``end`` go (read once: a session
        of hours is not kept resident)."""
        if not isinstance(self.data, mmap.mmap):
            return
        first = -(-start // mmap.PAGESIZE) * mmap.PAGESIZE
        last = end // mmap.PAGESIZE * mmap.PAGESIZE
        if last > first and hasattr(mmap, 'MADV_DONTNEED'):
            self.data.madvise(mmap.MADV_DONTNEED, first, last - first)

    def chunk_by_its_fields(self, pos: int, limit: int) -> tuple[int, bytes] | None:
        """A known chunk whose record length is damaged: its extent from its own fields (the
        compression name and the compressed size), if that fits before ``limit``."""
        try:
            stream = _stream(bytes(self.data[pos + 9:min(limit, pos + 9 + 1024)]))
            stream.read(8 + 8 + 8 + 4)
            stream.read(stream.read4())
            length = stream.count + 8 + stream.read8()
        except RECORD_ERRORS:
            return None
        if pos + 9 + length > limit:
            return None
        self.out.damage.append(f'chunk at byte {pos}: its record length is damaged')
        return Opcode.CHUNK, bytes(self.data[pos + 9:pos + 9 + length])

    def prefetch_after(self, pos: int) -> None:
        """Start decompressing the chunk after the one at ``pos``, if it is whole."""
        later = bisect.bisect_right(self._chunk_list, pos)
        if later >= len(self._chunk_list):
            return
        start = self._chunk_list[later]
        limit = (self._chunk_list[later + 1] if later + 1 < len(self._chunk_list)
                 else self._data_end)
        found = self.record_at(start, limit)
        if found is not None and found[0] == Opcode.CHUNK:
            self._ahead = (start, self._pool.submit(_prepared, found[1]))

    def message_index(self, pos: int, limit: int) -> IntArray | None:
        """Where a chunk's messages start, from the message index records after it (at
        ``pos``); None where there are none or they are unreadable."""
        found: list[IntArray] = []
        while True:
            record = self.record_at(pos, limit)
            if record is None or record[0] != Opcode.MESSAGE_INDEX:
                break
            body = record[1]
            if len(body) < 6 or 6 + int.from_bytes(body[2:6], 'little') != len(body) \
                    or (len(body) - 6) % 16:
                return None
            found.append(np.frombuffer(body, dtype='<u8', offset=6)[1::2].astype(np.int64))
            pos += 9 + len(body)
        return np.concatenate(found) if found else None

    def chunk(self, pos: int, body: bytes, index: IntArray | None) -> None:
        """A chunk whose messages go to the sink as arrays (found from its message index where
        it has one, else by walking its records). The next chunk is decompressed on a thread
        meanwhile (what it gives, or what it raises, is taken when its turn comes: the scan's
        order of work is the same)."""
        self.read_chunks.add(pos)
        self.out.chunks += 1
        # start and end time, uncompressed size, then the CRC-32 of the records
        self.out.unverified += body[24:28] == b'\0\0\0\0'
        ahead, self._ahead = self._ahead, None
        self.prefetch_after(pos)
        try:
            data = (ahead[1].result() if ahead is not None and ahead[0] == pos
                    else _prepared(body))
            indexed = _indexed_messages(data, index) if index is not None else None
            records, starts, lengths = indexed if indexed is not None else \
                _chunk_messages(data)
        except RECORD_ERRORS as exc:
            self.out.damage.append(f'chunk at byte {pos} ({9 + len(body)} bytes): {exc}')
            return
        for record in records:
            self.add(record, f'chunk at byte {pos}')
        if not starts.size:
            return
        raw = np.frombuffer(data, dtype=np.uint8)
        channels = _little(raw, starts + 9, 2)
        counts = np.bincount(channels)
        for channel in np.flatnonzero(counts).tolist():
            self.out.counts[channel] = self.out.counts.get(channel, 0) + int(counts[channel])
        self.sink(self.out, raw, channels, _little(raw, starts + 9 + 6, 8),
                  starts + 9 + MESSAGE_HEADER.size, lengths - MESSAGE_HEADER.size)

    def data_section(self, pos: int, end: int) -> int:
        """Read records from ``pos`` until the data section ends or a record is unreadable;
        return where it stopped."""
        chunks = sorted(self.known_chunks)
        self._chunk_list, self._data_end = chunks, end
        while pos < end:
            later = bisect.bisect_right(chunks, pos)
            limit = chunks[later] if later < len(chunks) else end   # no record spans a chunk
            found = self.record_at(pos, limit)
            if found is None and pos in self.known_chunks:
                found = self.chunk_by_its_fields(pos, limit)
            if found is None:
                what = ('the file ends inside a record' if limit == self.out.size
                        else 'a record with a damaged length')
                self.out.damage.append(f'bytes {pos}-{limit}: {what}')
                self.read_chunks.add(pos)   # if it is a chunk, it is accounted for here
                return pos
            opcode, body = found
            if pos in self.known_chunks or opcode == Opcode.CHUNK:
                if opcode != Opcode.CHUNK:
                    self.out.damage.append(f'byte {pos}: a chunk whose opcode was changed')
                self.chunk(pos, body, self.message_index(pos + 9 + len(body), limit))
                self.release(pos, pos + 9 + len(body))
            elif opcode in (Opcode.MESSAGE, Opcode.SCHEMA, Opcode.CHANNEL):
                try:
                    record: Schema | Channel | Message = (
                        Message.read(_stream(body), len(body)) if opcode == Opcode.MESSAGE
                        else DESCRIPTIONS[opcode].read(_stream(body)))
                except RECORD_ERRORS as exc:
                    self.out.damage.append(f'record at byte {pos}: {exc}')
                else:
                    self.add(record, f'byte {pos}')
            elif opcode == Opcode.METADATA:
                try:
                    metadata = Metadata.read(_stream(body))
                except RECORD_ERRORS as exc:
                    self.out.damage.append(f'metadata record at byte {pos}: {exc}')
                else:
                    self.out.metadata[metadata.name] = metadata.metadata
            elif opcode in (Opcode.DATA_END, Opcode.FOOTER):
                return pos
            elif opcode == Opcode.HEADER and pos == 8:
                pass
            elif opcode not in Opcode.__members__.values() or opcode == Opcode.HEADER:
                self.out.damage.append(f'byte {pos}: not a record (opcode {opcode:#04x})')
                return pos
            pos += 9 + len(body)
        return pos

    def run(self) -> McapScan:
        if self.data[:8] != MAGIC:
            self.out.damage.append('bytes 0-8: not the MCAP magic')
        data_end = self.summary()
        self.find_chunks(data_end)
        if len(self.data) > 8 and self.data[8] != Opcode.HEADER:
            self.out.damage.append('byte 8: no MCAP header record')
        pos = 8
        while True:
            before = len(self.out.damage)
            stopped = self.data_section(pos, data_end)
            unread = sorted(c for c in self.known_chunks
                            if c > stopped and c not in self.read_chunks)
            if not unread:
                break
            if len(self.out.damage) == before:   # an early end of the data section
                self.out.damage.append(f'bytes {stopped}-{unread[0]}: a record out of place')
            pos = unread[0]
        for offset in sorted(self.known_chunks - self.read_chunks):
            self.out.damage.append(f'chunk at byte {offset}: passed over (a damaged record '
                                   'before it)')
        for record, pos in self.summary_records:
            self.add(record, f'summary at byte {pos}')
        described = set(self.out.channels)
        for index in sorted(set(self.out.counts) - described):
            lost = self.out.counts[index]
            self.out.damage.append(f'{lost} messages on channel {index}, which the file does '
                                   'not describe')
        return self.out


def scan_mcap(path: Path, sink: MessageSink | None = None) -> McapScan:
    """Every record of the MCAP file at ``path`` that can be read, and what cannot; with a
    ``sink``, the messages go to it (chunk by chunk, as arrays) instead of into the scan.

    Raises ``OSError`` if the file cannot be opened.
    """
    with path.open('rb') as stream:
        if stream.seek(0, io.SEEK_END) == 0:
            out = McapScan(path, 0)
            out.damage.append('the file is empty')
            return out
        with mmap.mmap(stream.fileno(), 0, access=mmap.ACCESS_READ) as data:
            scanner = _Scanner(path, data, sink)
            try:
                return scanner.run()
            finally:
                scanner._pool.shutdown(wait=True, cancel_futures=True)
