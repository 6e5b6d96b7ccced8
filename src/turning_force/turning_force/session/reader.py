"""Reading a recorded session back: the signals as arrays, the experiment it ran.

Topics are found by their relative name, whatever namespace the graph ran in
(``/lathe1/servo/currents`` is ``servo/currents``). Signals are aligned per control block: the
``k``-th block of currents, the estimate, command and override that answered it (matched by
header stamp), and the simulator's truth for it. The cut log (``pmc/cuts``) is read as it was
recorded, one record per cut.

Nothing is lost without a word. The MCAP file is read record by record
(:mod:`turning_force.session.scan`), and what was read is checked against what the session
says it holds: ``metadata.yaml``'s message count of every topic, and the stamps of
``servo/currents``, one block after the other with no gap (a DAQ block every control period).
A session that falls short is a :class:`BagError` naming the bag and what is missing; a caller
that accepts a partial session (``partial=True``, ``--partial`` on the command line) gets what
is there and :attr:`Session.warning` saying how much is missing, which the command prints.
A session rebuilt by ``turning-force repair`` reads without ``partial``, with that warning.
A damaged file from which nothing was lost (a torn summary: every message counted) reads with
a warning too.

Every session read says how whole it is (:class:`Wholeness`): whole, ended early (closed
cleanly before its planned count of blocks), killed (never closed) or damaged, with the count
of blocks; chunks without a CRC are named as unverifiable. The settings come from the
``session/settings`` topic where the session has it (``metadata.yaml``'s custom data is a copy,
which bag tools drop), and only files inside the session folder are read (:func:`inside`).
"""

from __future__ import annotations

import dataclasses
import json
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass, field
from functools import cache, cached_property
from pathlib import Path
from typing import Any, cast

import numpy as np
import numpy.typing as npt
import yaml
from rosbags.interfaces import Nodetype
from rosbags.typesys import (
    Stores,
    TypesysError,
    get_types_from_idl,
    get_types_from_msg,
    get_typestore,
)
from rosbags.typesys.store import Typestore

from turning_force.core.errors import ConfigError, shortened
from turning_force.core.experiment import Experiment, build_experiment, parse_experiment
from turning_force.core.kernel.batch import CurrentArrays, InputArrays
from turning_force.core.metrics import compute_metrics
from turning_force.core.plant.drive import CurrentBlock
from turning_force.core.pmc.shopfloor import CutRecord, InputValues
from turning_force.session import codec
from turning_force.session.bag import (
    CUSTOM_END,
    CUSTOM_EXPERIMENT,
    CUSTOM_PARAMETERS,
    CUSTOM_PLANNED,
    CUSTOM_RECORDING,
    CUSTOM_REPAIR,
    CUSTOM_VERSIONS,
    GRAPH_TYPES,
    SETTINGS_TOPIC,
    SETTINGS_TYPE,
    BagError,
    typestore,
)
from turning_force.session.codec import DECODE_ERRORS, Table, TableBuilder
from turning_force.session.scan import McapScan, MessageSink, scan_mcap

__all__ = ['DAMAGED', 'DECODE_ERRORS', 'ENDED_EARLY', 'KILLED', 'WHOLE', 'Recording', 'Session',
           'TopicInfo', 'Wholeness', 'applied_overrides', 'estimate_metrics', 'inside',
           'is_settings', 'read_metadata', 'read_recording', 'read_session', 'recorded_metrics',
           'recorded_reachable', 'session_typestore', 'settings_data', 'wholeness']

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]

ANSWERS = ('force/estimate', 'control/feed_command', 'pmc/feed_override', 'sim/cutting_state')
READ = ('servo/currents', *ANSWERS, 'pmc/cuts')
MSGTYPES = {topic: GRAPH_TYPES[topic] for topic in ('servo/currents', *ANSWERS)}
# Each signal of a session (per block, NaN where no message answers it): the answering topic
# and the field it comes from. The decision's inputs and outputs are NaN in sessions recorded
# before FeedOverride carried them.
SIGNALS: dict[str, tuple[str, str]] = {
    'estimated_force_n': ('force/estimate', 'force_n'),
    'estimated_force_rate_n_s': ('force/estimate', 'force_rate_n_s'),
    'estimate_status': ('force/estimate', 'status'),
    'requested_override_pct': ('control/feed_command', 'override_pct'),
    'reference_n': ('control/feed_command', 'reference_force_n'),
    'sliding_variable': ('control/feed_command', 'sliding_variable'),
    'reference_reachable': ('control/feed_command', 'reference_reachable'),
    'answered_override_pct': ('pmc/feed_override', 'applied_pct'),
    'override_reason': ('pmc/feed_override', 'reason'),
    'program_enable': ('pmc/feed_override', 'program_enable'),
    'threading': ('pmc/feed_override', 'threading'),
    'operator_dial_pct': ('pmc/feed_override', 'operator_dial_pct'),
    'engaged': ('pmc/feed_override', 'engaged'),
    'alarm': ('pmc/feed_override', 'alarm'),
    'stop_request': ('pmc/feed_override', 'stop_request'),
    'tool_number': ('pmc/feed_override', 'tool_number'),
    'force_n': ('sim/cutting_state', 'force_n'),
    'depth_mm': ('sim/cutting_state', 'depth_of_cut_mm'),
    'feed_mm_rev': ('sim/cutting_state', 'feed_mm_rev'),
    'applied_override_pct': ('sim/cutting_state', 'override_pct'),
}
# The fields decoded of the answers: their stamps, the signals' and the bridge's armed flag;
# servo/currents and pmc/cuts are kept whole.
STAMP = ('header.stamp.sec', 'header.stamp.nanosec')
KEPT = {topic: (*STAMP, *(f for t, f in SIGNALS.values() if t == topic),
                *(('armed',) if topic == 'pmc/feed_override' else ())) for topic in ANSWERS}
SAFE_LOADER = getattr(yaml, 'CSafeLoader', yaml.SafeLoader)   # libyaml's where installed
SHOWN = 3   # damaged stretches and gaps named in one line; the rest are counted


