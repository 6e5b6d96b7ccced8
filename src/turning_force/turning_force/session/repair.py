"""``turning-force repair BAG``: a session rebuilt from what its MCAP file still holds.

For a recording that was killed (SIGKILL, a power cut), whose disk filled, or whose file was
cut short or damaged since: every complete chunk is read (:func:`scan_mcap`), its messages are
written to a new, closed MCAP file (summary, index, CRCs), and ``metadata.yaml`` is rebuilt with
the real message counts and the session's custom data (the experiment, the parameters, the
versions: from the old ``metadata.yaml``, which the recorder writes at its start, or from the
MCAP's own rosbag2 record). The old file is kept beside it as ``<name>.damaged``, the old
``metadata.yaml`` as ``metadata.yaml.before_repair`` (``.2``, ``.3`` ... after the first
repair: nothing is overwritten). Nothing outside the session folder is read or renamed: a
``metadata.yaml`` naming a file elsewhere is refused. What was recovered and what was lost is
recorded (``turning_force.repair_json``), and reading the session says so on every read.
"""

from __future__ import annotations

import contextlib
import shutil
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml
from mcap.records import Message
from rosbags.typesys import TypesysError
from rosbags.typesys.store import Typestore

from turning_force.session.bag import (
    CUSTOM_RECORDING,
    CUSTOM_REPAIR,
    BagError,
    SessionWriter,
    dumps,
)
from turning_force.session.reader import (
    DECODE_ERRORS,
    inside,
    read_metadata,
    read_recording,
    session_typestore,
)
from turning_force.session.scan import McapScan, scan_mcap

__all__ = ['RepairResult', 'repair']


@dataclass(frozen=True)
class RepairResult:
    """What a repair did: ``recovered`` messages per topic, ``recorded`` what the session had
    counted (None for a recording that never closed), ``damage`` what could not be read.
    ``repaired`` is False when there was nothing to repair."""

    path: Path
    repaired: bool
    recovered: dict[str, int]
    recorded: dict[str, int] | None
    damage: list[str]
    summary: str
    kept: list[str] = field(default_factory=list)   # the files replaced, kept under these names


def _old_metadata(path: Path) -> tuple[dict[str, str], dict[str, int] | None, str | None]:
    """(custom data, counts if final, the .mcap it names) from the old metadata.yaml, if any."""
    try:
        info, custom, topics = read_metadata(path)
    except BagError:
        return {}, None, None
    files = info.get('relative_file_paths') or []
    name = str(files[0]) if isinstance(files, list) and len(files) == 1 else None
    counts = {n: t.count for n, t in topics.items() if t.count is not None}
    return custom, None if CUSTOM_RECORDING in custom else counts, name


def _mcap_file(path: Path, named: str | None) -> Path:
    if named is not None:
        mcap = inside(path, named, 'metadata.yaml names')   # never a file outside the folder
        if mcap.is_file():
            return mcap
    found = sorted(path.glob('*.mcap'))
    if len(found) != 1:
        raise BagError(f'{path}: {len(found)} .mcap files and no metadata.yaml naming one: '
                       'nothing to repair from' if not found else
                       f'{path}: {", ".join(f.name for f in found)}: which one is the session?')
    return found[0]


def kept_name(path: Path, suffix: str) -> Path:
    """Where a file about to be replaced is kept: ``NAME.SUFFIX`` beside it, or
    ``NAME.SUFFIX.2``, ``.3`` ... where an earlier repair kept one (never overwritten)."""
    keep = path.with_name(f'{path.name}.{suffix}')
    n = 2
    while keep.exists() or keep.is_symlink():
        keep = path.with_name(f'{path.name}.{suffix}.{n}')
        n += 1
    return keep


def _custom_from_mcap(scan: McapScan) -> dict[str, str]:
    """The custom data rosbag2 embeds in the MCAP's own metadata record (written at close)."""
    try:
        info = yaml.safe_load(scan.metadata['rosbag2']['serialized_metadata'])
        return {str(k): str(v) for k, v in (info.get('custom_data') or {}).items()}
    except (KeyError, TypeError, AttributeError, yaml.YAMLError):
        return {}


def _currents_span(messages: list[Message], channels: dict[int, tuple[str, str]],
                   store: Typestore) -> str:
    """The time the recovered servo/currents blocks cover, from their header stamps."""
    stamps = []
    for message in messages:
        topic, msgtype = channels.get(message.channel_id, ('', ''))
        if topic.endswith('servo/currents'):
            msg: Any = store.deserialize_cdr(message.data, msgtype)
            start = msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9
            stamps.append((start, start + len(msg.phase_u_a) * msg.sample_period_s))
    if not stamps:
        return 'no servo/currents block'
    return (f'servo/currents {len(stamps)} blocks, {min(s for s, _ in stamps):.3f}-'
            f'{max(e for _, e in stamps):.3f} s')


