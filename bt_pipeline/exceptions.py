"""The one exception hierarchy of bt.

Every error bt raises on purpose derives from :class:`BtError`, so a command-line front end can
catch it and print its message alone. Messages say what was wrong and what would be valid.
"""

from __future__ import annotations


class BtError(Exception):
    """Root of every error bt raises on purpose."""


class ConfigError(BtError, ValueError):
    """A setting or argument is out of range or of the wrong kind."""


class UnknownTaskError(ConfigError):
    """A task name that is not valid, or a task without a built-in guide where one is needed."""


class RecordingError(BtError):
    """A recording file is missing, unreadable or does not follow format v1."""


class DemoError(BtError, ValueError):
    """A demonstration cannot be used: too short, degenerate, non-periodic or not finite."""


class SessionLostError(BtError):
    """A worker process (a teleop tab's simulation) died or stopped answering."""


class SessionBusyError(BtError):
    """A worker process did not answer a quick call in time but still runs (a busy machine);
    its late answer is dropped when it comes."""
