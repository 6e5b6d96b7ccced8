"""The exceptions of turning_force: one small family, so callers catch what they mean."""

from __future__ import annotations

__all__ = ['ConfigError', 'TurningForceError']


class TurningForceError(Exception):
    """Base of every error turning_force raises on purpose."""


class ConfigError(TurningForceError, ValueError):
    """A setting is missing, malformed or out of range.

    The message names the key (``section.name``) and the bad value, and says what was expected.
    """
