"""The exceptions of turning_force: one small family, so callers catch what they mean."""

from __future__ import annotations

__all__ = ['ConfigError', 'NoCutError', 'TurningForceError', 'short_repr', 'shortened']


class TurningForceError(Exception):
    """Base of every error turning_force raises on purpose."""


class NoCutError(TurningForceError, ValueError):
    """A run in which the tool never cut (an air cut): there is no force to score."""


class ConfigError(TurningForceError, ValueError):
    """A setting is missing, malformed or out of range.

    The message names the key (``section.name``) and the bad value, and says what was expected.
    """


def shortened(text: str, limit: int = 80) -> str:
    """``text`` on one line and at most ``limit`` characters, for an error line that names a
    bad value (a whole file echoed back would bury the line)."""
    flat = ' '.join(str(text).split())
    return flat if len(flat) <= limit else f'{flat[:limit - 3]}...'


def short_repr(value: object, limit: int = 60) -> str:
    """``repr(value)`` cut to ``limit`` characters, for an error line that names a bad value
    (a value of megabytes is named by its start and its length, never echoed whole)."""
    if isinstance(value, str | bytes | list | tuple):
        text = repr(value[:limit + 1])
        length = f' ({len(value)} long)'
    else:
        text, length = repr(value), ''
    return text if len(text) <= limit else f'{text[:limit]}...{length}'
