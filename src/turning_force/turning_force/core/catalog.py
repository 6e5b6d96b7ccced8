"""Every node's parameters, explained: the one list ``turning-force describe`` prints,
docs/parameters.md is generated from, and the nodes declare their ROS parameters from.

A node's parameters are the fields of its settings classes (:mod:`turning_force.core.settings`:
default, description, unit, range, whether it may change while cutting, the paper and
equation). :data:`NODES` says which classes each node declares; the few parameters a node has
besides its core settings (how it is run, not what it computes) are the small classes here.
"""

from __future__ import annotations

import dataclasses
import difflib
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from turning_force.core.errors import ConfigError
from turning_force.core.experiment import (
    SHARED,
    RecorderSettings,
    RunSettings,
    parameter_sections,
)
from turning_force.core.settings import DIMENSIONLESS, Settings, Spec, setting
from turning_force.core.yamlfile import load_yaml, read_text

__all__ = ['NODES', 'BridgeNodeSettings', 'LatheSimNodeSettings', 'NodeParameters', 'Parameter',
           'describe', 'experiments_setting', 'find', 'missing_metadata', 'parameters',
           'parameters_markdown']


@dataclass(frozen=True)
class LatheSimNodeSettings(Settings):
    """``lathe_sim``'s parameters besides the plant's: how the node runs."""

    SECTION = 'lathe_sim'

    publish_clock: bool = setting(False, 'Publish /clock from the plant: the node owns the '
                                  "graph's time (a simulated graph without the lock-step runner)")
    latency_window_s: float = setting(10.0, 'Sliding window of the block-to-override latency '
                                      'statistics on /diagnostics (wall clock only)', 's',
                                      low=0.0, low_open=True, high=3600.0)
    machine_file: str = setting('', 'Machine file (shared with pmc_bridge): with backend '
                                'modbus_tcp, the coils the override is read from')
    backend: str = setting('simulated', 'Where the override is read: simulated (the '
                           'pmc/feed_override topic) or modbus_tcp (the coils of the machine '
                           "file's module)", choices=('simulated', 'modbus_tcp'))


@dataclass(frozen=True)
class BridgeNodeSettings(Settings):
    """``pmc_bridge``'s parameter besides the bridge's settings: how it starts."""

    SECTION = 'pmc_bridge'

    autostart: bool = setting(True, 'Configure and activate at start (false: wait for '
                              '~/change_state, as ros2 lifecycle set drives it)')


@dataclass(frozen=True)
class NodeParameters:
    """A node (or the ``experiment`` section, which the runner reads) and its settings."""

    node: str
    summary: str
    settings: tuple[type[Settings], ...]

    def fields(self) -> dict[str, tuple[type, Spec, Any, type[Settings]]]:
        """Name -> (scalar type, spec, default, declaring class), in declaration order."""
        out: dict[str, tuple[type, Spec, Any, type[Settings]]] = {}
        for kind in self.settings:
            defaults = kind()
            for name, (scalar, spec) in kind.fields().items():
                out.setdefault(name, (scalar, spec, getattr(defaults, name), kind))
        return out


def _nodes() -> tuple[NodeParameters, ...]:
    # Imported here: the controller's settings import every law installed.
    from turning_force.core.control import ControllerSettings
    from turning_force.core.estimation.settings import EstimatorSettings
    from turning_force.core.plant.daq import DaqSettings
    from turning_force.core.plant.settings import PlantSettings
    from turning_force.core.pmc.settings import BridgeSettings

    return (
        NodeParameters('experiment', 'The run itself (not a node: `turning-force run` reads '
                       'it): duration, scoring, the paper it reproduces', (RunSettings,)),
        NodeParameters('lathe_sim', 'The simulated lathe: cutting process (Park Eq. 1), feed '
                       'servo, current sensing, injected faults, simulated machine inputs',
                       (PlantSettings, LatheSimNodeSettings)),
        NodeParameters('force_estimator', "Cutting force from the feed drive's phase "
                       'currents (Park Sec. 3, Eqs. 25-26): d-q transform, filter, friction',
                       (EstimatorSettings,)),
        NodeParameters('force_controller', 'The control law and what every law shares; '
                       "each law's own parameters carry its name as a prefix",
                       (ControllerSettings,)),
        NodeParameters('pmc_bridge', 'The override gate and the PMC: safety holds, shop-floor '
                       'behaviours, the cut log', (BridgeSettings, BridgeNodeSettings)),
        NodeParameters('session_recorder', 'Where the session is recorded and what it embeds',
                       (RecorderSettings,)),
        NodeParameters('servo_daq', "The machine PC's NI-DAQ: phase currents and rotor angle",
                       (DaqSettings,)),
    )


NODES: tuple[NodeParameters, ...] = _nodes()
_BY_NODE = {n.node: n for n in NODES}