def _topic(name: str) -> str:
    """The relative topic name: strip any namespace in front of the graph's names."""
    for relative in READ:
        if name.endswith('/' + relative) or name == relative:
            return relative
    return name


def _listed(items: list[str]) -> str:
    shown = '; '.join(items[:SHOWN])
    return shown + (f'; and {len(items) - SHOWN} more' if len(items) > SHOWN else '')


@dataclass(frozen=True)
class TopicInfo:
    """A topic as ``metadata.yaml`` lists it; ``count`` is None while a recording is open."""

    name: str
    msgtype: str
    count: int | None
    type_hash: str


@dataclass
class Recording:
    """The raw messages of a session folder, checked against what the session says it holds.

    ``messages`` maps each topic (its full name) to its (log time [ns], CDR bytes) in file
    order (empty where the session was streamed: :func:`read_session`); ``counts`` how many
    messages of each were read. ``missing`` says what is known to be missing or unreadable,
    one phrase each; ``damage`` what is damaged in the MCAP file ``file`` (which loses
    messages only where ``missing`` says so); ``note`` what a repair recorded;
    ``definitions`` each topic's message definition in the file (type, encoding, text).
    :meth:`check` turns them into an error or a warning.
    """

    path: Path
    custom_data: dict[str, str]
    topics: dict[str, TopicInfo]
    messages: dict[str, list[tuple[int, bytes]]]
    missing: list[str] = field(default_factory=list)
    damage: list[str] = field(default_factory=list)
    note: str = ''
    file: str = ''
    definitions: dict[str, tuple[str, str, str]] = field(default_factory=dict)
    counts: dict[str, int] = field(default_factory=dict)   # messages read, per topic

    def recorded(self, relative: str) -> int | None:
        """How many messages of a topic (by its relative name) were recorded, if known."""
        counts = [t.count for name, t in self.topics.items() if _topic(name) == relative]
        return None if None in counts or not counts else sum(c or 0 for c in counts)

    def check(self, partial: bool, extra: Sequence[str] = (), state: str = '') -> str:
        """Raise the :class:`BagError` that says what is missing, unless ``partial`` or the
        session was repaired (what it lacks is known then); return the warning to print
        (empty if there is nothing to say). ``state`` (:class:`Wholeness`) heads the text."""
        missing = [*extra, *self.missing]
        if missing:
            text = f'{self.path}: {state + ": " if state else ""}{_listed(missing)}'
            if self.damage:
                text += f'; {self.file}: {_listed(self.damage)}'
            if not partial and not self.note:
                raise BagError(f'{text}. `turning-force repair {self.path}` keeps what can be '
                               'read; --partial reads it as it is')
            return f'partial session: {text}' + (f'; {self.note}' if self.note else '')
        warning = []
        if self.note:
            warning.append(f'{self.path}: {self.note}')
        if self.damage:
            warning.append(f'{self.path}: {self.file} is damaged ({_listed(self.damage)}) '
                           f'but every recorded message was read; `turning-force repair '
                           f'{self.path}` rewrites it')
        return '; '.join(warning)


WHOLE, ENDED_EARLY, KILLED, DAMAGED = 'whole', 'ended early', 'killed', 'damaged'


@dataclass(frozen=True)
class Wholeness:
    """How whole a session is, one of four states:

    - ``whole``: closed cleanly, every recorded message read (and every planned block, for a
      run with a plan);
    - ``ended early``: closed cleanly, but stopped before its plan (by the user or a signal it
      caught): ``blocks`` of ``planned``;
    - ``killed``: never closed (SIGKILL, a power cut, a full disk): what the complete chunks
      hold, ``blocks``; what the recorder wrote after them (at most one chunk) is lost;
    - ``damaged``: closed, but CRC or structure errors in its file, or fewer messages than it
      recorded: ``lost`` says what.

    ``unverified`` of ``chunks`` carry no CRC (written by a tool that does not compute one):
    their bytes cannot be checked, which every state mentions.
    """

    state: str
    blocks: int
    planned: int | None = None
    recorded: int | None = None   # the servo/currents blocks the recorder counted
    stopped_by: str | None = None
    lost: tuple[str, ...] = ()
    chunks: int = 0
    unverified: int = 0
    repaired: bool = False

    def line(self) -> str:
        """One phrase, beginning with the state."""
        of = f' of {self.planned} planned' if self.planned is not None else ''
        if self.state == ENDED_EARLY:
            text = (f'ended early: stopped by {self.stopped_by or "its recorder"} after '
                    f'{self.blocks}{of} blocks (closed cleanly)')
        elif self.state == KILLED:
            text = (f'killed: never closed; the complete chunks hold {self.blocks}{of} blocks, '
                    'and what was recorded after them (at most one chunk) is lost')
        elif self.state == DAMAGED:
            text = (f'damaged: {self.blocks}{of} blocks read'
                    + (f'; {_listed(list(self.lost))}' if self.lost else ''))
        elif self.unverified:   # nothing can tell a changed byte in those chunks
            text = f'whole as far as can be told (unverifiable): {self.blocks}{of} blocks'
        else:
            text = f'whole: {self.blocks}{of} blocks'
        if self.repaired:
            text += ' (repaired)'
        if self.unverified:
            text += (f'; {self.unverified} of {self.chunks} chunks carry no CRC: their bytes '
                     'cannot be verified')
        return text

    def to_json(self) -> dict[str, Any]:
        return {'state': self.state, 'blocks': self.blocks, 'planned': self.planned,
                'recorded': self.recorded, 'stopped_by': self.stopped_by, 'lost': list(self.lost),
                'chunks': self.chunks, 'unverified_chunks': self.unverified,
                'repaired': self.repaired, 'text': self.line()}


def _json_object(text: str | None) -> dict[str, Any] | None:
    try:
        value = json.loads(text) if text is not None else None
    except ValueError:
        return None
    return value if isinstance(value, dict) else None


def _count(value: Any) -> int | None:
    try:
        return None if value is None else int(value)
    except (TypeError, ValueError):
        return None


