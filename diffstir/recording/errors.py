"""Errors and warnings raised for recordings that do not follow the format."""

from __future__ import annotations

from ..errors import DiffstirError


class RecordingError(DiffstirError, ValueError):
    """A recording (or a measurement in one) breaks the format or is physically impossible.

    The message names the file, the field or column, the offending value (with row and time for columns)
    and the expected unit.
    """


class RecordingNotFound(RecordingError, FileNotFoundError):
    """A recording path that does not exist or is not a directory."""


class RecordingWarning(UserWarning):
    """A recording is readable but something in it deserves attention (unknown fields, partial data, ...)."""
