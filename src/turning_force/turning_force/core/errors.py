"""The exceptions of turning_force: one small family, so callers catch what they mean."""

from __future__ import annotations

__all__ = ['ConfigError', 'NoCutError', 'TurningForceError']


class TurningForceError(Exception):
    """Base of every error turning_force raises on purpose."""


class NoCutError(TurningForceError, ValueError):
    """A run in which the tool never cut (an air cut): there is no force to score."""


class ConfigError(TurningForceError, ValueError):
    """A setting is missing, malformed or out of range.

    The message names the key (``section.name``) and the bad value, and says what was expected.
    """