def wholeness(recording: Recording, scan: McapScan, blocks: int, problems: Sequence[str],
              settings_recorded: bool) -> Wholeness:
    """The :class:`Wholeness` of a session read: ``blocks`` of servo/currents read,
    ``problems`` what reading them found wrong (gaps, undecodable messages),
    ``settings_recorded`` whether the file holds a session/settings message."""
    custom = recording.custom_data
    end = _json_object(custom.get(CUSTOM_END))
    repair = _json_object(custom.get(CUSTOM_REPAIR))
    planned = _count(custom.get(CUSTOM_PLANNED))
    recorded = _count(end.get('blocks')) if end is not None else None
    if recorded is None:
        recorded = recording.recorded('servo/currents')
    killed = CUSTOM_RECORDING in custom or (end is None and (
        settings_recorded or (repair is not None and repair.get('recorded') is None)))
    lost = [*problems, *(m for m in recording.missing if 'never closed' not in m),
            *scan.damage]
    if not killed and recorded is not None and blocks < recorded:
        lost.insert(0, f'servo/currents {blocks} of {recorded} recorded blocks read')
    if not killed and repair is not None and repair.get('damage'):   # lost before the repair
        lost.append(shortened(str(repair.get('summary', 'repaired')), 200))
    stopped = end.get('stopped_by') if end is not None else None
    if killed:
        state = KILLED
    elif lost:
        state = DAMAGED
    elif stopped is not None or (planned is not None and blocks < planned):
        state = ENDED_EARLY
    else:
        state = WHOLE
    return Wholeness(state, blocks, planned, recorded if not killed else None,
                     str(stopped) if stopped is not None else None, tuple(lost), scan.chunks,
                     scan.unverified, repair is not None)


def read_metadata(path: Path) -> tuple[dict[str, Any], dict[str, str], dict[str, TopicInfo]]:
    """metadata.yaml: its rosbag2 information, custom data and topics (a :class:`BagError`
    of one line saying what is wrong with it, the bad value shortened)."""
    where = path / 'metadata.yaml'
    try:
        loaded = yaml.load(where.read_bytes(), Loader=SAFE_LOADER)
    except OSError as exc:
        raise BagError(f'{where}: cannot read: {exc.strerror or exc}') from exc
    except yaml.YAMLError as exc:
        mark = getattr(exc, 'problem_mark', None)
        at = f' at line {mark.line + 1}, column {mark.column + 1}' if mark is not None else ''
        problem = getattr(exc, 'problem', None) or exc
        raise BagError(f'{where}: not rosbag2 metadata: not YAML{at} '
                       f'({shortened(str(problem))})') from exc
    info = loaded.get('rosbag2_bagfile_information') if isinstance(loaded, dict) else None
    if not isinstance(info, dict):
        raise BagError(f'{where}: not rosbag2 metadata: no rosbag2_bagfile_information mapping '
                       f'(it holds {shortened(repr(loaded), 60)})')
    entry: Any = None
    try:
        custom = {str(k): str(v) for k, v in (info.get('custom_data') or {}).items()}
        recording = CUSTOM_RECORDING in custom
        topics = {}
        for entry in info.get('topics_with_message_count') or []:
            meta = entry['topic_metadata']
            name = str(meta['name'])
            topics[name] = TopicInfo(name, str(meta['type']),
                                     None if recording else int(entry['message_count']),
                                     str(meta.get('type_description_hash') or ''))
    except (KeyError, TypeError, ValueError, AttributeError) as exc:
        what = (f'the topic entry {shortened(repr(entry), 60)}' if entry is not None
                else 'custom_data or topics_with_message_count')
        raise BagError(f'{where}: not rosbag2 metadata: {what} is malformed') from exc
    return info, custom, topics


def _mcap_file(path: Path, info: dict[str, Any]) -> Path:
    storage = info.get('storage_identifier', 'mcap')
    if storage != 'mcap':
        raise BagError(f'{path}: storage {shortened(repr(storage), 40)}: turning_force '
                       'sessions are MCAP')
    files = info.get('relative_file_paths') or []
    if not isinstance(files, list) or len(files) != 1:
        raise BagError(f'{path}: metadata.yaml lists {shortened(repr(files), 60)}: a session '
                       'is one .mcap file')
    return inside(path, str(files[0]), 'metadata.yaml names')


def inside(path: Path, name: str, what: str) -> Path:
    """The file ``name`` of the session folder ``path``, which must be in it: a name with a
    folder in it (``../``, an absolute path) or a link out of the folder is refused, so that
    what reads or repairs a session touches nothing outside it. And the only .mcap there: a
    second one is refused (which is the session?)."""
    where = path / name
    if Path(name).name != name or name in ('', '.', '..') or \
            where.resolve().parent != path.resolve():
        raise BagError(f'{path}: {what} {shortened(repr(name), 200)}, which is not a file in the '
                       'session folder: refused (a session reads and rewrites only its own '
                       'files)')
    others = sorted(f.name for f in path.glob('*.mcap') if f.name != name)
    if others:
        raise BagError(f'{path}: {", ".join([name, *others][:4])}: more than one .mcap in the '
                       'session folder; a session is one .mcap (move the others out)')
    return where


def _open(path: Path) -> tuple[dict[str, Any], dict[str, str], dict[str, TopicInfo]]:
    """A session folder's metadata.yaml (a :class:`BagError` saying what the folder is if it
    has none)."""
    if not (path / 'metadata.yaml').is_file():
        found = sorted(path.glob('*.mcap')) if path.is_dir() else []
        if found:
            raise BagError(f'{path}: no metadata.yaml beside {found[0].name} (a recording '
                           f'killed before it wrote one): `turning-force repair {path}` '
                           'rebuilds it from what the file holds')
        raise BagError(f'{path}: not a rosbag2 folder (no metadata.yaml)')
    return read_metadata(path)


def _scan(mcap: Path, sink: MessageSink | None = None) -> McapScan:
    try:
        return scan_mcap(mcap, sink)
    except OSError as exc:
        raise BagError(f'{mcap}: cannot read the session: {exc.strerror or exc}') from exc


def read_recording(path: str | Path) -> Recording:
    """Every message a session folder holds, and what is missing from it (see
    :meth:`Recording.check`)."""
    path = Path(path)
    info, custom, topics = _open(path)
    scan = _scan(_mcap_file(path, info))
    settings = [m.data for m in scan.messages if is_settings(
        getattr(scan.channels.get(m.channel_id), 'topic', ''))]
    return _recording(path, {**custom, **settings_data(settings)[0]}, topics, scan)


