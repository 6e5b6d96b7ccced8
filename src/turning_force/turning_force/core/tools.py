"""Per-tool settings: a tools file, one section per tool number, that the machine's tool input
selects from (docs/commissioning.md, "One section per tool").

A turret holds tools of different inserts and depths; commercial adaptive feed keeps its limits
per tool. The tools file (``tools_file``, read by ``force_controller`` and ``pmc_bridge``) gives,
per tool number, the controller's settings that differ for it (the reference force, the law's
commissioning results: what ``turning-force identify --tool N`` writes) and the bridge's
per-tool limits (:data:`TOOL_BRIDGE_KEYS`: the entry level, the feed floor, the overload limit,
the cut detector's thresholds, the rise limit)::

    tools:
      1:
        force_controller: {reference_force_n: 500.0, smc_ksd_min_n_mm: 1900.0}
        pmc_bridge: {air_cut_override_pct: 30.0}
      2:
        force_controller: {reference_force_n: 350.0}

What a section does not give, the node's own settings give. A tool with no section is never
run on another's: configure refuses a program whose tools it does not cover, and a tool number
without a section arriving while running hands the feed back with the reason. Settings fixed
for the session (the law, the control period, the override table, the spindle and the feed
axis) are the machine's, not a tool's: a section giving one is refused.
"""

from __future__ import annotations

from collections.abc import Collection, Mapping
from pathlib import Path
from typing import Any, TypeVar

import yaml

from turning_force.core.errors import ConfigError, short_repr
from turning_force.core.settings import Settings
from turning_force.core.yamlfile import read_yaml_file, replace_file

__all__ = ['FIXED_CONTROLLER_KEYS', 'NO_TOOL', 'TOOL_BRIDGE_KEYS', 'ToolSections',
           'load_tools_file', 'save_tool_section', 'tool_settings']

# A tool's sections: tool number -> node -> parameter -> value.
ToolSections = dict[int, dict[str, dict[str, Any]]]

# The pmc_bridge parameters a tool's section may give (the order of gate.TOOL_GATE).
TOOL_BRIDGE_KEYS = ('air_cut_override_pct', 'min_cut_override_pct', 'overload_force_n',
                    'engage_force_n', 'exit_force_n', 'rise_rate_pct_s')
# The force_controller parameters that are the machine's, not a tool's.
FIXED_CONTROLLER_KEYS = frozenset({
    'controller', 'control_period_s', 'spindle_speed_rpm', 'spindle_speed_stale_s',
    'programmed_feed_mm_rev', 'override_table', 'max_feed_force_n', 'tools_file',
    'initial_override_pct'})
NODES = ('force_controller', 'pmc_bridge')
MAX_TOOL = 9999   # a T code's tool number (FANUC: up to four digits)
NO_TOOL = -2      # a tool input that reads no number (a BCD digit above 9): no section has it

S = TypeVar('S', bound=Settings)


def load_tools_file(path: str | Path) -> ToolSections:
    """A tools file's sections; ``ConfigError`` naming the file and key of anything malformed
    (a missing file too: a tool's settings are not to be guessed)."""
    path = Path(path)
    data = read_yaml_file(path, ' tools file')
    if not isinstance(data, Mapping) or set(data) != {'tools'} or not isinstance(
            data['tools'], Mapping):
        raise ConfigError(f'{path}: expected a mapping with one key, tools: a mapping of tool '
                          'number -> {force_controller: ..., pmc_bridge: ...}')
    out: ToolSections = {}
    for number, section in data['tools'].items():
        key = f'tools.{number}'
        if isinstance(number, bool) or not isinstance(number, int) or not (
                0 <= number <= MAX_TOOL):
            raise ConfigError(f'{path}: {key}: expected a tool number 0 to {MAX_TOOL}')
        if not isinstance(section, Mapping) or set(section) - set(NODES):
            raise ConfigError(f'{path}: {key} = {short_repr(section)}: expected a mapping with '
                              f'{" and/or ".join(NODES)}')
        out[number] = {}
        for node, params in section.items():
            if not isinstance(params, Mapping):
                raise ConfigError(f'{path}: {key}.{node} = {short_repr(params)}: expected a '
                                  'mapping of parameter -> value')
            out[number][node] = dict(params)
    return out


def tool_settings(base: S, sections: ToolSections, source: str,
                  allowed: Collection[str] | None = None) -> dict[int, S]:
    """``base`` with each tool's section for its node (``base.SECTION``) applied, validated as
    the node validates its own; ``allowed``: the keys a section may give (None: every one but
    :data:`FIXED_CONTROLLER_KEYS`). Errors name ``source``, the tool and the key."""
    out: dict[int, S] = {}
    for number, section in sorted(sections.items()):
        params = section.get(base.SECTION, {})
        where = f'{source}: tools.{number}.{base.SECTION}'
        for name, value in params.items():
            fixed = name in FIXED_CONTROLLER_KEYS or (allowed is not None and name not in allowed)
            if name == 'controller' and value != getattr(base, name):
                raise ConfigError(f'{where}.controller = {short_repr(value)}: the law is the '
                                  f"machine's, one for every tool ({base.SECTION}.controller = "
                                  f'{getattr(base, name)!r}); run {value} for every tool, or '
                                  "commission this tool for the machine's law")
            if fixed and name != 'controller':
                given = ', '.join(allowed) if allowed is not None else 'the others'
                raise ConfigError(f'{where}.{name} = {short_repr(value)}: not a per-tool '
                                  f'setting (per tool: {given}); set it for the machine')
        try:
            out[number] = type(base).from_params({**base.to_params(), **params})
        except ConfigError as exc:
            raise ConfigError(f'{where}: {exc}') from exc
    return out


def save_tool_section(path: str | Path, number: int, section: Mapping[str, Mapping[str, Any]],
                      header: str = '') -> None:
    """Write (or update) tool ``number``'s section of a tools file, keeping the other tools'
    (a missing file is created); the file is replaced at once, never half written."""
    path = Path(path)
    tools = load_tools_file(path) if path.exists() else {}
    tools[number] = {node: dict(params) for node, params in section.items()}
    comment = ''.join(f'# {line}\n' for line in header.splitlines())
    replace_file(path, '# turning_force tools file: one section per tool number (tools_file)\n'
                 + comment + yaml.safe_dump({'tools': dict(sorted(tools.items()))},
                                            sort_keys=False), ' tools file')
