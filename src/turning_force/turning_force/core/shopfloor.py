"""What a machinist expects of adaptive feed: the shop-floor behaviours of the override gate.

Commercial adaptive feed options (HEIDENHAIN AFC, Caron TMAC, CERATIZIT ToolScope, Haas
Autofeed) bring behaviours around the control law that a shop relies on. Each is a
``pmc_bridge`` setting here (:class:`ShopFloorSettings`), off or conservative by default:

- Program enable: the bridge acts only while the part program sets an input (an M-code relay,
  ToolScope's M810/M811); otherwise it writes the programmed feed.
- Threading: FANUC runs thread cutting and tapping at 100 % whatever the override; while an
  input marks them the bridge stands down to the programmed feed.
- The operator's dial keeps precedence: the lower of the dial and the controller's request, or
  their product (a dial above 100 % never raises the feed over the request).
- Rise limit: the override rises toward a higher request at most ``rise_rate_pct_s`` (Haas
  recovers at 10 %/s); a fall is never slowed.
- Feed floor: while cutting, a request below ``min_cut_override_pct`` is raised to it.
- Air cut: out of the cut the feed is held to the air-cut override until the force rises
  (AFC's FIDL, TMAC's approach override); engagement and exit are detected with hysteresis.
- Overload reaction (AFC's OVLD): after ``reaction_delay_s`` above the reaction limit, raise the
  alarm output, also hold the feed, or also request a stop or retract through an output.
- Tool breakage: a force far above (a spike) or below (a drop) its recent level holds the feed
  from the next control period.
- Teach-in: a learning cut at the programmed feed records the tool's force level; the reference
  becomes ``teach_fraction`` of it, kept per tool in ``teach_file`` for the next session.
- Cut log (AFC's log): per cut from engagement to exit, the time, the time at a fixed 100 %
  override, max and mean force, lowest override, overload events, reachable fraction.

The safety gate keeps precedence over all of it (:mod:`turning_force.core.pmc`): the overload
hold, disarmed, the watchdog and invalid commands decide first. Nothing here writes more than
the controller asked for, except the stand-downs to the programmed feed (threading, the program
not enabling the option, a learning cut) and the feed floor, which is off by default.

ROS-free and deterministic: :class:`ShopFloor` takes plain values once per control block
(:meth:`ShopFloor.observe` with the force estimate, :meth:`ShopFloor.commit` with the decision
that answered it), so that the core loop, replay and the bridge decide alike.
"""

from __future__ import annotations

import math
import os
import tempfile
from collections import deque
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from turning_force.core.errors import ConfigError
from turning_force.core.settings import Settings, setting

__all__ = [
    'NO_INPUTS',
    'CutLog',
    'CutRecord',
    'InputValues',
    'Learned',
    'ShopFloor',
    'ShopFloorSettings',
    'TaughtTool',
    'load_teach_file',
    'save_teach_file',
    'taught_reference',
]

DIAL_MODES = ('min', 'product', 'ignore')   # not 'off': YAML reads it as false
REACTIONS = ('none', 'alarm', 'hold', 'stop')
# A force back under this share of the reaction limit ends one overload event (hysteresis, so
# that noise around the limit is not counted as many events).
EVENT_RESET_FRACTION = 0.9


@dataclass(frozen=True)
class InputValues:
    """The machine's inputs, as plain values; ``None`` where the machine wires none.

    ``program_enable``: the part program's enable (an M-code relay); ``threading``: thread
    cutting or tapping in progress; ``operator_dial_pct``: the operator's override dial [%].
    """

    program_enable: bool | None = None
    threading: bool | None = None
    operator_dial_pct: float | None = None

    def over(self, fallback: InputValues) -> InputValues:
        """These values where given, ``fallback``'s elsewhere (a module's wired inputs over a
        topic's)."""
        return InputValues(
            fallback.program_enable if self.program_enable is None else self.program_enable,
            fallback.threading if self.threading is None else self.threading,
            (fallback.operator_dial_pct if self.operator_dial_pct is None
             else self.operator_dial_pct))


NO_INPUTS = InputValues()   # a machine that wires none


