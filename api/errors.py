"""Exceptions of drivetrain-id.

Every error a user can cause (a bad file, a bad option, a recording that does not hold what a
command needs) is raised as a subclass of :class:`DtidError`. The command line turns these into a
one-line ``error: ...`` message and a non-zero exit; anything else is a bug and keeps its traceback.
Each subclass also inherits the built-in exception it resembles, so callers may catch either.
"""


class DtidError(Exception):
    """Root of every error caused by user input rather than by a bug."""


class ConfigError(DtidError, ValueError):
    """A parameter set, signal map, test definition or option is invalid."""


class DbcError(DtidError, ValueError):
    """A CAN database cannot be read, or lacks what the signal map names."""


class RecordingError(DtidError, OSError):
    """A CAN recording cannot be read or written, or holds too little to work on."""


class AnalysisError(DtidError, ValueError):
    """The data cannot support the analysis asked for (no chirp, chirp too short, ...)."""
