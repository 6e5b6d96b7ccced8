"""CDR of many messages at once: numpy structured views over the bytes of a topic's messages.

Our messages are of fixed layout once their strings and sequences have a length: a
``ServoCurrents`` of ten samples with frame ``z_axis`` is the same 376 bytes, field for field,
every block. So the messages of one topic that share a byte length are decoded together: the
layout (each field's offset) is found by walking the first of them with the type store's field
definitions, the way rosbags' CDR does it (XCDR1, little-endian: the 4-byte encapsulation
header, then each primitive aligned to its size counted from the end of that header, strings and
sequences as a ``uint32`` length (a string's counts its NUL) aligned to 4, a sequence's elements
aligned to theirs when it has any); then every message of the group is read through one
structured dtype at those offsets. Each message of the group must carry the same length fields
(and NULs, and encapsulation) as the first: those that do not are laid out on their own, and
what cannot be walked at all goes to rosbags' ``deserialize_cdr`` (which says whether it is
damaged).

Layouts come from the type store's definitions, not from offsets written down here: a session
recorded with an older definition of a message decodes with its own
(:func:`turning_force.session.reader.session_typestore`).

A decoded topic is a :class:`Table`: one column per field path (``header.stamp.sec``,
``phase_u_a``): a 1-D array over the messages for a primitive or a string (``bytes``, numpy
``S``), a 2-D one for a fixed array; a sequence is its elements, all messages' one after the
other, with :attr:`Table.lengths` saying how many each message has. :func:`encode` is the
inverse, giving the bytes rosbags' ``serialize_cdr`` gives.

What the fast path does not take (sequences or arrays of nested messages, arrays of strings,
``float128``, big-endian data) falls back to rosbags whole; :func:`supports` says which.
"""

from __future__ import annotations

import struct
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, cast

import numpy as np
import numpy.typing as npt
from rosbags.interfaces import Nodetype
from rosbags.serde import SerdeError
from rosbags.typesys.store import Typestore

__all__ = ['DECODE_ERRORS', 'Field', 'Table', 'TableBuilder', 'concat', 'decode', 'encode',
           'fields', 'ranges', 'supports']

# What rosbags' generated CDR deserialisers raise on damaged bytes.
DECODE_ERRORS = (SerdeError, ValueError, IndexError, KeyError, TypeError, struct.error,
                 OverflowError, MemoryError, UnicodeDecodeError)

DTYPES = {'bool': '?', 'byte': 'u1', 'char': 'u1', 'int8': 'i1', 'uint8': 'u1', 'int16': '<i2',
          'uint16': '<u2', 'int32': '<i4', 'uint32': '<u4', 'int64': '<i8', 'uint64': '<u8',
          'float32': '<f4', 'float64': '<f8'}
SIZES = {base: np.dtype(code).itemsize for base, code in DTYPES.items()}
CDR_LE = b'\x00\x01'   # the encapsulation of little-endian CDR (bytes 2-3: options)
# The most layouts one length group is split into before the rest goes to rosbags.
MAX_LAYOUTS = 8
MAX_SEQUENCE = 1 << 24

UInt8Array = npt.NDArray[np.uint8]
IntArray = npt.NDArray[np.int64]


@dataclass(frozen=True)
class Field:
    """A leaf of a message type: ``kind`` is ``value`` (a primitive), ``string``, ``array``
    (fixed length ``size``), ``sequence`` (of primitives) or ``strings`` (a sequence of
    strings); ``base`` the primitive's ROS name (``string`` for strings)."""

    path: str
    kind: str
    base: str
    size: int = 0

    @property
    def dtype(self) -> np.dtype[Any]:
        return np.dtype('S1' if self.base == 'string' else DTYPES[self.base])


class Unsupported(ValueError):
    """A type the array path does not lay out (rosbags decodes it)."""