def _recording(path: Path, custom: dict[str, str], topics: dict[str, TopicInfo],
               scan: McapScan) -> Recording:
    """What the scan read, checked against metadata.yaml (the messages themselves only where
    the scan kept them: without a sink)."""
    messages: dict[str, list[tuple[int, bytes]]] = {}
    counts: Counter[str] = Counter()
    definitions: dict[str, tuple[str, str, str]] = {}
    problems: list[str] = []
    for message in scan.messages:
        channel = scan.channels.get(message.channel_id)
        if channel is not None:
            messages.setdefault(channel.topic, []).append((message.log_time, message.data))
    for index, count in scan.counts.items():
        channel = scan.channels.get(index)
        if channel is not None:
            counts[channel.topic] += count
    for channel in scan.channels.values():
        schema = scan.schemas.get(channel.schema_id)
        recorded = topics.get(channel.topic)
        if recorded is None:
            problems.append(f'topic {channel.topic} is in the file, not in metadata.yaml')
            continue
        if schema is None or schema.name != recorded.msgtype:
            problems.append(f'{channel.topic} in the file is '
                            f'{schema.name if schema else "of no known type"}, '
                            f'metadata.yaml says {recorded.msgtype}')
            continue
        try:
            definitions[channel.topic] = (schema.name, schema.encoding, schema.data.decode())
        except UnicodeDecodeError:
            problems.append(f'{channel.topic}: its message definition in the file is damaged')
    recording = Recording(path, custom, topics, messages, definitions=definitions,
                          counts=dict(counts))
    if CUSTOM_RECORDING in custom:
        problems.append('the recording was never closed (the recorder was killed, or its '
                        'disk filled): metadata.yaml has no message counts to check against')
    else:
        short = []
        for name, topic in topics.items():
            got, expected = counts.get(name, 0), topic.count or 0
            if got < expected:
                short.append((name, got, expected))
            elif got > expected:
                problems.append(f'{name}: {got} messages where metadata.yaml counts {expected}')
        if short:
            total = sum(t.count or 0 for t in topics.values())
            read = sum(counts.values())
            shown = ', '.join(f'{_topic(n).lstrip("/")} {g} of {e}' for n, g, e in short)
            problems.append(f'{total - read} of {total} recorded messages missing ({shown})')
    recording.missing = problems
    recording.damage = list(scan.damage)
    recording.file = scan.path.name
    if CUSTOM_REPAIR in custom:
        recording.note = _repair_note(custom[CUSTOM_REPAIR])
    return recording


def is_settings(topic: str) -> bool:
    """Whether ``topic`` is the session's settings topic (in any namespace)."""
    return topic == SETTINGS_TOPIC or topic.endswith(f'/{SETTINGS_TOPIC}')


def settings_data(messages: Sequence[bytes]) -> tuple[dict[str, str], list[str]]:
    """The custom data the session/settings messages hold (a later message's keys over an
    earlier one's), and what is wrong with those that cannot be read."""
    out: dict[str, str] = {}
    problems: list[str] = []
    for raw in messages:
        try:
            text = str(getattr(typestore().deserialize_cdr(raw, SETTINGS_TYPE), 'data', ''))
            value = yaml.load(text, Loader=SAFE_LOADER)
        except (*DECODE_ERRORS, yaml.YAMLError) as exc:
            problems.append(f'a {SETTINGS_TOPIC} message is unreadable ({shortened(str(exc))})')
            continue
        if not isinstance(value, dict):
            problems.append(f'a {SETTINGS_TOPIC} message holds no mapping')
            continue
        out.update({str(k): str(v) for k, v in value.items()})
    return out, problems


def _repair_note(text: str) -> str:
    repair = _json_object(text) or {}
    return f'repaired session: {repair["summary"]}' if 'summary' in repair else 'repaired session'


@dataclass
class Session:
    """A recorded session, per control block.

    ``currents`` the blocks of ``servo/currents`` as arrays (:class:`CurrentArrays`; None only
    for a session whose blocks differ in length or sample period, which :attr:`blocks` still
    gives). ``t_s`` is the end of each block (as the core loop's traces);
    ``answer_stamps_ns`` the stamp of its last sample, which the estimate, command and
    override that answer it carry. Arrays hold NaN where a block had no answer (the graph did
    not act on it). ``warning`` says what is missing from a partial or repaired session (empty
    when nothing is); ``message_counts`` how many messages of each topic were read.
    """

    path: Path
    custom_data: dict[str, str]
    experiment: Experiment | None
    currents: CurrentArrays | None
    t_s: FloatArray
    answer_stamps_ns: npt.NDArray[np.int64]
    signals: dict[str, FloatArray] = field(default_factory=dict)
    has_truth: bool = False
    # The bridge's armed flag as recorded: its first value and every change, (time [s],
    # armed). Replay arms and disarms its gate at these times, as the operator (or the runner)
    # did: what the bridge did, whatever its parameters said.
    arm_changes: list[tuple[float, bool]] = field(default_factory=list)
    # The cut log the bridge recorded (pmc/cuts), in order.
    cuts: list[CutRecord] = field(default_factory=list)
    warning: str = ''
    message_counts: dict[str, int] = field(default_factory=dict)   # read, per topic
    # The blocks of a session whose blocks differ (no ``currents`` then).
    ragged: list[CurrentBlock] | None = None
    # Whether it is whole, ended early, killed or damaged, and how many blocks it holds.
    wholeness: Wholeness | None = None

    @property
    def blocks(self) -> Sequence[CurrentBlock]:
        """The blocks one by one (views of :attr:`currents`), for callers that take blocks."""
        return self.ragged if self.ragged is not None else self.currents or []

    @property
    def block_starts_s(self) -> FloatArray:
        """The time of each block's first sample [s]."""
        if self.currents is not None:
            return self.currents.t0_s
        return np.array([b.t0_s for b in self.blocks])

    @cached_property
    def input_arrays(self) -> InputArrays:
        """The machine's inputs each recorded decision saw, as arrays (NaN in the signals: the
        session does not say, no answer or recorded before the bridge recorded them)."""
        s = self.signals
        enable, threading, dial = s['program_enable'], s['threading'], s['operator_dial_pct']
        tool = s['tool_number']   # -1 not given; NaN: recorded before FeedOverride carried it
        given = ~(np.isnan(enable) | np.isnan(threading))
        return InputArrays(given, np.where(given & (enable >= 0), enable, -1).astype(np.int8),
                           np.where(given & (threading >= 0), threading, -1).astype(np.int8),
                           np.where(given, dial, np.nan),
                           tool_number=np.where(given & (tool != -1), tool, np.nan))

    def inputs(self, k: int) -> InputValues | None:
        """The machine's inputs the decision answering block ``k`` saw; None where the session
        does not say."""
        return self.input_arrays(k)

    @property
    def versions(self) -> dict[str, str]:
        return dict(json.loads(self.custom_data.get(CUSTOM_VERSIONS, '{}')))