@dataclass(frozen=True)
class Parameter:
    """One parameter of one node, as ``describe`` prints it."""

    node: str
    name: str
    kind: type
    spec: Spec
    default: Any
    owner: str   # the control law whose parameter it is ('' for every law's, other nodes)
    shared_with: tuple[str, ...]   # the other nodes that declare it (one value, under /**)

    @property
    def type_text(self) -> str:
        array = isinstance(self.default, tuple)
        return f'list of {self.kind.__name__}' if array else self.kind.__name__

    @property
    def unit_text(self) -> str:
        if self.kind in (int, float):
            return 'dimensionless' if self.spec.unit == DIMENSIONLESS else self.spec.unit
        return ''

    @property
    def range_text(self) -> str:
        if self.spec.choices:
            return 'one of ' + ', '.join(self.spec.choices)
        if self.kind is bool:
            return 'true or false'
        if self.kind is str:
            return 'text'
        return self.spec.range_text() + self.spec.unit_text

    @property
    def default_text(self) -> str:
        return _yaml(self.default)

    @property
    def changes_text(self) -> str:
        return 'while cutting' if self.spec.dynamic else 'fixed for a session (read-only)'

    def section_text(self) -> str:
        """Where an experiment file sets it."""
        if self.node == 'servo_daq':
            where = "the machine PC's parameters file, under `/**/servo_daq: ros__parameters:`"
        else:
            where = f'an experiment file, under `/**/{self.node}: ros__parameters:`'
        if self.shared_with:
            where += (' or once under `/**: ros__parameters:` for every node that declares it '
                      f'({", ".join((self.node, *self.shared_with))}: one value)')
        return where


def _yaml(value: Any) -> str:
    if isinstance(value, bool):
        return 'true' if value else 'false'
    if isinstance(value, tuple):
        return '[' + ', '.join(_yaml(v) for v in value) + ']'
    if isinstance(value, str):
        return repr(value) if value == '' else value
    return f'{value:g}' if isinstance(value, float) else str(value)


def _law_owners() -> dict[str, str]:
    """force_controller field -> the law that declares it (every law's own)."""
    from turning_force.core.control.law import ControllerBase
    from turning_force.core.control.registry import CONTROLLERS

    base = {f.name for f in dataclasses.fields(ControllerBase)}
    return {f.name: law.name for law in CONTROLLERS.values()
            for f in dataclasses.fields(law.settings) if f.name not in base}


def parameters(node: str | None = None) -> Iterator[Parameter]:
    """Every parameter of ``node`` (of every node when None), in declaration order."""
    owners = _law_owners()
    declared = {n.node: set(n.fields()) for n in NODES}
    for entry in NODES if node is None else (_node(node),):
        for name, (kind, spec, default, _) in entry.fields().items():
            # /** reaches every section of an experiment file; servo_daq reads a file of its own.
            shared = tuple(other for other, names in declared.items()
                           if other not in (entry.node, 'servo_daq')
                           and entry.node != 'servo_daq' and name in names)
            yield Parameter(entry.node, name, kind, spec, default,
                            owners.get(name, '') if entry.node == 'force_controller' else '',
                            shared)


def _node(node: str) -> NodeParameters:
    found = _BY_NODE.get(node)
    if found is None:
        raise ConfigError(f'{node!r}: no such node; the nodes: {", ".join(_BY_NODE)}')
    return found


def find(target: str) -> Parameter:
    """``NODE.PARAM`` -> its :class:`Parameter`; a :class:`ConfigError` names what is wrong."""
    node, _, name = target.partition('.')
    entry = _node(node)
    for parameter in parameters(entry.node):
        if parameter.name == name:
            return parameter
    close = difflib.get_close_matches(name, [p.name for p in parameters(entry.node)], n=3)
    hint = f'; did you mean {" or ".join(close)}?' if close else ''
    raise ConfigError(f'{target!r}: {node} has no parameter {name!r}{hint} '
                      f'(turning-force describe {node} lists them)')


def experiments_setting(parameter: Parameter, directory: Path) -> list[tuple[str, Any]]:
    """The experiment files in ``directory`` that set ``parameter``, and the value each gives
    (its own section's, else the shared ``/**`` one)."""
    found = []
    for path in sorted(directory.glob('*.yaml')):
        try:
            sections = parameter_sections(load_yaml(read_text(path)), str(path))
        except (ConfigError, ValueError):
            continue   # not an experiment file (describe is not where a broken one is told)
        for section in (parameter.node, SHARED):
            params = sections.get(section, {})
            if parameter.name in params:
                found.append((path.name, params[parameter.name]))
                break
    return found