@dataclass(frozen=True)
class ShopFloorSettings(Settings):
    """The shop-floor behaviours (``pmc_bridge`` parameters, with :class:`BridgeSettings`)."""

    SECTION = 'pmc_bridge'

    program_enable_required: bool = setting(
        False, "Act only while the part program sets the program-enable input (an M-code relay, "
        "like ToolScope's M810/M811); otherwise, or with no such input wired, write the "
        'programmed feed')
    threading_stand_down: bool = setting(
        True, 'Write the programmed feed while the threading input says thread cutting or '
        'tapping is in progress (FANUC runs them at 100 % whatever the override)')
    operator_dial: str = setting(
        'min', "How the operator's override dial, where one is read, limits the feed: the lower "
        "of the dial and the controller's request (min), their product with the dial counted "
        'up to 100 % (product), or not at all (ignore)', choices=DIAL_MODES)
    rise_rate_pct_s: float = setting(
        0.0, 'Fastest rise of the override toward a higher request (Haas Autofeed: 10 %/s); a '
        'fall is never slowed; 0: no limit', '%/s', low=0.0, high=1e4)
    min_cut_override_pct: float = setting(
        0.0, 'Feed floor while the tool is in the cut: a lower request is raised to it (the '
        'overload hold still holds the feed); 0: none', '%', low=0.0, high=100.0)
    air_cut_override_pct: float = setting(
        0.0, "Override while the tool is out of the cut (AFC's FIDL, TMAC's approach "
        "override), never above the controller's request; 0: off", '%', low=0.0, high=1000.0)
    engage_force_n: float = setting(
        100.0, 'Estimated force above which the tool counts as in the cut', 'N', low=0.0,
        low_open=True, high=1e5)
    exit_force_n: float = setting(
        50.0, "Estimated force below which the tool counts as out of the cut (AFC's POUT)", 'N',
        low=0.0, high=1e5)
    engage_time_s: float = setting(
        0.02, 'How long the force must stay past engage_force_n (exit_force_n) for the tool to '
        'count as in (out of) the cut; at least one control period', 's', low=0.0, high=10.0)
    cut_settle_s: float = setting(
        0.3, 'After engagement, time left for the force to settle before its level counts '
        '(tool breakage, teach-in)', 's', low=0.0, high=60.0)
    overload_reaction: str = setting(
        'none', "What a force above the reaction limit for reaction_delay_s does (AFC's OVLD): "
        'nothing (none), raise the alarm output (alarm), also hold the feed until re-armed '
        '(hold), or also set the stop_request output for a stop or retract (stop)',
        choices=REACTIONS)
    reaction_force_fraction: float = setting(
        0.8, "The overload reaction's limit as a fraction of overload_force_n (which holds the "
        'feed at once); also the limit the cut log counts overload events at', low=0.0,
        low_open=True, high=1.0)
    reaction_delay_s: float = setting(
        1.0, 'How long the force must stay above the reaction limit before the overload '
        'reaction (AFC: 1 s)', 's', low=0.0, low_open=True, high=600.0)
    breakage_spike_fraction: float = setting(
        0.0, 'Tool breakage: a force this fraction above its recent level holds the feed from '
        'the next period; 0: off', low=0.0, high=100.0)
    breakage_drop_fraction: float = setting(
        0.0, 'Tool breakage: a force this fraction below its recent level holds the feed; '
        'judged only while the program-enable input is set (a tool exit drops the force too: '
        'the program clears the input before it); 0: off', low=0.0, high=1.0, high_open=True)
    breakage_window_s: float = setting(
        0.5, "The force's recent level for the breakage detector: its mean over this window", 's',
        low=0.0, low_open=True, high=60.0)
    tool: str = setting('', 'The tool in use (e.g. T0101): the key of teach-in and the cut log')
    teach_file: str = setting(
        '', 'Per-tool teach-in file (YAML): where tool is taught, its reference is used; a '
        'learning cut writes it; empty: no teach-in')
    teach_in: bool = setting(
        False, "The session's first cut is a learning cut for tool: at the programmed feed, its "
        'force level (its mean, cut_settle_s after the entry to cut_settle_s before the exit) is '
        'learned, written to teach_file, and the reference set from it')
    teach_fraction: float = setting(
        0.9, 'The reference a learning cut sets: this fraction of its learned force level',
        low=0.0, low_open=True, high=2.0)

    def debounce_blocks(self, period_s: float) -> int:
        """The control blocks the force must stay past a threshold for the cut detector to
        engage (or exit): ``engage_time_s`` in blocks of ``period_s``, at least one."""
        return max(1, math.ceil(self.engage_time_s / period_s - 1e-9))

    def check(self) -> None:
        if self.exit_force_n >= self.engage_force_n:
            self.fail('exit_force_n', f'not below engage_force_n ({self.engage_force_n:g} N): '
                                      'the cut detector needs a hysteresis')
        if self.teach_file and not self.tool:
            self.fail('tool', f'empty, with teach_file = {self.teach_file!r}: teach-in is kept '
                              'per tool')
        if self.teach_in and not self.teach_file:
            self.fail('teach_file', 'empty, with teach_in = True: the learning cut has nowhere '
                                    'to go')


