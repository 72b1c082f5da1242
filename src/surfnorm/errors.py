"""Exceptions raised by surfnorm.

Every error that bad input can cause subclasses a built-in exception, so that
``except ValueError`` catches a wrong shape or option as users expect, and the
CLI can turn all of them into a one-line message with exit code 2.
"""

from __future__ import annotations

__all__ = ["SurfnormError", "InputError", "MissingDependencyError", "DataFileError"]


class SurfnormError(Exception):
    """Base class of every exception surfnorm raises on purpose."""


class InputError(SurfnormError, ValueError):
    """An argument has the wrong type, shape, dtype or value.

    The message names the argument, what was expected and what was received.
    """


class DataFileError(SurfnormError, ValueError):
    """A file could not be read as what it was supposed to be (corrupt, truncated, wrong format), or written."""


class MissingDependencyError(SurfnormError, ImportError):
    """An optional dependency (an extra such as ``surfnorm[torch]``) is not installed."""