def _fields(store: Typestore, msgtype: str, prefix: str = '') -> list[Field]:
    out: list[Field] = []
    for name, desc in store.get_msgdef(msgtype).fields:
        path = f'{prefix}{name}'
        kind, detail = cast('tuple[Nodetype, Any]', desc)
        if kind == Nodetype.NAME:
            out += _fields(store, detail, f'{path}.')
        elif kind == Nodetype.BASE:
            base = detail[0]
            if base != 'string' and base not in SIZES:
                raise Unsupported(f'{msgtype}.{path}: {base}')
            out.append(Field(path, 'string' if base == 'string' else 'value', base))
        else:
            sub, length = detail
            if sub[0] != Nodetype.BASE or (sub[1][0] not in SIZES and sub[1][0] != 'string'):
                raise Unsupported(f'{msgtype}.{path}: an array or sequence of {sub[1]}')
            base = sub[1][0]
            if kind == Nodetype.ARRAY:
                if base == 'string':
                    raise Unsupported(f'{msgtype}.{path}: an array of strings')
                out.append(Field(path, 'array', base, int(length)))
            else:
                out.append(Field(path, 'strings' if base == 'string' else 'sequence', base))
    return out


_FIELDS: dict[tuple[int, str], tuple[Field, ...] | None] = {}


def fields(store: Typestore, msgtype: str) -> tuple[Field, ...]:
    """The leaves of ``msgtype`` in CDR order (:class:`Unsupported` if it has leaves the array
    path does not take)."""
    key = (id(store), msgtype)
    if key not in _FIELDS:
        try:
            _FIELDS[key] = tuple(_fields(store, msgtype))
        except Unsupported:
            _FIELDS[key] = None
    found = _FIELDS[key]
    if found is None:
        raise Unsupported(msgtype)
    return found


def supports(store: Typestore, msgtype: str) -> bool:
    """Whether ``msgtype`` decodes and encodes as arrays (else: rosbags, message by message)."""
    try:
        fields(store, msgtype)
    except Unsupported:
        return False
    return True


def _align(pos: int, size: int) -> int:
    return (pos + size - 1) & -size


# A layout entry: (field index, element or -1, what, offset, count). ``what``: 'v' values
# (count of them; 1 for a primitive), 'n' a uint32 length, 's' string bytes (count, no NUL).
Entry = tuple[int, int, str, int, int]


def _walk(leaves: Sequence[Field], length_at: Callable[[int], int], limit: int,
          ) -> tuple[list[Entry], int]:
    """Offsets (after the 4-byte encapsulation) of every leaf, reading each string's and
    sequence's length with ``length_at(offset)``; ``limit`` the bytes there are. Returns the
    entries and the end. Raises ``ValueError`` where the lengths do not fit."""
    entries: list[Entry] = []
    pos = 0
    for index, leaf in enumerate(leaves):
        if leaf.kind in ('value', 'array'):
            size, count = SIZES[leaf.base], leaf.size if leaf.kind == 'array' else 1
            pos = _align(pos, size)
            entries.append((index, -1, 'v', pos, count))
            pos += size * count
        elif leaf.kind == 'string':
            pos = _string(entries, index, -1, pos, length_at, limit)
        else:
            pos = _align(pos, 4)
            if pos + 4 > limit:
                raise ValueError(f'a sequence length at {pos} past the end')
            count = length_at(pos)
            entries.append((index, -1, 'n', pos, count))
            pos += 4
            if leaf.kind == 'sequence':
                size = SIZES[leaf.base]
                if count > MAX_SEQUENCE or pos + count * size > limit:
                    raise ValueError(f'a sequence of {count} at {pos} past the end')
                if count:
                    pos = _align(pos, size)
                entries.append((index, -1, 'v', pos, count))
                pos += count * size
            else:
                if count > MAX_SEQUENCE or pos + count * 5 > limit:
                    raise ValueError(f'a sequence of {count} strings at {pos} past the end')
                for element in range(count):
                    pos = _string(entries, index, element, pos, length_at, limit)
        if pos > limit:
            raise ValueError(f'{leaf.path} runs past the end')
    return entries, pos