# --- teach-in file --------------------------------------------------------------------------


@dataclass(frozen=True)
class TaughtTool:
    """One tool's entry in the teach-in file."""

    learned_force_n: float      # the force level of its learning cut [N]
    teach_fraction: float       # the share of it taken as the reference
    reference_force_n: float    # learned_force_n * teach_fraction [N]
    max_force_n: float = math.nan
    cut_s: float = math.nan     # how long the learning cut was [s]

    def to_dict(self) -> dict[str, float]:
        out = {'learned_force_n': self.learned_force_n, 'teach_fraction': self.teach_fraction,
               'reference_force_n': self.reference_force_n}
        if math.isfinite(self.max_force_n):
            out['max_force_n'] = self.max_force_n
        if math.isfinite(self.cut_s):
            out['cut_s'] = self.cut_s
        return out


_TOOL_KEYS = ('learned_force_n', 'teach_fraction', 'reference_force_n', 'max_force_n', 'cut_s')


def _number(path: Path, key: str, value: Any, required: bool = True) -> float:
    if value is None and not required:
        return math.nan
    if isinstance(value, bool) or not isinstance(value, int | float) or not (
            math.isfinite(value) and value > 0):
        raise ConfigError(f'{path}: {key} = {value!r}: expected a finite number above 0')
    return float(value)


def load_teach_file(path: str | Path) -> dict[str, TaughtTool]:
    """The taught tools of a teach-in file; a missing file has none (a learning cut creates it).

    ``ConfigError`` names the file and key of anything malformed.
    """
    path = Path(path)
    try:
        text = path.read_text()
    except FileNotFoundError:
        return {}
    except OSError as exc:
        raise ConfigError(f'{path}: cannot read teach-in file: {exc.strerror}') from exc
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        where = getattr(exc, 'problem_mark', None)
        line = f' (line {where.line + 1})' if where is not None else ''
        raise ConfigError(f'{path}: teach-in file is not valid YAML{line}') from exc
    if data is None:
        return {}
    if not isinstance(data, Mapping) or set(data) - {'tools'}:
        raise ConfigError(f'{path}: expected a mapping with one key, tools')
    tools = data.get('tools') or {}
    if not isinstance(tools, Mapping):
        raise ConfigError(f'{path}: tools = {tools!r}: expected a mapping of tool -> entry')
    out: dict[str, TaughtTool] = {}
    for name, entry in tools.items():
        key = f'tools.{name}'
        if not isinstance(entry, Mapping):
            raise ConfigError(f'{path}: {key} = {entry!r}: expected a mapping')
        unknown = sorted(set(entry) - set(_TOOL_KEYS))
        if unknown:
            raise ConfigError(f'{path}: {key}: unknown keys {unknown}; known: '
                              f'{sorted(_TOOL_KEYS)}')
        learned = _number(path, f'{key}.learned_force_n', entry.get('learned_force_n'))
        fraction = _number(path, f'{key}.teach_fraction', entry.get('teach_fraction'))
        # The reference is what is used: a machinist may edit it by hand to tune the tool.
        reference = _number(path, f'{key}.reference_force_n', entry.get('reference_force_n'))
        out[str(name)] = TaughtTool(
            learned, fraction, reference,
            _number(path, f'{key}.max_force_n', entry.get('max_force_n'), required=False),
            _number(path, f'{key}.cut_s', entry.get('cut_s'), required=False))
    return out


