"""A recording's content digest: what ties a fit's checkpoint to the recording it fitted.

The digest is the SHA-256 of the recording's content as the fitter reads it: its rig, sensor and density block
(the metadata as sorted JSON) and its columns (each column's name and its float64 little-endian bytes), with the
rig clock's ``time_origin`` [s]. Its name, its path and the text layout of its files (separators, number format,
line endings, a byte-order mark) do not enter: the same recording moved, renamed or re-saved keeps its digest, and
a recording whose numbers differ in any bit does not.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json

import numpy as np

from .format import OPTIONAL_COLUMNS, REQUIRED_COLUMNS, Recording


def recording_digest(recording: Recording) -> str:
    """The SHA-256 of ``recording``'s content (module docstring), as 64 hex digits."""
    meta = {"cup": dataclasses.asdict(recording.cup), "rod": dataclasses.asdict(recording.rod),
            "sensor": dataclasses.asdict(recording.sensor),
            "density": None if recording.density is None else dataclasses.asdict(recording.density),
            "time_origin": float(recording.time_origin)}
    digest = hashlib.sha256(json.dumps(meta, sort_keys=True, default=_plain).encode("utf-8"))
    for name in REQUIRED_COLUMNS + OPTIONAL_COLUMNS:
        column = getattr(recording, name)
        if column is not None:
            digest.update(name.encode("utf-8") + b"\0")
            digest.update(np.ascontiguousarray(column, dtype="<f8").tobytes())
    return digest.hexdigest()


def _plain(value):
    """A JSON value for what ``json`` cannot write itself (numpy scalars and arrays, tuples nested in them)."""
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    raise TypeError(f"recording metadata: {type(value).__name__} is not plain data")
