"""An experiment: one ROS 2 parameters file, read into validated settings for every node.

The file is what ``ros2 run ... --ros-args --params-file`` reads on the lathe PC::

    /**:                      # shared by every node that declares the parameter
      ros__parameters: {spindle_speed_rpm: 600.0, programmed_feed_mm_rev: 0.2, ...}
    /**/experiment:           # the run itself: duration, metrics, the paper's figure
      ros__parameters: {...}
    /**/lathe_sim: ...  /**/force_estimator: ...  /**/force_controller: ...
    /**/pmc_bridge: ...  /**/session_recorder: ...

Node sections are written ``/**/<node>`` so that they reach the node in any namespace (a graph
per machine, ``/lathe1/...``); ROS reads a bare ``force_estimator`` as ``/force_estimator``
only. Keys under a node's own section must be parameters that node declares; a typo is an
error, not a silently ignored line. Keys under ``/**`` reach every section that knows them. A key
given twice, in one mapping or in two sections of one node, is an error too: YAML would keep the
last one without a word.
"""

from __future__ import annotations

import functools
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypeVar

import yaml

from turning_force.core import shared
from turning_force.core.control import ControllerSettings
from turning_force.core.errors import ConfigError
from turning_force.core.estimation.settings import EstimatorSettings
from turning_force.core.metrics import MetricSettings
from turning_force.core.plant.settings import PlantSettings
from turning_force.core.pmc.overrides import get_table
from turning_force.core.pmc.settings import BridgeSettings
from turning_force.core.settings import Settings, setting
from turning_force.core.yamlfile import load_yaml, read_text, yaml_error_text

__all__ = [
    'Experiment',
    'RecorderSettings',
    'RunSettings',
    'ViewSettings',
    'assignments',
    'build_experiment',
    'check_node',
    'load_experiment',
    'parameter_sections',
    'parse_experiment',
    'parse_set',
]

SHARED = '/**'
_T = TypeVar('_T')


@dataclass(frozen=True)
class RunSettings(Settings):
    """The run (``experiment`` section): what it reproduces, how long, how it is scored."""

    SECTION = 'experiment'

    name: str = setting('experiment', 'Short name of the experiment')
    description: str = setting('', 'What the experiment shows')
    paper_figure: str = setting('', 'The paper figure it reproduces, if any')
    paper_steady_mean_abs_error_n: float = setting(
        0.0, "The paper's average tracking error for this figure; 0: the paper gives none", 'N',
        low=0.0, high=1e5)
    duration_s: float = setting(12.0, 'Simulated time', 's', low=0.0, low_open=True, high=3600.0)
    control_period_s: float = shared.control_period_s()
    settle_window_s: float = setting(1.0, 'Left out of the steady metrics after each change', 's',
                                     low=0.0, high=60.0)
    allowed_error_n: float = shared.allowed_error_n()
    arm_bridge: bool = setting(True, 'The run arms the PMC bridge; false keeps it disarmed, the '
                               'machine at the programmed feed (an air cut for calibration). '
                               'pmc_bridge.armed, where a file gives it, says the same')

    def check(self) -> None:
        # The name becomes a file name (bags/<name>_<time>): nothing that leaves that folder.
        if not self.name or self.name in ('.', '..') or any(c in self.name for c in '/\\\0'):
            self.fail('name', 'must be a plain file name (no /, \\, .. or empty)')


@dataclass(frozen=True)
class RecorderSettings(Settings):
    """The ``session_recorder`` section: where the session goes and what it embeds.

    ``turning-force run`` sets these itself; on the machine PC they come from the file.
    """

    SECTION = 'session_recorder'

    output_dir: str = setting('', 'rosbag2 folder to create (must not exist); empty: '
                              'bags/session_<time>')
    experiment_file: str = setting('', 'Experiment parameters file to embed in the session')
    flush_period_s: float = setting(1.0, 'Longest wall time between writes to the disk', 's',
                                    low=0.0, low_open=True, high=3600.0)
    capture_parameters: bool = setting(True, 'Ask the graph nodes for their parameters and '
                                       'embed them')


