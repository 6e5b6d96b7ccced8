"""The exceptions of turning_force: one small family, so callers catch what they mean."""

from __future__ import annotations

__all__ = ['ConfigError', 'NoCutError', 'TurningForceError', 'shortened']


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