def save_teach_file(path: str | Path, tool: str, taught: TaughtTool) -> None:
    """Write (or update) ``tool``'s entry; the file is replaced at once, never half written."""
    path = Path(path)
    tools = load_teach_file(path)
    tools[tool] = taught
    text = ('# turning_force teach-in: the force level learned per tool (pmc_bridge.teach_file)\n'
            + yaml.safe_dump({'tools': {name: entry.to_dict()
                                        for name, entry in sorted(tools.items())}},
                             sort_keys=False))
    path.parent.mkdir(parents=True, exist_ok=True)
    try:
        fd, tmp = tempfile.mkstemp(prefix=f'.{path.name}.', dir=path.parent)
        with os.fdopen(fd, 'w') as stream:
            stream.write(text)
        os.replace(tmp, path)
    except OSError as exc:
        raise ConfigError(f'{path}: cannot write teach-in file: {exc.strerror}') from exc


def taught_reference(settings: ShopFloorSettings) -> float | None:
    """The reference a session starts from: ``tool``'s taught one, unless this session learns
    (``teach_in``) or nothing is taught; ``None`` then."""
    if not settings.teach_file or settings.teach_in:
        return None
    taught = load_teach_file(settings.teach_file).get(settings.tool)
    return None if taught is None else taught.reference_force_n


# --- the cut log ----------------------------------------------------------------------------


@dataclass(frozen=True)
class CutRecord:
    """One cut from engagement to exit (the core side of ``CutRecord``)."""

    index: int
    tool: str
    start_s: float
    end_s: float
    programmed_feed_s: float
    max_force_n: float
    mean_force_n: float
    min_override_pct: float
    overload_events: int
    breakage: bool
    reachable_fraction: float
    learned: bool = False
    complete: bool = True

    @property
    def duration_s(self) -> float:
        return self.end_s - self.start_s

    def to_dict(self) -> dict[str, Any]:
        return {'index': self.index, 'tool': self.tool, 'start_s': self.start_s,
                'end_s': self.end_s, 'duration_s': self.duration_s,
                'programmed_feed_s': self.programmed_feed_s, 'max_force_n': self.max_force_n,
                'mean_force_n': self.mean_force_n, 'min_override_pct': self.min_override_pct,
                'overload_events': self.overload_events, 'breakage': self.breakage,
                'reachable_fraction': self.reachable_fraction, 'learned': self.learned,
                'complete': self.complete}


@dataclass(frozen=True)
class _Block:
    """One control block as the cut log keeps it."""

    t_s: float                 # end of the block
    force_n: float             # NaN: no valid estimate for it
    applied_pct: float         # the override the PMC applied during it
    reachable: bool | None     # the command's flag; None: no command answered it
    event: bool                # an overload event started in it
    breakage: bool


class CutLog:
    """The cuts of a session, from blocks as they are answered.

    A cut starts with the first block of the run of blocks that engaged the tool and ends with
    the last block before the run that took it out (both runs are ``debounce`` blocks long), so
    that its time does not depend on the detector's debounce.
    """

    def __init__(self, tool: str = '', period_s: float = 0.01, debounce: int = 1) -> None:
        self.tool = tool
        self.period_s = period_s
        self.records: list[CutRecord] = []
        self._cut: list[_Block] = []
        self._recent: deque[_Block] = deque(maxlen=max(debounce, 1))
        self._in_cut = False

    def add(self, block: _Block) -> None:
        (self._cut if self._in_cut else self._recent).append(block)

    def start(self, run: int) -> None:
        """The tool is in the cut; the cut began ``run`` blocks ago (counting the current block,
        which is added after)."""
        self._in_cut = True
        back = max(run - 1, 0)
        self._cut = list(self._recent)[len(self._recent) - back:] if back else []
        self._recent.clear()

    def end(self, run: int, learned: bool = False) -> CutRecord | None:
        """The tool is out; the last ``run - 1`` blocks added were already out of the cut."""
        self._in_cut = False
        back = max(run - 1, 0)
        blocks = self._cut[:len(self._cut) - back] if back else self._cut
        self._cut = []
        return self._record(blocks, learned, complete=True)

    def close(self) -> CutRecord | None:
        """The session ends: the cut still open, if any, marked incomplete."""
        if not self._in_cut:
            return None
        self._in_cut = False
        blocks, self._cut = self._cut, []
        return self._record(blocks, False, complete=False)

    @property
    def blocks(self) -> list[_Block]:
        """The blocks of the cut in progress."""
        return self._cut

    def _record(self, blocks: list[_Block], learned: bool, complete: bool) -> CutRecord | None:
        if not blocks:
            return None
        forces = [b.force_n for b in blocks if math.isfinite(b.force_n)]
        commanded = [b.reachable for b in blocks if b.reachable is not None]
        record = CutRecord(
            index=len(self.records) + 1, tool=self.tool,
            start_s=blocks[0].t_s - self.period_s, end_s=blocks[-1].t_s,
            # The distance fed is the applied override times the programmed feed rate over
            # each block; at a fixed 100 % the same distance takes this long.
            programmed_feed_s=math.fsum(b.applied_pct / 100.0 * self.period_s for b in blocks),
            max_force_n=max(forces) if forces else math.nan,
            mean_force_n=math.fsum(forces) / len(forces) if forces else math.nan,
            min_override_pct=min(b.applied_pct for b in blocks),
            overload_events=sum(b.event for b in blocks),
            breakage=any(b.breakage for b in blocks),
            reachable_fraction=(sum(commanded) / len(commanded) if commanded else math.nan),
            learned=learned, complete=complete)
        self.records.append(record)
        return record