@dataclass(frozen=True)
class ViewSettings(Settings):
    """The ``live_view`` section: the Foxglove WebSocket server of ``turning-force view``.

    It binds to this machine only unless ``host`` says otherwise: the protocol has no
    authentication, and anyone who reaches the port sees the machine's signals.
    """

    SECTION = 'live_view'

    host: str = setting('127.0.0.1', 'Address the WebSocket server binds to (0.0.0.0: every '
                        'interface)')
    port: int = setting(8765, 'TCP port of the WebSocket server; 0: a free one, printed',
                        low=0, high=65535)
    rate_hz: float = setting(0.0, 'Most messages a second forwarded on each streaming topic (one '
                             'message a block); 0: every message', 'Hz', low=0.0, high=10000.0)
    allowed_error_n: float = shared.allowed_error_n()

    def check(self) -> None:
        if not self.host.strip():
            self.fail('host', 'must be an address to bind to (127.0.0.1, 0.0.0.0, a name)')


@dataclass(frozen=True)
class Experiment:
    """Every node's settings for one run, and the parameter file they came from."""

    source: str
    run: RunSettings
    plant: PlantSettings
    estimator: EstimatorSettings
    controller: ControllerSettings
    bridge: BridgeSettings
    sections: Mapping[str, Mapping[str, Any]]

    @property
    def metric_settings(self) -> MetricSettings:
        return MetricSettings(self.run.settle_window_s, self.run.allowed_error_n)

    def resolved_params(self) -> dict[str, dict[str, Any]]:
        """Every node's full parameter set, defaults included: what the run used."""
        return {
            s.SECTION: s.to_params()
            for s in (self.run, self.plant, self.estimator, self.controller, self.bridge)
        }

    def with_sets(self, assignments: Sequence[str]) -> Experiment:
        """A copy with ``node.param=value`` assignments applied (values parsed as YAML)."""
        sections = {name: dict(params) for name, params in self.sections.items()}
        for text in assignments:
            node, param, value = parse_set(text)   # '/**.param=value' sets a shared value
            check_node(node, f'--set {text!r}: unknown node {node!r}')
            sections.setdefault(node, {})[param] = value
        return build_experiment(self.source, sections)


SETTINGS_OF: Mapping[str, type[Settings]] = {
    'experiment': RunSettings,
    'lathe_sim': PlantSettings,
    'force_estimator': EstimatorSettings,
    'force_controller': ControllerSettings,
    'pmc_bridge': BridgeSettings,
}
# Sections of nodes outside the control loop: validated, not part of an Experiment.
OTHER_SECTIONS: Mapping[str, type[Settings]] = {
    'session_recorder': RecorderSettings,
    'live_view': ViewSettings,
}
_SECTIONS: Mapping[str, type[Settings]] = {**SETTINGS_OF, **OTHER_SECTIONS}


def check_node(node: str, unknown: str) -> None:
    """Refuse a section no node of the graph has: ``unknown`` and the known ones."""
    if node != SHARED and node not in SETTINGS_OF and node not in OTHER_SECTIONS:
        known = ', '.join([SHARED, *SETTINGS_OF, *OTHER_SECTIONS])
        raise ConfigError(f'{unknown}; known: {known}')


def assignments(node: str, params: Mapping[str, Any]) -> list[str]:
    """``node.param=value`` for each parameter, as :meth:`Experiment.with_sets` and ``--set``
    read them (text bare, numbers and the rest as Python writes them, which YAML reads back)."""
    return [f'{node}.{key}={value if isinstance(value, str) else repr(value)}'
            for key, value in params.items()]


def parse_set(text: str) -> tuple[str, str, Any]:
    """``node.param=value`` -> (node, param, value), the value parsed as YAML."""
    target, sep, raw = text.partition('=')
    node, dot, param = target.strip().rpartition('.')
    if not (sep and dot and node and param):
        raise ConfigError(f'--set {text!r}: expected node.param=value')
    try:
        value = load_yaml(raw)
    except yaml.YAMLError as exc:
        raise ConfigError(f'--set {text!r}: value is not valid YAML: '
                          f'{yaml_error_text(exc)}') from exc
    return node, param, value


def load_experiment(path: str | Path) -> Experiment:
    """Read and validate an experiment parameters file."""
    path = Path(path)
    return parse_experiment(read_text(path), str(path))


def parse_experiment(text: str, path: str) -> Experiment:
    """Validate an experiment parameters file's text; errors name ``path``."""
    try:
        data = load_yaml(text)
    except yaml.YAMLError as exc:
        raise ConfigError(f'{path}: not valid YAML: {yaml_error_text(exc)}') from exc
    sections = parameter_sections(data, path)
    try:
        return build_experiment(path, sections)
    except ConfigError as exc:
        raise ConfigError(f'{path}: {exc}') from exc