def _string(entries: list[Entry], index: int, element: int, pos: int,
            length_at: Callable[[int], int], limit: int) -> int:
    pos = _align(pos, 4)
    if pos + 4 > limit:
        raise ValueError(f'a string length at {pos} past the end')
    length = length_at(pos)
    if length < 1 or pos + 4 + length > limit:
        raise ValueError(f'a string of {length} bytes at {pos}')
    entries.append((index, element, 'n', pos, length))
    entries.append((index, element, 's', pos + 4, length - 1))
    return pos + 4 + length


@dataclass
class Table:
    """Decoded messages of one type, as columns (see the module's text). ``count`` messages;
    ``columns`` by field path; ``lengths`` the number of elements of each sequence, per
    message."""

    msgtype: str
    count: int
    columns: dict[str, np.ndarray[Any, Any]] = field(default_factory=dict)
    lengths: dict[str, IntArray] = field(default_factory=dict)

    def rows(self, path: str) -> np.ndarray[Any, Any]:
        """A sequence as (count, n) when every message has ``n`` elements (``ValueError``
        otherwise)."""
        counts = self.lengths[path]
        values = self.columns[path]
        if self.count == 0:
            return values.reshape(0, 0)
        n = int(counts[0])
        if np.any(counts != n):
            raise ValueError(f'{self.msgtype}.{path}: sequences of different lengths')
        return values.reshape(self.count, n)

    def text(self, path: str, k: int) -> str:
        """String ``path`` of message ``k``."""
        return bytes(self.columns[path][k]).decode('utf-8', 'replace')

    def take(self, index: IntArray) -> Table:
        """The messages at ``index``, in that order."""
        out = Table(self.msgtype, int(index.size))
        for path, values in self.columns.items():
            if path in self.lengths:
                counts = self.lengths[path]
                starts = np.concatenate([[0], np.cumsum(counts)])[:-1]
                picked = counts[index]
                out.lengths[path] = picked
                out.columns[path] = values[ranges(starts[index], picked)]
            else:
                out.columns[path] = values[index]
        return out


def ranges(starts: IntArray, counts: IntArray) -> IntArray:
    """The indices ``starts[i] .. starts[i] + counts[i] - 1`` of every ``i``, concatenated."""
    total = int(counts.sum())
    placed = np.cumsum(counts) - counts   # where each range starts in the output
    out: IntArray = np.arange(total, dtype=np.int64) + np.repeat(starts - placed, counts)
    return out


def _empty_table(leaves: Sequence[Field], msgtype: str, n: int) -> Table:
    table = Table(msgtype, n)
    for leaf in leaves:
        if leaf.kind == 'value':
            table.columns[leaf.path] = np.zeros(n, dtype=leaf.dtype)
        elif leaf.kind == 'string':
            table.columns[leaf.path] = np.zeros(n, dtype='S1')
        elif leaf.kind == 'array':
            table.columns[leaf.path] = np.zeros((n, leaf.size), dtype=leaf.dtype)
        else:
            table.columns[leaf.path] = np.zeros(0, dtype=leaf.dtype)
            table.lengths[leaf.path] = np.zeros(n, dtype=np.int64)
    return table


def _structured(leaves: Sequence[Field], entries: Sequence[Entry], itemsize: int,
                ) -> tuple[np.dtype[Any], list[tuple[int, int, str, int]]]:
    """The dtype reading one layout, and (field, element, name, count) of its 'v' and 's'
    entries."""
    names: list[str] = []
    formats: list[Any] = []
    offsets: list[int] = []
    picked: list[tuple[int, int, str, int]] = []
    for index, element, what, offset, count in entries:
        if what == 'n' or count == 0:
            if what != 'n':
                picked.append((index, element, '', 0))
            continue
        name = f'f{len(names)}'
        leaf = leaves[index]
        if what == 's':
            formats.append(f'S{count}')
        elif leaf.kind == 'value':
            formats.append(DTYPES[leaf.base])
        else:
            formats.append((DTYPES[leaf.base], (count,)))
        names.append(name)
        offsets.append(4 + offset)
        picked.append((index, element, name, count))
    dtype = np.dtype({'names': names, 'formats': formats, 'offsets': offsets,
                      'itemsize': itemsize})
    return dtype, picked