def repair(path: str | Path) -> RepairResult:
    """Rebuild the session folder ``path`` from what its MCAP file holds (module docstring)."""
    path = Path(path)
    if not path.is_dir():
        raise BagError(f'{path}: not a session folder')
    custom, recorded, named = _old_metadata(path)
    mcap = _mcap_file(path, named)
    try:
        scan = scan_mcap(mcap)
    except OSError as exc:
        raise BagError(f'{mcap}: cannot read: {exc.strerror or exc}') from exc
    if recorded is not None and not scan.damage:
        try:
            complete = read_recording(path)
        except BagError:
            pass
        else:
            if not complete.missing:
                total = sum(len(m) for m in complete.messages.values())
                return RepairResult(path, False, {t: len(m) for t, m in
                                                  complete.messages.items()},
                                    recorded, [], f'nothing to repair: all {total} recorded '
                                    'messages are there')
    channels: dict[int, tuple[str, str]] = {}
    definitions: dict[str, tuple[str, str, str]] = {}   # the types as the file defines them
    for index, channel in sorted(scan.channels.items()):
        schema = scan.schemas.get(channel.schema_id)
        if schema is not None:
            with contextlib.suppress(UnicodeDecodeError):
                definitions[channel.topic] = (schema.name, schema.encoding,
                                              schema.data.decode())
                channels[index] = (channel.topic, schema.name)
    try:
        store = session_typestore(tuple(sorted(set(definitions.values()))))
    except (TypesysError, ValueError, IndexError) as exc:
        raise BagError(f'{mcap}: the message definitions in it are unreadable: {exc}') from exc
    kept: list[Message] = []
    undecodable: Counter[str] = Counter()
    for message in scan.messages:
        if message.channel_id not in channels:
            continue
        topic, msgtype = channels[message.channel_id]
        try:   # a message that cannot be decoded is damage, not data
            store.deserialize_cdr(message.data, msgtype)
        except DECODE_ERRORS:
            undecodable[topic] += 1
            continue
        kept.append(message)
    damage = [*scan.damage, *(f'{n} {topic} messages that cannot be decoded left out'
                              for topic, n in undecodable.items())]
    if not kept:
        raise BagError(f'{mcap}: no message can be recovered '
                       f'({"; ".join(damage) or "the file holds none"})')
    custom = {**_custom_from_mcap(scan), **custom}
    custom.pop(CUSTOM_RECORDING, None)
    custom.pop(CUSTOM_REPAIR, None)

    recovered = dict.fromkeys(sorted({topic for topic, _ in channels.values()}), 0)
    for message in kept:
        recovered[channels[message.channel_id][0]] += 1
    read, total = sum(recovered.values()), sum((recorded or {}).values())
    span = _currents_span(kept, channels, store)
    summary = (f'{read} of {total} recorded messages recovered ({span})' if recorded is not None
               else f'{read} messages recovered ({span}) from a recording that was never '
               'closed; what it held after them is lost')
    if damage:
        summary += f'; unreadable: {"; ".join(damage[:3])}'
    report = {'summary': summary, 'file': mcap.name, 'recovered': dict(recovered),
              'recorded': recorded, 'damage': damage}

    work = path.parent / f'.{path.name}.repair'
    if work.exists():
        shutil.rmtree(work)
    work.mkdir()
    try:
        fresh = work / path.name
        writer = SessionWriter(fresh)
        for key, value in custom.items():
            writer.set_custom_data(key, value)
        writer.set_custom_data(CUSTOM_REPAIR, dumps(report))
        for topic, msgtype in dict.fromkeys(channels.values()):
            writer.add_topic(topic, msgtype, (definitions[topic][2], store.hash_rihs01(msgtype)))
        for message in kept:
            writer.write(channels[message.channel_id][0], message.log_time, message.data)
        writer.close()
        # Every file replaced is kept beside it: the old .mcap, and metadata.yaml (however
        # garbled: the only record of what it said).
        kept_files = [kept_name(mcap, 'damaged')]
        mcap.replace(kept_files[0])
        metadata = path / 'metadata.yaml'
        if metadata.exists() or metadata.is_symlink():
            kept_files.append(kept_name(metadata, 'before_repair'))
            metadata.replace(kept_files[-1])
        (fresh / f'{path.name}.mcap').replace(path / f'{path.name}.mcap')
        (fresh / 'metadata.yaml').replace(metadata)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    return RepairResult(path, True, dict(recovered), recorded, damage, summary,
                        [k.name for k in kept_files])

