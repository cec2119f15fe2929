"""Error and warning types.

Every error a user can cause is a :class:`DitherlabError` whose message is one sentence naming
the file, the column or key, the value and what was expected. The CLI prints that sentence on
stderr and exits with status 2; the library never prints.
"""

from __future__ import annotations


def where_prefix(where: object | None) -> str:
    """``"<where>: "`` for the start of an error message, or ``""`` when the place is unknown."""
    return f"{where}: " if where else ""


def one_line(exc: BaseException) -> str:
    """A library's error message on one line (pyarrow's and pandas' can span several), or the
    exception's type name when it has no message (MemoryError)."""
    return " ".join(str(exc).split()) or type(exc).__name__


class DitherlabError(Exception):
    """Base of all errors caused by bad input or bad options (CLI exit status 2)."""


class RecordingError(DitherlabError):
    """A recording (file or in-memory table) violates the recording contract."""


class FormatError(RecordingError):
    """A file cannot be read: truncated, corrupt, wrong format, missing topics."""


class RobotError(DitherlabError):
    """An unknown robot name, a URDF that does not parse, a joint count that does not match."""


class ModelError(DitherlabError):
    """A torque-model file that is invalid (inverted bands, non-positive noise, unknown effect)."""


class ConfigError(DitherlabError):
    """A bad option or configuration value (unknown scenario, negative magnitude, unknown key)."""


class DitherlabWarning(UserWarning):
    """Suspicious but legal input, e.g. joint angles far beyond the limits (degrees?)."""