# Settings added after sessions were recorded whose default behaves differently from what
# those sessions ran: a recording without the setting ran with this value.
BEFORE_THE_SETTING: dict[tuple[str, str], Any] = {
    ('force_controller', 'quantiser'): 'nearest',   # requests went to the PMC's nearest level
}


def _experiment(path: Path, custom: dict[str, str]) -> Experiment | None:
    """The run's settings: the resolved parameters a lock-step run embeds, else the experiment
    file a recorder on the machine embeds (its parameters as the file gives them)."""
    try:
        if CUSTOM_PARAMETERS in custom:
            recorded = json.loads(custom[CUSTOM_PARAMETERS])
            for (section, key), value in BEFORE_THE_SETTING.items():
                if section in recorded and key not in recorded[section]:
                    recorded[section][key] = value
            if 'experiment' not in recorded and CUSTOM_EXPERIMENT in custom:
                recorded['experiment'] = _run_section(path, custom[CUSTOM_EXPERIMENT])
            return build_experiment(f'{path} (recorded parameters)', recorded)
        if CUSTOM_EXPERIMENT in custom:
            return parse_experiment(custom[CUSTOM_EXPERIMENT], f'{path} (recorded experiment)')
    except (ValueError, ConfigError) as exc:
        raise BagError(f'{path}: the recorded settings are not a valid experiment: {exc}') \
            from exc
    return None


def _run_section(path: Path, text: str) -> dict[str, Any]:
    """The run's own settings (its name, the band, the settle window) from the experiment file
    a recorder embeds: no node declares them, so the parameters it captured from the nodes do
    not hold them. Empty (the defaults) where the file is not a valid experiment: the captured
    parameters are what ran."""
    try:
        return parse_experiment(text, f'{path} (recorded experiment)').run.to_params()
    except (ValueError, ConfigError):
        return {}


def _check_types(path: Path, topics: dict[str, TopicInfo]) -> None:
    """The topics the signals come from must carry our messages: anything else is not a
    turning_force session."""
    names = {_topic(t): t for t in topics}
    if 'servo/currents' not in names:
        listed = ', '.join(sorted(topics)) or 'no topics'
        raise BagError(f'{path}: no servo/currents topic ({listed}): not a turning_force '
                       'session')
    for name, topic in topics.items():
        relative = _topic(name)
        if relative in MSGTYPES and topic.msgtype != MSGTYPES[relative]:
            raise BagError(f'{path}: {name} is {topic.msgtype}, not {MSGTYPES[relative]}: '
                           'not a turning_force session')


@cache
def session_typestore(definitions: tuple[tuple[str, str, str], ...]) -> Typestore:
    """A type store with a session's own message definitions ((type, encoding, text), as the
    MCAP's schemas hold them): a session recorded before a message gained a field decodes with
    the definition it was written with, as rosbags' AnyReader does it. Ours stand in for a type
    the session does not define."""
    given: dict[str, Any] = {}
    for msgtype, encoding, text in definitions:
        if encoding == 'ros2msg':
            given.update(get_types_from_msg(text, msgtype))
        elif encoding == 'ros2idl':
            separator = '=' * 80 + '\n'
            parts = ([p.split('\n', 1)[1] for p in text.split(separator)[1:]]
                     if text.startswith(f'{separator}IDL: ') else [text])
            for idl in parts:
                given.update(get_types_from_idl(idl))
    # The given types and those they use, no more: a store of every ROS type takes a second.
    types: dict[str, Any] = {}
    wanted = [t for t, _, _ in definitions] + list(given)
    while wanted:
        name = wanted.pop()
        if name in types:
            continue
        if name in given:
            types[name] = given[name]
        else:   # ours (building the store of every ROS type only when it is needed)
            ours = typestore().fielddefs
            if name not in ours:
                continue
            types[name] = ours[name]
        for _, (kind, detail) in types[name][1]:
            inner = detail if kind == Nodetype.NAME else (
                detail[0][1] if kind in (Nodetype.ARRAY, Nodetype.SEQUENCE)
                and detail[0][0] == Nodetype.NAME else None)
            if isinstance(inner, str):
                wanted.append(inner)
    store = get_typestore(Stores.EMPTY)
    store.register(types)
    return store