def _checks(entries: Sequence[Entry]) -> IntArray:
    """The byte positions (in the message) that every message of a layout shares: the
    encapsulation kind, the length fields and the strings' NULs."""
    positions = [0, 1]
    for _, _, what, offset, count in entries:
        if what == 'n':
            positions += range(4 + offset, 8 + offset)
        elif what == 's':
            positions.append(4 + offset + count)
    return np.array(positions, dtype=np.int64)


def _layout(leaves: Sequence[Field], raw: UInt8Array) -> list[Entry]:
    """The layout of one message (``ValueError`` if it cannot be walked)."""
    if len(raw) < 4 or bytes(raw[:2]) != CDR_LE:
        raise ValueError('not little-endian CDR')
    body = raw[4:]

    def length_at(pos: int) -> int:
        return int(body[pos]) | int(body[pos + 1]) << 8 | int(body[pos + 2]) << 16 \
            | int(body[pos + 3]) << 24

    entries, end = _walk(leaves, length_at, len(body))
    if end + 3 < len(body):   # as rosbags: up to 3 bytes of padding at the end
        raise ValueError(f'{len(body) - end} bytes after the message')
    for _, _, what, offset, count in entries:
        if what == 's' and body[offset + count] != 0:
            raise ValueError(f'a string at {offset} without its NUL')
    return entries


def decode(store: Typestore, msgtype: str, data: UInt8Array, offsets: IntArray,
           sizes: IntArray, keep: Iterable[str] | None = None) -> tuple[Table, IntArray]:
    """The messages ``data[offsets[i]:offsets[i] + sizes[i]]`` of ``msgtype``, as a
    :class:`Table` of those that decode, and the indices (into ``offsets``) of those.

    Messages that share a size and a layout are read through one structured view; a message
    the layout walk refuses goes to rosbags' ``deserialize_cdr``, and is left out if that
    refuses it too (a damaged message: the caller counts them). ``keep``: the field paths to
    give (default all; the others are still checked, not copied out).
    """
    leaves = fields(store, msgtype)
    wanted = None if keep is None else frozenset(keep)
    out_leaves = leaves if wanted is None else tuple(f for f in leaves if f.path in wanted)
    parts: list[tuple[IntArray, Table]] = []
    odd: list[int] = []
    if sizes.size and np.all(sizes == sizes[0]):
        groups = [np.arange(sizes.size)]
    else:
        order = np.argsort(sizes, kind='stable')   # file order kept inside each size
        groups = np.split(order, np.flatnonzero(np.diff(sizes[order])) + 1)
    for group in groups:
        if not group.size:
            continue
        size = int(sizes[group[0]])
        rows = _gather(data, offsets[group], size)
        pending: IntArray | None = None   # None: all of the group
        for _ in range(MAX_LAYOUTS):
            first = 0 if pending is None else (int(pending[0]) if pending.size else -1)
            if first < 0:
                break
            try:
                entries = _layout(leaves, rows[first])
            except (ValueError, IndexError):
                odd.append(int(group[first]))
                pending = (np.arange(1, group.size) if pending is None else pending[1:])
                continue
            checks = _checks(entries)
            if pending is None:
                same = np.all(rows[:, checks] == rows[first, checks], axis=1)
                members = np.flatnonzero(same)
                pending = np.flatnonzero(~same)
            else:
                same = np.all(rows[pending][:, checks] == rows[first, checks], axis=1)
                members, pending = pending[same], pending[~same]
            parts.append((group[members], _read(leaves, msgtype, entries, rows, members,
                                                size, wanted)))
        else:
            if pending is not None:
                odd += group[pending].tolist()
    for odd_index in odd:
        raw = bytes(data[offsets[odd_index]:offsets[odd_index] + sizes[odd_index]])
        try:
            message = store.deserialize_cdr(raw, msgtype)
        except DECODE_ERRORS:
            continue
        parts.append((np.array([odd_index], dtype=np.int64), _from_object(out_leaves, msgtype,
                                                                          message)))
    if not parts:
        return _empty_table(out_leaves, msgtype, 0), np.zeros(0, dtype=np.int64)
    index = np.concatenate([p[0] for p in parts])
    table = concat([p[1] for p in parts])
    if index.size > 1 and not np.all(index[1:] > index[:-1]):
        order = np.argsort(index, kind='stable')
        table, index = table.take(order), index[order]
    return table, index


