"""Errors of the application layer, under `handeye.calib.errors.HandeyeError`."""

from handeye.calib.errors import HandeyeError, ParameterError


class ConfigError(ParameterError):
    """A field of a configuration file (or a command-line override) is missing or invalid (the message names it)."""


class SessionError(HandeyeError):
    """A recorded session or an imported file is missing, unreadable, or of an unknown version."""


class OutageError(HandeyeError):
    """A device stayed away longer than ``reconnect.max_outage_s``, or the run was stopped during its outage."""


class MonitorError(HandeyeError):
    """A monitoring run ended on an unexpected error at a sample (recorded in its session; a service restarts it)."""