class _Decoder:
    """The message sink of :func:`read_session`: each chunk's messages of the topics the signals
    come from, decoded as arrays (:mod:`turning_force.session.codec`) with the definition each
    was recorded with, into arrays that grow chunk by chunk. Nothing else is kept of them."""

    def __init__(self, path: Path, topics: dict[str, TopicInfo]) -> None:
        self.path = path
        self.topics = topics
        # By channel id: (store, type, relative topic, builder), or None: not decoded here.
        self._channels: dict[int, tuple[Typestore, str, str, TableBuilder] | None] = {}
        self._later: list[tuple[int, bytes]] = []   # messages of channels not described yet
        self.failed: Counter[str] = Counter()
        self.problems: list[str] = []
        self.settings: list[bytes] = []   # the session/settings messages (CDR), in order

    def _channel(self, scan: McapScan, index: int, final: bool
                 ) -> tuple[Typestore, str, str, TableBuilder] | None:
        if index in self._channels:
            return self._channels[index]
        channel = scan.channels.get(index)
        if channel is None:
            if final:
                self._channels[index] = None
            return None
        relative = _topic(channel.topic)
        topic = self.topics.get(channel.topic)
        schema = scan.schemas.get(channel.schema_id)
        found: tuple[Typestore, str, str, TableBuilder] | None = None
        if relative in READ and topic is not None and schema is not None \
                and schema.name == topic.msgtype:
            try:
                definition = (schema.name, schema.encoding, schema.data.decode())
            except UnicodeDecodeError:
                definition = None   # _recording names it
            if definition is not None:
                try:
                    store = session_typestore((definition,))
                except (TypesysError, ValueError, IndexError) as exc:
                    raise BagError(f'{self.path}: the message definitions in '
                                   f'{scan.path.name} are unreadable: {exc}') from exc
                if topic.type_hash and topic.type_hash != store.hash_rihs01(topic.msgtype):
                    self.problems.append(f'{channel.topic}: the definition of '
                                         f'{topic.msgtype} in the file does not match '
                                         "metadata.yaml's hash")
                if codec.supports(store, topic.msgtype):
                    builder = TableBuilder(codec.fields(store, topic.msgtype), topic.msgtype,
                                           topic.count or 0, KEPT.get(relative))
                    found = (store, topic.msgtype, relative, builder)
                else:
                    self.problems.append(f'{channel.topic}: {topic.msgtype} as the file '
                                         'defines it has no fixed layout')
        self._channels[index] = found
        return found

    def take(self, scan: McapScan, data: npt.NDArray[np.uint8], channels: IntArray,
             log_times: IntArray, offsets: IntArray, sizes: IntArray) -> None:
        """One chunk's messages (:data:`turning_force.session.scan.MessageSink`)."""
        del log_times
        for index in np.flatnonzero(np.bincount(channels)).tolist():
            chosen = channels == index if channels.size > 1 else np.ones(1, dtype=bool)
            self._take(scan, index, data, offsets[chosen], sizes[chosen], final=False)

    def _take(self, scan: McapScan, index: int, data: npt.NDArray[np.uint8], offsets: IntArray,
              sizes: IntArray, final: bool) -> None:
        """Messages of channel ``index``: the settings kept, the signals' topics decoded, those
        of a channel not described yet kept for :meth:`finish` (unless ``final``)."""
        channel = scan.channels.get(index)
        if channel is not None and is_settings(channel.topic):
            self.settings += [bytes(data[o:o + n]) for o, n in zip(
                offsets.tolist(), sizes.tolist(), strict=True)]
            return
        found = self._channel(scan, index, final)
        if found is not None:
            self._decode(found, data, offsets, sizes)
        elif index not in self._channels:   # described later in the file, maybe
            self._later += [(index, bytes(data[o:o + n])) for o, n in zip(
                offsets.tolist(), sizes.tolist(), strict=True)]

    def _decode(self, found: tuple[Typestore, str, str, TableBuilder],
                data: npt.NDArray[np.uint8], offsets: IntArray, sizes: IntArray) -> None:
        store, msgtype, relative, builder = found
        table, read = codec.decode(store, msgtype, data, offsets, sizes,
                                   (f.path for f in builder.leaves))
        builder.append(table)
        if read.size < offsets.size:
            self.failed[relative] += int(offsets.size - read.size)

    def finish(self, scan: McapScan) -> dict[str, Table]:
        """The tables of the topics read, by relative name (messages of channels the file
        describes only after them, or in its summary, decoded now)."""
        later, self._later = self._later, []
        for index, raw in later:
            self._take(scan, index, np.frombuffer(raw, dtype=np.uint8),
                       np.zeros(1, dtype=np.int64), np.array([len(raw)], dtype=np.int64), True)
        tables: dict[str, list[Table]] = {}
        for found in self._channels.values():
            if found is not None and found[3].count:
                tables.setdefault(found[2], []).append(found[3].finish())
        return {topic: codec.concat(parts) for topic, parts in tables.items()}


def _stamps(table: Table) -> IntArray:
    """Each message's header stamp [ns]."""
    sec = table.columns['header.stamp.sec'].astype(np.int64)
    stamps: IntArray = sec * 1_000_000_000 + table.columns['header.stamp.nanosec'].astype(
        np.int64)
    return stamps


def _rows(table: Table, path: str) -> FloatArray | None:
    """A sequence of samples as (blocks, samples), if every message has as many."""
    if path not in table.lengths:
        return None
    try:
        return np.asarray(table.rows(path), dtype=np.float64)
    except ValueError:
        return None