def _gather(data: UInt8Array, offsets: IntArray, size: int) -> UInt8Array:
    """The messages at ``offsets`` (ascending, ``size`` bytes each) as rows: a view where they
    lie at one stride (a topic's messages in a chunk usually do), else copied out."""
    n = int(offsets.size)
    if size == 0:
        return np.zeros((n, 0), dtype=np.uint8)
    steps = np.diff(offsets)
    if n == 1 or (steps[0] >= size and np.all(steps == steps[0])):
        stride = int(steps[0]) if n > 1 else size
        return np.lib.stride_tricks.as_strided(data[int(offsets[0]):], shape=(n, size),
                                               strides=(stride, 1), writeable=False)
    if np.all(steps >= size):   # in order, not overlapping: the bytes they cover, in one go
        start = int(offsets[0])
        return data[start:int(offsets[-1]) + size][_covered(offsets - start, size, int(
            offsets[-1]) + size - start)].reshape(n, size)
    copied: UInt8Array = data[offsets[:, None] + np.arange(size)]
    return copied


def _covered(starts: IntArray, size: int, total: int) -> npt.NDArray[np.bool_]:
    """A mask of the bytes ``starts[i] .. starts[i] + size - 1`` (ascending, apart)."""
    delta = np.zeros(total + 1, dtype=np.int8)
    delta[starts] = 1
    delta[starts + size] -= 1
    return np.cumsum(delta[:total], dtype=np.int8).view(np.bool_)


def _read(leaves: Sequence[Field], msgtype: str, entries: Sequence[Entry],
          rows: UInt8Array, members: IntArray, size: int,
          wanted: frozenset[str] | None = None) -> Table:
    """The messages ``rows[members]`` (each ``size`` bytes, of one layout) as a table (of the
    ``wanted`` fields only, where given)."""
    n = int(members.size)
    dtype, picked = _structured(leaves, entries, size)
    picked_rows = rows if n == rows.shape[0] else rows[members]
    if not size:
        view = np.zeros(n, dtype=dtype)
    elif picked_rows.strides[1] == 1:   # a view: the fields are copied out, not the rows
        view = picked_rows.view(dtype).reshape(n)
    else:
        view = np.ascontiguousarray(picked_rows).view(dtype).reshape(n)
    table = _empty_table([f for f in leaves if wanted is None or f.path in wanted], msgtype, n)
    strings: dict[int, list[np.ndarray[Any, Any]]] = {}
    for index, _, name, count in picked:
        leaf = leaves[index]
        if wanted is not None and leaf.path not in wanted:
            continue
        if leaf.kind in ('value', 'string', 'array'):
            if name:   # else (none of it in the layout) as _empty_table left it
                table.columns[leaf.path] = view[name].copy()
        elif leaf.kind == 'sequence':
            table.lengths[leaf.path] = np.full(n, count, dtype=np.int64)
            table.columns[leaf.path] = (np.ascontiguousarray(view[name]).reshape(-1) if name
                                        else np.zeros(0, dtype=leaf.dtype))
        else:
            strings.setdefault(index, []).append(view[name] if name
                                                 else np.zeros(n, dtype='S1'))
    for index, leaf in enumerate(leaves):
        if leaf.kind != 'strings' or (wanted is not None and leaf.path not in wanted):
            continue
        elements = strings.get(index, [])
        table.lengths[leaf.path] = np.full(n, len(elements), dtype=np.int64)
        if elements:
            width = max(e.dtype.itemsize for e in elements)
            table.columns[leaf.path] = np.stack(
                [e.astype(f'S{width}') for e in elements], axis=1).reshape(-1)
        else:
            table.columns[leaf.path] = np.zeros(0, dtype='S1')
    return table