def parameter_sections(data: Any, path: str) -> dict[str, dict[str, Any]]:
    """A ROS 2 parameters file's YAML as sections by node name (``/**/force_controller`` ->
    ``force_controller``; ``/**`` stays ``/**``); errors name ``path``, the node and the key.
    A parameter given twice for one node (under ``/**/x`` and ``x``, say) is refused."""
    if not isinstance(data, dict):
        raise ConfigError(f'{path}: expected a mapping of node names, got {type(data).__name__}')
    sections: dict[str, dict[str, Any]] = {}
    given_in: dict[tuple[str, str], str] = {}
    for node, body in data.items():
        if not str(node).isprintable():
            raise ConfigError(f'{path}: {node!r}: not a node name')
        name = str(node) if node == SHARED else str(node).rstrip('/').rsplit('/', 1)[-1]
        params = body.get('ros__parameters') if isinstance(body, dict) else None
        if not isinstance(params, dict):
            raise ConfigError(f'{path}: {node}: expected a ros__parameters mapping')
        check_node(name, f'{path}: {node}: unknown node')
        for key in params:
            if not str(key).isprintable():
                raise ConfigError(f'{path}: {node}: {key!r}: not a parameter name')
            first = given_in.setdefault((name, str(key)), str(node))
            if first != str(node):
                raise ConfigError(f'{path}: {node}: {key} is set under {first} already; one '
                                  'value per parameter')
        sections.setdefault(name, {}).update(params)
    return sections


# Settings built from the same parameters, again: the commissioning's verification builds a
# thousand experiments that differ in the controller's section alone. A settings object is
# frozen, so one serves them all.
def _frozen(value: Any) -> Any:
    """``value`` as a key: its type with it, at every level (1, 1.0 and True are three
    values to a settings field: an int field refuses 1.0)."""
    if isinstance(value, (list, tuple)):
        return type(value), tuple(_frozen(v) for v in value)
    if isinstance(value, Mapping):
        return dict, tuple((k, _frozen(v)) for k, v in value.items())
    hash(value)   # TypeError where it cannot be a key
    return type(value), value


def _thawed(key: Any) -> Any:
    """The value :func:`_frozen` made ``key`` of."""
    kind, value = key
    if kind is dict:
        return {k: _thawed(v) for k, v in value}
    if kind in (list, tuple):
        return kind(_thawed(v) for v in value)
    return value


@functools.lru_cache(maxsize=256)
def _built(section: str, key: Any) -> Settings:
    return _SECTIONS[section].from_params(_thawed(key))


def _settings(section: str, params: Mapping[str, Any]) -> Settings:
    """The settings of ``section`` (SETTINGS_OF, OTHER_SECTIONS) from ``params``, built once
    for the same parameters."""
    try:
        key = _frozen(params)
    except TypeError:
        return _SECTIONS[section].from_params(params)
    return _built(section, key)


def build_experiment(source: str, sections: Mapping[str, Mapping[str, Any]]) -> Experiment:
    """Validated settings from parameter sections (``/**`` shared, then per node)."""
    shared = dict(sections.get(SHARED, {}))
    unused = set(shared)
    built: dict[str, Settings] = {}
    for name, kind in _SECTIONS.items():
        known = kind.fields()
        params = {k: v for k, v in shared.items() if k in known}
        unused -= set(params)
        params.update(sections.get(name, {}))
        built[name] = _settings(name, params)
    if unused:
        names = sorted(str(k) for k in unused)
        raise ConfigError(f'{SHARED}: {names}: no node declares these parameters')
    run, bridge = _resolve_arming(sections, _as(built['experiment'], RunSettings),
                                  _as(built['pmc_bridge'], BridgeSettings))
    controller = _as(built['force_controller'], ControllerSettings)
    experiment = Experiment(
        source=source,
        run=run,
        plant=_resolve_approach(sections, _as(built['lathe_sim'], PlantSettings), controller,
                                bridge),
        estimator=_as(built['force_estimator'], EstimatorSettings),
        controller=controller,
        bridge=bridge,
        sections={k: dict(v) for k, v in sections.items()},
    )
    _check_consistent(experiment)
    return experiment


def _resolve_arming(sections: Mapping[str, Mapping[str, Any]], run: RunSettings,
                    bridge: BridgeSettings) -> tuple[RunSettings, BridgeSettings]:
    """One answer to "is the bridge armed in this run", in both places that can say it.

    ``experiment.arm_bridge`` (default true: a desk run regulates) and ``pmc_bridge.armed``
    (default false: a bridge on the machine starts disarmed). A file that gives one decides;
    a file that gives both must agree. The settings then say what runs, so the session records
    what ran.
    """
    def given(section: str, key: str) -> bool:
        return key in sections.get(section, {}) or key in sections.get(SHARED, {})

    if given('pmc_bridge', 'armed'):
        if given('experiment', 'arm_bridge') and run.arm_bridge != bridge.armed:
            raise ConfigError(
                f'pmc_bridge.armed = {bridge.armed!r}: contradicts experiment.arm_bridge = '
                f'{run.arm_bridge!r}; give one of them')
        return run.replace(arm_bridge=bridge.armed), bridge
    return run, bridge.replace(armed=run.arm_bridge)


