"""What a machinist expects of adaptive feed: the shop-floor behaviours of the override gate.

Commercial adaptive feed options (HEIDENHAIN AFC, Caron TMAC, CERATIZIT ToolScope, Haas
Autofeed) bring behaviours around the control law that a shop relies on: program enable,
threading stand-down, the operator's dial, a rise limit, a feed floor, the air-cut override, the
overload reaction, tool breakage, teach-in and the cut log. Each is a ``pmc_bridge`` setting
here (:class:`ShopFloorSettings`, whose descriptions say what each does), off or conservative by
default; docs/machine-pc.md tells them as a machinist meets them.

The safety gate keeps precedence over all of it (:mod:`turning_force.core.pmc.settings`). Nothing
here writes more than the controller asked for, except the stand-downs to the programmed feed and
the feed floor, which is off by default. The behaviours are written once, compiled, with the safety
gate (:mod:`turning_force.core.pmc.gate`), so that the core loop, replay and the bridge decide
alike; this module holds their settings, the teach-in file and the records they give. """

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from turning_force.core.errors import ConfigError
from turning_force.core.settings import Settings, setting
from turning_force.core.yamlfile import replace_file

__all__ = ['NO_INPUTS', 'CutRecord', 'InputValues', 'Learned', 'ShopFloorSettings', 'TaughtTool',
           'load_teach_file', 'save_teach_file', 'taught_reference']

DIAL_MODES = ('min', 'product', 'ignore')   # not 'off': YAML reads it as false
REACTIONS = ('none', 'alarm', 'hold', 'stop')


@dataclass(frozen=True)
class InputValues:
    """The machine's inputs, as plain values; ``None`` where the machine wires none.

    ``program_enable``: the part program's enable (an M-code relay); ``threading``: thread
    cutting or tapping in progress; ``operator_dial_pct``: the operator's override dial [%];
    ``spindle_speed_rpm``: the live spindle speed (``machine/spindle_speed``) [rpm], which the
    controller and the feed-follow check use; ``tool_number``: the tool in use (the T code,
    ``machine/tool``), which selects its section of the tools file
    (:mod:`turning_force.core.tools`).
    """

    program_enable: bool | None = None
    threading: bool | None = None
    operator_dial_pct: float | None = None
    spindle_speed_rpm: float | None = None
    tool_number: int | None = None

    def over(self, fallback: InputValues) -> InputValues:
        """These values where given, ``fallback``'s elsewhere (a module's wired inputs over a
        topic's)."""
        return InputValues(
            fallback.program_enable if self.program_enable is None else self.program_enable,
            fallback.threading if self.threading is None else self.threading,
            (fallback.operator_dial_pct if self.operator_dial_pct is None
             else self.operator_dial_pct),
            (fallback.spindle_speed_rpm if self.spindle_speed_rpm is None
             else self.spindle_speed_rpm),
            fallback.tool_number if self.tool_number is None else self.tool_number)


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
        30.0, "Override while the tool is out of the cut and after it enters until the force is "
        "established (the entry feed: AFC's FIDL, TMAC's approach override; cut_settle_s, "
        "entry_rise_limit_per_s), never above the controller's "
        'request; the controller starts from it when the cut is established; 0: off', '%',
        low=0.0, high=1000.0)
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
        '(tool breakage, teach-in), and the shortest hold of the entry feed', 's', low=0.0,
        high=60.0)
    entry_rise_limit_per_s: float = setting(
        0.5, 'The entry feed holds past cut_settle_s while the force still rises faster than '
        'this fraction of its level per second (the cut not yet established: a slow chip '
        'formation); 0: cut_settle_s only', '1/s', low=0.0, high=100.0)
    entry_hold_max_s: float = setting(
        1.0, 'The longest hold of the entry feed after engagement, the force established or '
        'not (cut_settle_s where that is longer)', 's', low=0.0, high=60.0)
    overload_reaction: str = setting(
        'none', "What a force above the reaction limit for reaction_delay_s does (AFC's OVLD): "
        'nothing (none), raise the alarm output (alarm), also hold the feed until re-armed '
        '(hold), or also set the stop_request output for a stop or retract (stop)',
        choices=REACTIONS)
    reaction_force_fraction: float = setting(
        0.8, "The overload reaction's limit as a fraction of overload_force_n (which holds the "
        'feed at once); also the limit the cut log counts overload events at', low=0.0,
        low_open=True, high=1.0, unit='-')
    reaction_delay_s: float = setting(
        1.0, 'How long the force must stay above the reaction limit before the overload '
        'reaction (AFC: 1 s)', 's', low=0.0, low_open=True, high=600.0)
    breakage_spike_fraction: float = setting(
        0.0, 'Tool breakage: a force this fraction above its recent level holds the feed from '
        'the next period; 0: off', low=0.0, high=100.0, unit='-')
    breakage_drop_fraction: float = setting(
        0.0, 'Tool breakage: a force this fraction below its recent level holds the feed; '
        'judged only while the program-enable input is set (a tool exit drops the force too: '
        'the program clears the input before it); 0: off', low=0.0, high=1.0, high_open=True,
        unit='-')
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
        low=0.0, low_open=True, high=2.0, unit='-')

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
    except UnicodeDecodeError as exc:
        raise ConfigError(f'{path}: pmc_bridge.teach_file: not a text (UTF-8) teach-in file '
                          f'(byte {exc.start} of it)') from exc
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
    replace_file(path, text, ' teach-in file')


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


# --- the behaviours ---------------------------------------------------------------------------


@dataclass(frozen=True)
class Learned:
    """What a learning cut taught: the tool's entry, and why it was not taken ('' if it was)."""

    tool: str
    taught: TaughtTool
    refused: str = ''