def describe(target: str | None = None, directory: Path | None = None) -> str:
    """The text ``turning-force describe`` prints: every node (no target), one node's
    parameters (``NODE``), or one parameter in full (``NODE.PARAM``), with the files of
    ``directory`` that set it."""
    if not target:
        lines = ['nodes (turning-force describe NODE lists its parameters; NODE.PARAM explains '
                 'one):']
        for entry in NODES:
            lines.append(f'  {entry.node:18s} {len(entry.fields()):3d} parameters  '
                         f'{entry.summary}')
        return '\n'.join(lines)
    if '.' not in target:
        entry = _node(target)
        rows = list(parameters(entry.node))

        def default(p: Parameter) -> str:
            unit = p.unit_text if p.unit_text != 'dimensionless' else ''
            return f'{p.default_text} {unit}'.strip()

        # Columns as wide as most of their cells: a long list or choice runs over.
        widths = [max(len(p.name) for p in rows), min(max(len(default(p)) for p in rows), 14),
                  min(max(len(p.range_text) for p in rows), 22)]
        lines = [f'{entry.node}: {entry.summary}',
                 f'  {"parameter":{widths[0]}s}  {"default":>{widths[1]}s}  '
                 f'{"range":{widths[2]}s}  meaning ([law] where one law reads it)']
        for p in rows:
            law = f'[{p.owner}] ' if p.owner else ''
            lines.append(f'  {p.name:{widths[0]}s}  {default(p):>{widths[1]}s}  '
                         f'{p.range_text:{widths[2]}s}  {law}{p.spec.description}')
        return '\n'.join(lines)
    p = find(target)
    lines = [f'{p.node}.{p.name}', f'  {p.spec.description}',
             f'  type:     {p.type_text}',
             f'  unit:     {p.unit_text or "-"}',
             f'  range:    {p.range_text}',
             f'  default:  {p.default_text}',
             f'  changes:  {p.changes_text}',
             f'  paper:    {p.spec.cite or "-"}']
    if p.owner:
        lines.append(f'  law:      read by the {p.owner} law (force_controller.controller = '
                     f'{p.owner})')
    lines.append(f'  set in:   {p.section_text()}; or on the command line: '
                 f'--set {p.node}.{p.name}=VALUE')
    if directory is not None:
        files = experiments_setting(p, directory)
        given = ', '.join(f'{name} ({_yaml(value)})' for name, value in files)
        lines.append(f'  set by:   {given or "no file in " + str(directory) + " (the default)"}')
    return '\n'.join(lines)


def _cell(text: str) -> str:
    return text.replace('|', '\\|')


def parameters_markdown() -> str:
    """docs/parameters.md: every parameter of every node, our laws' (not those installed from
    other packages: they document their own)."""
    from turning_force.core.control.registry import OURS, law_modules

    ours = {name for name, module in law_modules().items() if module.startswith(OURS)}
    out = ['# Parameters', '',
           '<!-- Generated by `turning-force describe --markdown > docs/parameters.md` from the '
           'settings declarations (the source of the ROS parameter descriptors): do not edit; a '
           'test fails when this file is out of step. -->', '',
           'Every parameter of every node: its default, unit, range, whether it may change '
           'while cutting, and the paper and equation it comes from. An experiment file sets '
           "a node's parameters under `/**/NODE: ros__parameters:`; the ones several nodes "
           'declare (the control period, the spindle speed, the programmed feed, the override '
           "table, the feed axis's force range) once under `/**: ros__parameters:`. "
           '`turning-force describe NODE.PARAM` says the same for one, and which experiment '
           'files set it; `--set NODE.PARAM=VALUE` changes one for a run.', '']
    for entry in NODES:
        out += [f'## {entry.node}', '', entry.summary + '.', '',
                '| parameter | default | unit | range | changes | meaning | paper |',
                '| --- | --- | --- | --- | --- | --- | --- |']
        for p in parameters(entry.node):
            if p.owner and p.owner not in ours:
                continue
            law = f'({p.owner} law) ' if p.owner else ''
            changes = 'while cutting' if p.spec.dynamic else 'read-only'
            bare = p.spec.range_text() if p.kind in (int, float) else p.range_text
            out.append('| ' + ' | '.join(_cell(c) for c in (
                f'`{p.name}`', f'`{p.default_text}`', p.unit_text, bare, changes,
                law + p.spec.description, p.spec.cite)) + ' |')
        out.append('')
    return '\n'.join(out)


def missing_metadata(among: Iterable[Parameter] | None = None) -> list[str]:
    """Every parameter (of ``among``; default: every node's) without a text saying what it is,
    or a number without a unit or without both ends of its range (the ROS descriptor carries
    a range only with both), one line each. Text and flags have no unit; text ranges over its
    choices where it has them."""
    problems = []
    for p in parameters() if among is None else among:
        where = f'{p.node}.{p.name}'
        if len(p.spec.description) < 10:
            problems.append(f'{where}: no text saying what it is')
        if p.kind in (int, float):
            if not p.spec.unit:
                problems.append(f'{where}: no unit (dimensionless: {DIMENSIONLESS!r})')
            if p.spec.low is None or p.spec.high is None:
                problems.append(f'{where}: range {p.spec.range_text()} is open-ended')
    return problems