def _blocks(table: Table | None) -> tuple[CurrentArrays | None, list[CurrentBlock] | None,
                                          IntArray, list[str]]:
    """The blocks of servo/currents in time order (as arrays where they are of one length and
    sample period, else as blocks), the stamp of each one's last sample [ns], and what is
    wrong with them: malformed blocks, and gaps and overlaps in the stamps (a block follows
    the one before one block length later)."""
    problems: list[str] = []
    names = ('phase_u_a', 'phase_v_a', 'rotor_angle_rad', 'feed_rate_mm_min')
    if table is None or not table.count:
        return None, None, np.zeros(0, dtype=np.int64), problems
    malformed = ('servo/currents blocks malformed (no samples, arrays of different lengths or '
                 'a bad sample period)')
    if not all(n in table.lengths for n in names) or 'sample_period_s' not in table.columns:
        problems.append(f'{table.count} {malformed}')
        return None, None, np.zeros(0, dtype=np.int64), problems
    period = table.columns['sample_period_s'].astype(np.float64)
    lengths = table.lengths['phase_u_a']
    good = (np.isfinite(period) & (period > 0) & (period < 1.0) & (lengths > 0))
    for name in names[1:]:
        good &= table.lengths[name] == lengths
    if not good.all():
        problems.append(f'{np.count_nonzero(~good)} {malformed}')
        table = table.take(np.flatnonzero(good))
        period, lengths = period[good], lengths[good]
    first = _stamps(table)
    order = np.argsort(first, kind='stable')
    if np.any(order != np.arange(order.size)):
        table, first = table.take(order), first[order]
        period, lengths = period[order], lengths[order]
    span_ns = np.round((lengths - 1) * period * 1e9).astype(np.int64)
    last = first + span_ns
    # Gaps: each block against the one after it.
    length_ns = lengths[:-1] * period[:-1] * 1e9
    gap = first[1:] - first[:-1] - length_ns
    flagged = np.flatnonzero(np.abs(gap) > 0.5 * period[:-1] * 1e9)
    gaps: list[str] = []
    lost = 0
    for k in flagged.tolist():
        after = int(first[k + 1])
        if gap[k] < 0:
            gaps.append(f'blocks overlap at {after * 1e-9:.3f} s')
            continue
        count = max(round(float(gap[k] / length_ns[k])), 1)
        lost += count
        gaps.append(f'{count} at {(int(first[k]) + float(length_ns[k])) * 1e-9:.3f}-'
                    f'{after * 1e-9:.3f} s')
    if gaps:
        problems.append(f'servo/currents stamps: {lost} blocks missing ({_listed(gaps)})')
    t0: FloatArray = first.astype(np.float64) * 1e-9
    samples = [_rows(table, name) for name in names]
    uniform = bool(np.all(period == period[0])) and all(a is not None for a in samples)
    if uniform:
        u, v, angle, feed = cast('list[FloatArray]', samples)
        return (CurrentArrays(t0, float(period[0]), u, v, angle, feed), None, last, problems)
    starts = np.concatenate([[0], np.cumsum(lengths)])
    columns = [np.asarray(table.columns[name], dtype=np.float64) for name in names]
    blocks = [CurrentBlock(float(t0[k]), float(period[k]),
                           *(c[starts[k]:starts[k + 1]] for c in columns))
              for k in range(table.count)]
    return None, blocks, last, problems


def _answer_column(table: Table | None, where: IntArray, path: str) -> FloatArray:
    """A field of the messages answering each block (``where``: :func:`_answers`), as floats;
    NaN where no message answers or the session's definition has no such field."""
    out = np.full(where.size, np.nan)
    if table is None or path not in table.columns or not table.count:
        return out
    found = where >= 0
    out[found] = table.columns[path][where[found]].astype(np.float64)
    return out


def _answers(table: Table | None, stamps: IntArray) -> IntArray:
    """The index of the message of ``table`` answering each block (stamped as its last sample;
    the first in the file where several are), -1 where none does."""
    if table is None or not table.count or 'header.stamp.sec' not in table.columns:
        return np.full(stamps.size, -1, dtype=np.int64)
    carried = _stamps(table)
    unique, first = np.unique(carried, return_index=True)   # the first of each stamp
    at = np.clip(np.searchsorted(unique, stamps), 0, unique.size - 1)
    found: IntArray = np.where(unique[at] == stamps, first[at], -1).astype(np.int64)
    return found


def _cuts(table: Table | None) -> list[CutRecord]:
    names = [f.name for f in dataclasses.fields(CutRecord)]
    if table is None or not all(n in table.columns for n in names):
        return []
    def row(k: int) -> dict[str, Any]:
        return {n: table.text(n, k) if n == 'tool' else table.columns[n][k].item()
                for n in names}

    return [CutRecord(**row(k)) for k in range(table.count)]


def read_session(path: str | Path, partial: bool = False) -> Session:
    """Read a session folder written by ``session_recorder``, chunk by chunk, the signals'
    topics decoded as arrays. A :class:`BagError` names the bag and what is missing (see the
    module docstring), unless ``partial``: then :attr:`Session.warning` says it."""
    path = Path(path)
    info, custom, topics = _open(path)
    _check_types(path, topics)
    decoder = _Decoder(path, topics)
    scan = _scan(_mcap_file(path, info), decoder.take)
    tables = decoder.finish(scan)
    recorded_settings, unreadable = settings_data(decoder.settings)
    custom = {**custom, **recorded_settings}   # metadata.yaml's are a copy: the topic's first
    recording = _recording(path, custom, topics, scan)
    failed = [*unreadable, *decoder.problems,
              *(f'{n} {topic} messages cannot be decoded' for topic, n in decoder.failed.items())]
    currents, ragged, stamps, gaps = _blocks(tables.get('servo/currents'))
    count = len(currents) if currents is not None else len(ragged or [])
    expected = recording.recorded('servo/currents')
    read = [f'servo/currents {count} of {expected} blocks read' if expected is not None
            else f'servo/currents {count} blocks read']
    t_end = (currents.t_end_s if currents is not None else
             np.array([b.t0_s + len(b) * b.sample_period_s for b in ragged or []]))
    if count:
        start = float(currents.t0_s[0]) if currents is not None else (ragged or [])[0].t0_s
        read[0] += f' ({start:.3f}-{float(t_end[-1]):.3f} s)'
    problems = [*failed, *gaps]
    state = wholeness(recording, scan, count, problems, bool(decoder.settings))
    if recording.missing or problems:
        problems = [*read, *problems]
    label = {KILLED: state.line(), DAMAGED: DAMAGED}.get(state.state, '')
    warning = recording.check(partial, problems, label)
    if state.state == ENDED_EARLY or (state.state == WHOLE and state.unverified):
        warning = '; '.join(filter(None, [f'{path}: {state.line()}', warning]))
    elif state.state == KILLED and not problems:   # repaired: what it was, after the repair
        warning = '; '.join(filter(None, [warning, f'{path}: {state.line()}']))
    if not count:
        said = f' ({state.line()})' if state.state != WHOLE else ''
        raise BagError(f'{path}: no servo/currents blocks in the session{said}')
    answering = {t: _answers(tables.get(t), stamps) for t in ANSWERS}
    signals = {name: _answer_column(tables.get(topic), answering[topic], path)
               for name, (topic, path) in SIGNALS.items()}
    override, truth = tables.get('pmc/feed_override'), tables.get('sim/cutting_state')
    arm_changes: list[tuple[float, bool]] = []
    if override is not None and override.count and 'armed' in override.columns:
        carried = _stamps(override)
        order = np.argsort(carried, kind='stable')
        armed = override.columns['armed'][order].astype(bool)
        changed = np.concatenate([[True], armed[1:] != armed[:-1]])
        arm_changes = [(stamp * 1e-9, flag) for stamp, flag in zip(
            carried[order][changed].tolist(), armed[changed].tolist(), strict=True)]
    return Session(path, custom, _experiment(path, custom), currents, t_end, stamps, signals,
                   has_truth=truth is not None and truth.count > 0, arm_changes=arm_changes,
                   cuts=_cuts(tables.get('pmc/cuts')), warning=warning,
                   message_counts={t: recording.counts.get(t, 0) for t in recording.topics},
                   ragged=ragged, wholeness=state)