# --- the behaviours ---------------------------------------------------------------------------


@dataclass(frozen=True)
class Learned:
    """What a learning cut taught: the tool's entry, and why it was not taken ('' if it was)."""

    tool: str
    taught: TaughtTool
    refused: str = ''


@dataclass(frozen=True)
class Verdict:
    """What the shop-floor behaviours make of one decision: the override (continuous, before the
    table's quantisation), the ``Reason`` value and why."""

    pct: float
    reason: int
    detail: str


# The Reason values this module hands out (core/pmc.py's enum; no import, to avoid a cycle).
NORMAL, OPERATOR, OVERLOAD_HOLD = 0, 4, 3
AIR_CUT, TOOL_BREAKAGE, RISE_LIMIT, FEED_FLOOR, TEACH_IN = 7, 8, 9, 10, 11
# The reasons of a regulating decision: the request, shaped.
SHAPED = (NORMAL, AIR_CUT, RISE_LIMIT, FEED_FLOOR, OPERATOR)


class ShopFloor:
    """The shop-floor behaviours' state, stepped once per control block.

    Per block: :meth:`observe` with the valid force estimate (engagement, breakage, overload
    reaction, teach-in), then :meth:`verdict` / :meth:`shape` for the decision, then
    :meth:`commit` with the decision that answered the block (the rise limit's base and the cut
    log). :meth:`rearm` clears the latched reactions.
    """

    def __init__(self, settings: ShopFloorSettings, overload_force_n: float,
                 period_s: float) -> None:
        self.settings = settings
        self.overload_force_n = overload_force_n
        self.period_s = period_s
        self.inputs = NO_INPUTS
        self.engaged = False
        self._debounce = settings.debounce_blocks(period_s)
        self.log = CutLog(settings.tool, period_s, self._debounce)
        self._run = 0                       # consecutive blocks past the threshold
        self._cut_blocks = 0                # blocks since engagement
        self._window: deque[float] = deque(
            maxlen=max(1, round(settings.breakage_window_s / period_s)))
        self._settle_blocks = math.ceil(settings.cut_settle_s / period_s - 1e-9)
        self._above = 0                     # consecutive blocks above the reaction limit
        self._in_event = False
        self._block_force = math.nan
        self._block_event = False
        self._breakage = ''                 # why the breakage detector holds the feed
        self._reaction = ''                 # why the overload reaction fired
        self._applied_pct = 100.0           # what the PMC applies now: the last answer
        self._ramp_pct = 100.0              # the rise limit's base (continuous)
        self._learning = settings.teach_in
        self._learned: Learned | None = None
        self._cuts: list[CutRecord] = []

    # --- per block ---------------------------------------------------------------------------

    @property
    def reaction_limit_n(self) -> float:
        return self.settings.reaction_force_fraction * self.overload_force_n

    def acting(self, armed: bool) -> bool:
        """Whether the option acts now: armed, and not stood down by the machine's inputs."""
        return armed and self._stand_down() is None

    def observe(self, force_n: float, armed: bool, hold_started: bool = False) -> None:
        """A valid, finite force estimate of the current block."""
        s = self.settings
        self._block_force = force_n
        self._engagement(force_n)
        acting = self.acting(armed)
        # Overload events (the cut log) and the overload reaction.
        limit = self.reaction_limit_n
        if force_n > limit and not self._in_event:
            self._in_event = self._block_event = True
        elif force_n < EVENT_RESET_FRACTION * limit:
            self._in_event = False
        self._block_event |= hold_started
        self._above = self._above + 1 if force_n > limit and acting else 0
        needed = math.ceil(s.reaction_delay_s / self.period_s - 1e-9)
        if (s.overload_reaction != 'none' and not self._reaction and self._above >= needed):
            self._reaction = (f'overload reaction ({s.overload_reaction}): force above '
                              f'{limit:g} N ({s.reaction_force_fraction:g} x overload_force_n) '
                              f'for {self._above * self.period_s:.2f} s')
        # Tool breakage: against the recent level, once the cut has settled.
        if not self.engaged:
            self._window.clear()
            return
        if self._cut_blocks > self._settle_blocks and len(self._window) == self._window.maxlen:
            why = self._breakage_check(force_n, acting)
            if why and not self._breakage:
                self._breakage = why
        if self._cut_blocks > self._settle_blocks:
            self._window.append(force_n)

    def _breakage_check(self, force_n: float, acting: bool) -> str:
        s = self.settings
        if not acting:
            return ''
        level = math.fsum(self._window) / len(self._window)
        if level <= 0.0:   # no level to compare with (noise around zero at the exit)
            return ''
        if s.breakage_spike_fraction > 0 and force_n > (1.0 + s.breakage_spike_fraction) * level:
            return (f'tool breakage: force {force_n:.0f} N is {force_n / level - 1.0:.0%} above '
                    f'its recent level {level:.0f} N')
        if (s.breakage_drop_fraction > 0 and self.inputs.program_enable
                and force_n < (1.0 - s.breakage_drop_fraction) * level):
            return (f'tool breakage: force {force_n:.0f} N is {1.0 - force_n / level:.0%} below '
                    f'its recent level {level:.0f} N while the program says the tool cuts')
        return ''

    def _engagement(self, force_n: float) -> None:
        s = self.settings
        if not self.engaged:
            self._run = self._run + 1 if force_n > s.engage_force_n else 0
            if self._run >= self._debounce:
                self.engaged = True
                self._cut_blocks = self._run
                self.log.start(self._run)
                self._run = 0
            return
        self._cut_blocks += 1
        self._run = self._run + 1 if force_n < s.exit_force_n else 0
        if self._run >= self._debounce:
            self.engaged = False
            learned = self._learn() if self._learning else None
            record = self.log.end(self._run, learned=learned is not None and not learned.refused)
            if record is not None:
                self._cuts.append(record)
            self._run = 0

    def _learn(self) -> Learned:
        """The learning cut is over: its level, the mean force between ``cut_settle_s`` after
        the entry and ``cut_settle_s`` before the exit (the force falling as the tool leaves)."""
        s = self.settings
        end = len(self.log.blocks) - (self._run - 1) - self._settle_blocks
        blocks = self.log.blocks[self._settle_blocks:max(end, self._settle_blocks)]
        forces = [b.force_n for b in blocks if math.isfinite(b.force_n)]
        level = math.fsum(forces) / len(forces) if forces else math.nan
        peak = max(forces) if forces else math.nan
        refused = ''
        if not forces:
            refused = (f'the cut was not longer than twice cut_settle_s ({s.cut_settle_s:g} s): '
                       'nothing settled to learn')
        elif any(b.applied_pct != 100.0 for b in blocks):
            low = min(b.applied_pct for b in blocks)
            refused = (f'the cut did not run at the programmed feed throughout (down to '
                       f"{low:g} %): its force is not the tool's level")
        elif any(b.breakage or b.event for b in blocks) or self._reaction or self._breakage:
            refused = 'the cut had an overload or a breakage: not a level to regulate to'
        elif level * s.teach_fraction >= self.overload_force_n:
            refused = (f'{s.teach_fraction:g} x {level:.0f} N is not below overload_force_n '
                       f'({self.overload_force_n:g} N)')
        self._learning = bool(refused)   # a cut that cannot be learned: the next one is
        cut_s = len(blocks) * self.period_s
        taught = TaughtTool(level, s.teach_fraction, level * s.teach_fraction, peak, cut_s)
        self._learned = Learned(s.tool, taught, refused)
        return self._learned

    def commit(self, t_s: float, applied_pct: float, verdict: Verdict | None,
               reachable: bool | None) -> None:
        """The decision answering the block that ends at ``t_s``: ``applied_pct`` from the next
        block on; ``verdict`` when it was a regulating one (the rise limit's base)."""
        self.log.add(_Block(t_s, self._block_force, self._applied_pct, reachable,
                            self._block_event, bool(self._breakage)))
        self._applied_pct = applied_pct
        self._ramp_pct = verdict.pct if verdict is not None else applied_pct
        self._block_force = math.nan
        self._block_event = False

    def rearm(self) -> None:
        """Re-armed: the latched reactions are cleared (the timers start again)."""
        self._breakage = self._reaction = ''
        self._above = 0

    def close(self) -> CutRecord | None:
        """The session ends: the open cut, marked incomplete."""
        record = self.log.close()
        if record is not None:
            self._cuts.append(record)
        self.engaged = False
        return record

    def take_cuts(self) -> list[CutRecord]:
        """Cuts finished since the last call."""
        cuts, self._cuts = self._cuts, []
        return cuts

    def take_learned(self) -> Learned | None:
        """What a learning cut just taught, once."""
        learned, self._learned = self._learned, None
        return learned

    # --- outputs -----------------------------------------------------------------------------

    @property
    def alarm(self) -> bool:
        return bool(self._breakage or self._reaction)

    @property
    def stop_request(self) -> bool:
        return bool(self._reaction) and self.settings.overload_reaction == 'stop'

    # --- the decision ------------------------------------------------------------------------

    def _stand_down(self) -> str | None:
        s, inputs = self.settings, self.inputs
        if s.threading_stand_down and inputs.threading:
            return ('thread cutting or tapping (threading input): FANUC runs the programmed '
                    'feed; stood down')
        if s.program_enable_required:
            if inputs.program_enable is None:
                return ('program_enable_required, but no program-enable input is wired or read: '
                        'programmed feed')
            if not inputs.program_enable:
                return ('the part program has not enabled adaptive feed (program-enable input '
                        'clear): programmed feed')
        return None

    def verdict(self) -> Verdict | None:
        """The holds and stand-downs that come before the request, in order; None if none."""
        if self._breakage:
            return Verdict(0.0, TOOL_BREAKAGE, self._breakage + '; re-arm to resume')
        if self._reaction and self.settings.overload_reaction == 'hold':
            return Verdict(0.0, OVERLOAD_HOLD, self._reaction + '; re-arm to resume')
        why = self._stand_down()
        if why is not None:
            return Verdict(100.0, OPERATOR, why)
        if self._learning:
            return Verdict(100.0, TEACH_IN, f'teach-in: learning cut for {self.settings.tool} '
                                            'at the programmed feed')
        return None

    def shape(self, requested_pct: float) -> Verdict:
        """The controller's request, shaped: feed floor, air cut, dial, rise limit."""
        s = self.settings
        pct, reason, detail = requested_pct, NORMAL, ''
        if self.engaged and s.min_cut_override_pct > 0 and pct < s.min_cut_override_pct:
            pct, reason = s.min_cut_override_pct, FEED_FLOOR
            detail = (f'request {requested_pct:.4g} % raised to the feed floor '
                      f'({s.min_cut_override_pct:g} %) while cutting')
        if not self.engaged and s.air_cut_override_pct > 0 and pct > s.air_cut_override_pct:
            pct, reason = s.air_cut_override_pct, AIR_CUT
            detail = f'tool out of the cut: air-cut override {s.air_cut_override_pct:g} %'
        dial = self.dial_pct
        if dial is not None:
            factor = min(dial, 100.0) / 100.0
            dialled = pct * factor if s.operator_dial == 'product' else min(pct, dial)
            if dialled < pct:
                pct, reason = dialled, OPERATOR
                detail = (f"the operator's dial at {dial:g} % "
                          f'({"times" if s.operator_dial == "product" else "below"} the '
                          f'request {requested_pct:.4g} %)')
        ceiling = self._ramp_pct + s.rise_rate_pct_s * self.period_s
        if s.rise_rate_pct_s > 0 and pct > ceiling:
            pct, reason = ceiling, RISE_LIMIT
            detail = f'rising at most {s.rise_rate_pct_s:g} %/s toward {requested_pct:.4g} %'
        return Verdict(pct, reason, detail)

    @property
    def dial_pct(self) -> float | None:
        """The operator's dial in force, or None (not read, or ignored)."""
        dial = self.inputs.operator_dial_pct
        if self.settings.operator_dial == 'ignore' or dial is None or not math.isfinite(dial):
            return None
        return max(dial, 0.0)