def _from_object(leaves: Sequence[Field], msgtype: str, message: Any) -> Table:
    """One message deserialised by rosbags as a table of one row."""
    table = Table(msgtype, 1)
    for leaf in leaves:
        value = message
        for part in leaf.path.split('.'):
            value = getattr(value, part)
        if leaf.kind == 'value':
            table.columns[leaf.path] = np.array([value], dtype=leaf.dtype)
        elif leaf.kind == 'string':
            table.columns[leaf.path] = np.array([str(value).encode()], dtype='S')
        elif leaf.kind == 'array':
            table.columns[leaf.path] = np.asarray(value, dtype=leaf.dtype).reshape(1, -1)
        elif leaf.kind == 'sequence':
            values = np.asarray(value, dtype=leaf.dtype).reshape(-1)
            table.columns[leaf.path] = values
            table.lengths[leaf.path] = np.array([values.size], dtype=np.int64)
        else:
            texts = [str(v).encode() for v in value]
            table.columns[leaf.path] = np.array(texts, dtype='S') if texts else \
                np.zeros(0, dtype='S1')
            table.lengths[leaf.path] = np.array([len(texts)], dtype=np.int64)
    return table


def concat(tables: Sequence[Table]) -> Table:
    """Tables of one type, one after the other: the columns they all have (strings to the
    widest)."""
    if len(tables) == 1:
        return tables[0]
    out = Table(tables[0].msgtype, sum(t.count for t in tables))
    for path in tables[0].columns:
        if not all(path in t.columns for t in tables):
            continue
        parts = [t.columns[path] for t in tables]
        if parts[0].dtype.kind == 'S':
            width = max(p.dtype.itemsize for p in parts)
            parts = [p.astype(f'S{width}') for p in parts]
        out.columns[path] = np.concatenate(parts)
        if path in tables[0].lengths:
            out.lengths[path] = np.concatenate([t.lengths[path] for t in tables])
    return out


class TableBuilder:
    """Tables of one type appended chunk by chunk into arrays that grow (by half again when
    full: no list of pieces, no copy of everything at the end). ``expected``: the number of
    messages to make room for at once (the session's count, when it is known); ``keep``: the
    field paths to keep (default all)."""

    def __init__(self, leaves: Sequence[Field], msgtype: str, expected: int = 0,
                 keep: Iterable[str] | None = None) -> None:
        kept = None if keep is None else set(keep)
        self.leaves = tuple(leaf for leaf in leaves if kept is None or leaf.path in kept)
        self.msgtype = msgtype
        self.count = 0
        self._expected = max(expected, 1)
        self._columns: dict[str, np.ndarray[Any, Any]] = {}
        self._filled: dict[str, int] = {}

    def _room(self, path: str, like: np.ndarray[Any, Any], need: int, rows: int) -> None:
        have = self._columns.get(path)
        width = like.dtype.itemsize if like.dtype.kind == 'S' else 0
        if have is not None and have.dtype.kind == 'S' and width > have.dtype.itemsize:
            have = self._columns[path] = have.astype(f'S{width}')
        if have is not None and have.shape[0] >= need:
            return
        capacity = max(need, rows if have is None else int(have.shape[0] * 1.5) + 16)
        grown = np.zeros((capacity, *like.shape[1:]),
                         dtype=like.dtype if have is None else have.dtype)
        if have is not None:
            used = self._filled[path]
            grown[:used] = have[:used]
        self._columns[path] = grown
        self._filled.setdefault(path, 0)

    def append(self, table: Table) -> None:
        n = table.count
        for leaf in self.leaves:
            values = table.columns[leaf.path]
            path = leaf.path
            if path in table.lengths:
                counts = table.lengths[path]
                per = int(counts[0]) if n and np.all(counts == counts[0]) else 1
                self._room(path, values, self._filled.get(path, 0) + values.shape[0],
                           self._expected * max(per, 1))
                self._room(path + '#', counts, self.count + n, self._expected)
                self._put(path + '#', counts)
            else:
                self._room(path, values, self.count + n, self._expected)
            self._put(path, values)
        self.count += n

    def _put(self, path: str, values: np.ndarray[Any, Any]) -> None:
        at = self._filled.get(path, 0)
        self._columns[path][at:at + values.shape[0]] = values
        self._filled[path] = at + values.shape[0]

    def finish(self) -> Table:
        """What was appended (views of the grown arrays)."""
        if not self.count:
            return _empty_table(self.leaves, self.msgtype, 0)
        table = Table(self.msgtype, self.count)
        for leaf in self.leaves:
            path = leaf.path
            table.columns[path] = self._columns[path][:self._filled[path]]
            if leaf.kind in ('sequence', 'strings'):
                table.lengths[path] = self._columns[path + '#'][:self.count]
        return table