def applied_overrides(answered_pct: FloatArray, initial_pct: float) -> FloatArray:
    """The override each block ran at: the answer to the block before, or the last answer
    before that where a block was not answered (the PMC holds it); ``initial_pct`` before the
    first answer."""
    written = np.where(np.isfinite(answered_pct), np.arange(answered_pct.size), -1)
    np.maximum.accumulate(written, out=written)
    held = np.where(written >= 0, answered_pct[np.maximum(written, 0)], initial_pct)
    applied: FloatArray = np.concatenate([[initial_pct], held[:-1]])
    return applied


def _block_lengths_s(session: Session) -> FloatArray:
    """Each block's length in time [s] (samples times sample period)."""
    c = session.currents
    if c is not None:
        return np.full(len(c), c.samples_per_block * c.sample_period_s)
    return np.array([len(b) * b.sample_period_s for b in session.blocks])


def _depth_change_times(session: Session, experiment: Experiment) -> list[float]:
    """When the depth of cut changed, on the session's own time line.

    The experiment's depth profile is in plant time, which a lock-step session is stamped in.
    A wall-clock session (the simulator run in real time) is stamped in epoch time from the
    simulator's start: there the changes are taken from the recorded depth instead (the start
    of the first block at each new depth).
    """
    profile = experiment.plant.depth_profile
    planned = profile.change_times_s()
    if not session.has_truth:
        return list(planned)
    depth, starts = session.signals['depth_mm'], session.t_s - _block_lengths_s(session)
    known = np.flatnonzero(np.isfinite(depth))
    changed: list[float] = starts[known[1:][depth[known[:-1]] != depth[known[1:]]]].tolist()
    block_s = float(np.median(session.t_s[1:] - session.t_s[:-1])) if len(starts) > 1 else 0.0
    # A taper's depth changes in every block of its ramp: the ramp is one planned change.
    ramps = [(t0, t1) for t0, t1, d0, d1 in zip(profile.times_s[:-1], profile.times_s[1:],
                                                profile.depth_mm[:-1], profile.depth_mm[1:],
                                                strict=True)
             if profile.interpolation == 'linear' and d0 != d1]
    if all(any(abs(c - p) <= block_s for p in planned)
           or any(t0 - block_s <= c <= t1 + block_s for t0, t1 in ramps) for c in changed):
        return list(planned)   # on the plant's time line: the planned times, exactly
    return changed


def estimate_metrics(session: Session, experiment: Experiment, force_n: FloatArray,
                     answered_pct: FloatArray, reference_n: FloatArray | None = None,
                     reachable: npt.NDArray[np.bool_] | None = None) -> dict[str, float]:
    """The DESIGN.md metrics on an estimated force: for a machine's session (no truth) and for
    replays, whose new commands never reached a plant.

    ``answered_pct`` is the override answering each block; a block ran at the answer to the one
    before, or at the one before that where a block was not answered (the PMC holds it).
    Blocks without an estimate are left out. The tool counts as engaged where the session has
    no depth.
    """
    reference = (np.full_like(force_n, experiment.controller.reference_force_n)
                 if reference_n is None else reference_n)
    depth = session.signals['depth_mm'] if session.has_truth else np.ones_like(force_n)
    applied = applied_overrides(answered_pct, experiment.plant.approach_override_pct)
    keep = np.isfinite(force_n) & np.isfinite(reference) & np.isfinite(depth)
    return compute_metrics(
        session.t_s[keep], force_n[keep], reference[keep], depth[keep], applied[keep],
        _depth_change_times(session, experiment), experiment.metric_settings,
        None if reachable is None else reachable[keep])


def recorded_reachable(session: Session) -> npt.NDArray[np.bool_]:
    """Where the recorded controller said it could reach the reference (a session without
    the flag, or a block without a command, counts as reachable)."""
    return np.asarray(session.signals['reference_reachable'] != 0.0)


def recorded_metrics(session: Session) -> dict[str, float]:
    """The DESIGN.md metrics of a session: on the simulator's true force and depth where the
    session has them, else (a machine's session) on the estimated force.

    Blocks the recording has no force for are left out (the first and last blocks of a
    wall-clock session may have currents without the simulator's state), so the metrics are
    numbers; a session with no force at all says what it lacks.
    """
    if session.experiment is None:
        raise BagError(f'{session.path}: no recorded parameters or experiment file: the metrics '
                       'need the settle window and the allowed error')
    experiment = session.experiment
    s = session.signals
    reference = np.where(np.isnan(s['reference_n']), experiment.controller.reference_force_n,
                         s['reference_n'])
    if not session.has_truth:
        if not np.any(np.isfinite(s['estimated_force_n'])):
            raise BagError(f'{session.path}: no force/estimate and no sim/cutting_state in the '
                           'session: no force to measure (`turning-force replay` estimates it '
                           'from the currents)')
        return estimate_metrics(session, experiment, s['estimated_force_n'],
                                s['answered_override_pct'], reference,
                                recorded_reachable(session))
    keep = (np.isfinite(s['force_n']) & np.isfinite(s['depth_mm'])
            & np.isfinite(s['applied_override_pct']))
    if not np.any(keep):
        raise BagError(f'{session.path}: sim/cutting_state answers none of the '
                       'servo/currents blocks (by stamp): no force to measure')
    return compute_metrics(
        session.t_s[keep], s['force_n'][keep], reference[keep], s['depth_mm'][keep],
        s['applied_override_pct'][keep], _depth_change_times(session, experiment),
        experiment.metric_settings, recorded_reachable(session)[keep],
        s['estimated_force_n'][keep])
