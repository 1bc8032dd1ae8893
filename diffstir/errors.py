"""The errors a user's input can cause. Each message is one line that names the file or setting, the field and the
expected unit; the command-line apps print it without a traceback and exit with status 2."""

from __future__ import annotations


class DiffstirError(Exception):
    """An input the user can correct: a recording, a setting, an output folder."""


class ConfigError(DiffstirError, ValueError):
    """A setting outside its range or its choices; the message lists the valid ones."""


class OutputError(DiffstirError):
    """An output that would overwrite something recorded or shipped, or belongs to another input."""