def _resolve_approach(sections: Mapping[str, Mapping[str, Any]], plant: PlantSettings,
                      controller: ControllerSettings, bridge: BridgeSettings) -> PlantSettings:
    """The override the simulated axis approached the work at before t = 0, where the file
    does not say: the level the PMC holds while the tool is in air. An armed bridge with an
    entry feed holds that (never above the controller's request, its initial override); else
    the PMC holds the controller's initial override. Quantised to the machine's table: the
    simulated lathe, the core loop and the graph start from the same level."""
    if 'approach_override_pct' in sections.get('lathe_sim', {}):
        return plant
    initial = controller.initial_override_pct
    entry = bridge.air_cut_override_pct
    level = min(initial, entry) if bridge.armed and entry > 0 else initial
    return plant.replace(approach_override_pct=get_table(plant.override_table).quantise(level))


def _as(value: object, kind: type[_T]) -> _T:
    assert isinstance(value, kind)
    return value


def _check_consistent(e: Experiment) -> None:
    # Settings several nodes declare must agree: one value, set once under /**.
    tied = (('control_period_s', e.run, (e.plant, e.controller, e.bridge)),
            ('max_feed_force_n', e.bridge, (e.controller,)),
            ('override_table', e.bridge, (e.controller, e.plant)),
            ('tools_file', e.bridge, (e.controller,)))
    for key, first, others in tied:
        for section in others:
            if getattr(section, key) != getattr(first, key):
                raise ConfigError(
                    f'{section.SECTION}.{key} = {getattr(section, key)!r}: differs from '
                    f'{first.SECTION}.{key} = {getattr(first, key)!r}; set it once under {SHARED}')
    if e.controller.reference_force_n >= e.bridge.overload_force_n:
        raise ConfigError(
            f'force_controller.reference_force_n = {e.controller.reference_force_n!r}: not below '
            f'pmc_bridge.overload_force_n = {e.bridge.overload_force_n!r}: the regulated force '
            'would hold the feed')
    if e.bridge.tools_file:
        _check_tools(e)
    bridge = e.bridge
    if bridge.air_cut_override_pct > 0 and bridge.engage_force_n >= e.controller.reference_force_n:
        raise ConfigError(
            f'pmc_bridge.engage_force_n = {e.bridge.engage_force_n!r}: not below '
            f'force_controller.reference_force_n = {e.controller.reference_force_n!r}: the tool '
            'would never count as in the cut, and the entry feed (air_cut_override_pct = '
            f'{e.bridge.air_cut_override_pct!r} %) would hold the whole cut; lower '
            'engage_force_n and exit_force_n, or set air_cut_override_pct to 0')


def _check_tools(e: Experiment) -> None:
    """Refuse a tools file a program cannot run on: a tool the simulated program changes to
    without a section (never run on another tool's settings), a section the nodes refuse, a
    tool whose reference would hold the feed."""
    from turning_force.core.tools import TOOL_BRIDGE_KEYS, load_tools_file, tool_settings

    path = e.bridge.tools_file
    tools = load_tools_file(path)
    if e.plant.tool_wired:
        missing = sorted({n for n in e.plant.tool_numbers if n not in tools})
        if missing:
            raise ConfigError(f'lathe_sim.tool_numbers = {list(e.plant.tool_numbers)}: tool '
                              f'{", ".join(map(str, missing))} has no section in the tools file '
                              f'{path} (sections: {sorted(tools) or "none"}); a tool is not run '
                              "on another's settings: `turning-force identify --tool N --out "
                              f'{path}` writes one')
    controllers = tool_settings(e.controller, tools, path)
    bridges = tool_settings(e.bridge, tools, path, TOOL_BRIDGE_KEYS)
    for number, controller in controllers.items():
        if controller.reference_force_n >= bridges[number].overload_force_n:
            raise ConfigError(
                f'{path}: tools.{number}: reference_force_n {controller.reference_force_n!r} N '
                f'not below overload_force_n {bridges[number].overload_force_n!r} N: the '
                'regulated force would hold the feed')