def encode(store: Typestore, msgtype: str, columns: Mapping[str, Any], count: int,
           ) -> tuple[bytes, IntArray]:
    """``count`` messages of ``msgtype`` from columns as a :class:`Table` holds them (a
    sequence may also be given as a 2-D array, one row per message; a primitive or a string
    may be one value for all; a field not given is zero, empty), serialised as rosbags'
    ``serialize_cdr`` does (little-endian). Returns all the bytes and the offsets (count + 1)
    of each message in them."""
    leaves = fields(store, msgtype)
    values: dict[str, np.ndarray[Any, Any]] = {}
    counts: dict[str, IntArray] = {}
    for leaf in leaves:
        given = columns.get(leaf.path)
        if leaf.kind in ('value', 'string'):
            dtype = leaf.dtype if leaf.kind == 'value' else np.dtype('S')
            if given is None:
                given = b'' if leaf.kind == 'string' else 0
            if isinstance(given, str):
                given = given.encode()
            array = np.asarray(given, dtype=dtype)
            values[leaf.path] = np.broadcast_to(array, (count,)) if array.ndim == 0 else array
        elif leaf.kind == 'array':
            array = np.zeros((count, leaf.size), leaf.dtype) if given is None else \
                np.asarray(given, dtype=leaf.dtype)
            values[leaf.path] = np.broadcast_to(array, (count, leaf.size))
        else:
            dtype = leaf.dtype if leaf.kind == 'sequence' else np.dtype('S')
            if given is None:
                array = np.zeros((count, 0), dtype=dtype)
            elif isinstance(given, tuple):   # (flat values, lengths)
                array, lengths = np.asarray(given[0], dtype=dtype), np.asarray(given[1])
                values[leaf.path], counts[leaf.path] = array, lengths.astype(np.int64)
                continue
            else:
                array = np.asarray(given, dtype=dtype)
                if array.ndim == 1:
                    array = np.broadcast_to(array, (count, array.size))
            counts[leaf.path] = np.full(count, array.shape[1], dtype=np.int64)
            values[leaf.path] = array.reshape(-1)
    # Each message's shape: its strings' byte lengths and its sequences' counts.
    shape_columns = []
    string_lengths: dict[str, IntArray] = {}
    for leaf in leaves:
        if leaf.kind == 'string':
            lengths = np.char.str_len(values[leaf.path]).astype(np.int64) \
                if count else np.zeros(0, np.int64)
            string_lengths[leaf.path] = lengths
            shape_columns.append(lengths)
        elif leaf.kind in ('sequence', 'strings'):
            shape_columns.append(counts[leaf.path])
            if leaf.kind == 'strings':
                lengths = np.char.str_len(values[leaf.path]).astype(np.int64) \
                    if values[leaf.path].size else np.zeros(0, np.int64)
                string_lengths[leaf.path] = lengths
    starts = {path: np.concatenate([[0], np.cumsum(c)])[:-1] for path, c in counts.items()}
    uniform = {path: bool(np.all(c == c[0])) if c.size else True for path, c in counts.items()}
    group_of = _group_ids(shape_columns, count)
    # Sequences of strings vary inside a shape: their element lengths join the key.
    uniform_strings = all(uniform[leaf.path] for leaf in leaves if leaf.kind == 'strings')
    if uniform_strings and count:   # as many strings each: their lengths as columns
        columns_of_lengths = [group_of]
        for leaf in leaves:
            if leaf.kind == 'strings':
                per = string_lengths[leaf.path].reshape(count, -1)
                columns_of_lengths += [per[:, j] for j in range(per.shape[1])]
        group_of = _group_ids(columns_of_lengths, count)
    elif any(leaf.kind == 'strings' for leaf in leaves) and count:
        detail = []
        for leaf in leaves:
            if leaf.kind == 'strings':
                detail.append([tuple(string_lengths[leaf.path][s:s + c].tolist()) for s, c in
                               zip(starts[leaf.path].tolist(), counts[leaf.path].tolist(),
                                   strict=True)])
        combined = list(zip(group_of.tolist(), *detail, strict=True))
        unique = {key: k for k, key in enumerate(dict.fromkeys(combined))}
        group_of = np.array([unique[c] for c in combined], dtype=np.int64)
    groups = int(group_of.max()) + 1 if count else 0
    sizes = np.zeros(count, dtype=np.int64)
    pieces: list[tuple[IntArray, np.ndarray[Any, Any]]] = []
    for group in range(groups):
        members = np.flatnonzero(group_of == group) if groups > 1 else np.arange(count)
        if not members.size:
            continue
        first = int(members[0])
        entries, end = _shape_layout(leaves, first, values, counts, starts, string_lengths)
        size = 4 + end
        dtype, picked = _structured(leaves, entries, size)
        out = np.zeros(members.size, dtype=dtype)
        raw = out.view(np.uint8).reshape(members.size, size)
        raw[:, 1] = 1
        for _, _, what, offset, value in entries:
            if what == 'n':
                raw[:, 4 + offset:8 + offset] = np.frombuffer(
                    struct.pack('<I', value), dtype=np.uint8)
        for index, element, name, n_values in picked:
            if not name:
                continue
            leaf = leaves[index]
            column = values[leaf.path]
            if leaf.kind in ('value', 'string', 'array'):
                out[name] = column[members]
            elif leaf.kind == 'sequence':
                if uniform[leaf.path]:   # every message has as many
                    out[name] = column.reshape(count, n_values)[members] \
                        if members.size < count else column.reshape(count, n_values)
                else:
                    out[name] = column[starts[leaf.path][members][:, None]
                                       + np.arange(n_values)]
            else:
                out[name] = column[starts[leaf.path][members] + element]
        sizes[members] = size
        pieces.append((members, raw))
    offsets = np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64)
    if len(pieces) == 1:
        return pieces[0][1].tobytes(), offsets
    buffer = np.zeros(int(offsets[-1]), dtype=np.uint8)
    for members, raw in pieces:
        buffer[_covered(offsets[members], raw.shape[1], buffer.size)] = raw.reshape(-1)
    return buffer.tobytes(), offsets


