"""Settings that several nodes share, declared once.

The plant, the controller and the PMC bridge each need some of the same machine facts (the control
period, the spindle speed, the programmed feed, the feed axis's force range; the override table's
is :func:`turning_force.core.pmc.overrides.override_table`). Each is declared here once, with its
description, unit and range, and the settings classes take their fields from these factories, so
that the value a file gives under ``/**`` is checked by one rule wherever it lands. """

from __future__ import annotations

from typing import Any

from turning_force.core.settings import setting

__all__ = [
    'allowed_error_n',
    'control_period_s',
    'max_feed_force_n',
    'programmed_feed_mm_rev',
    'spindle_speed_rpm',
    'spindle_speed_stale_s',
    'tools_file',
]


def control_period_s() -> Any:
    """One block of currents, one force estimate, one feed command (Park: 10 ms)."""
    return setting(0.01, 'Control period: one block of currents, one estimate, one command (Park: '
                   '10 ms)', 's', low=1e-4, high=1.0, cite='Park 1998, Sec. 2.3')


def allowed_error_n() -> Any:
    """The band about the reference that the metrics, the report and the live view draw."""
    return setting(10.0, 'Allowed tracking error: the band of the settling time and of the '
                   'figures', 'N', low=0.0, low_open=True, high=1e5)


def spindle_speed_rpm() -> Any:
    return setting(600.0, 'Spindle speed N', 'rpm', low=0.0, low_open=True, high=20000.0)


def spindle_speed_stale_s() -> Any:
    return setting(0.5, 'The live spindle speed (machine/spindle_speed) older than this counts as '
                   'unplugged: spindle_speed_rpm is used and /diagnostics warns; 0: the topic is '
                   'not read', 's', low=0.0, high=60.0)


def programmed_feed_mm_rev() -> Any:
    return setting(0.2, 'Programmed feed (the 100 % override)', 'mm/rev', low=0.0,
                   low_open=True, high=5.0)


def max_feed_force_n() -> Any:
    """The force range of the feed axis: what the overload limit and the reference must stay
    inside. Park's FANUC 0-T z axis reads about 145 N per ampere; a 30 A current sensor spans
    about 4400 N."""
    return setting(5000.0, 'Largest feed force the feed axis, its drive and its current sensor '
                   'are rated for; the overload limit and the reference stay below it', 'N',
                   low=0.0, low_open=True, high=1e5)


def tools_file() -> Any:
    """Per-tool settings (core/tools.py): the controller's and the bridge's, per tool number."""
    return setting('', 'Tools file (YAML, one section per tool number: the reference, the '
                   "law's commissioning results, the entry level and limits; `turning-force "
                   "identify --tool N` writes one): the machine's tool input (machine/tool) "
                   "selects the section; a tool without one is never run on another's; empty: "
                   'these settings for every tool')