def _group_ids(columns: Sequence[IntArray], count: int) -> IntArray:
    """A group number per message, the same for the same values in every column."""
    key = np.zeros(count, dtype=np.int64)
    for column in columns:
        if count and np.all(column == column[0]):
            continue
        values, inverse = np.unique(column, return_inverse=True)
        key = key * values.size + inverse.reshape(-1)
        _, key = np.unique(key, return_inverse=True)   # small again, never overflowing
        key = key.reshape(-1).astype(np.int64)
    return key


def _shape_layout(leaves: Sequence[Field], k: int, values: Mapping[str, Any],
                  counts: Mapping[str, IntArray], starts: Mapping[str, IntArray],
                  string_lengths: Mapping[str, IntArray]) -> tuple[list[Entry], int]:
    """The layout of message ``k`` from its strings' lengths and sequences' counts, and its
    end (as :func:`_walk`)."""
    lengths: list[int] = []
    for leaf in leaves:
        if leaf.kind == 'string':
            lengths.append(int(string_lengths[leaf.path][k]) + 1)
        elif leaf.kind == 'sequence':
            lengths.append(int(counts[leaf.path][k]))
        elif leaf.kind == 'strings':
            c, s = int(counts[leaf.path][k]), int(starts[leaf.path][k])
            lengths.append(c)
            lengths += [int(v) + 1 for v in string_lengths[leaf.path][s:s + c]]
    given = iter(lengths)
    return _walk(leaves, lambda pos: next(given), 1 << 62)

