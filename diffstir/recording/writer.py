"""Streaming a recording to disk row by row, so that a crash at any moment leaves a loadable partial recording.

recording.yaml says ``complete: false`` (``partial_reason: in progress``) from the start and is rewritten
atomically to ``complete: true`` by a clean close(). append() flushes and fsyncs stir.csv once ``flush_interval``
seconds of wall time have passed since the last flush, so a crash loses at most the rows appended within
``flush_interval`` seconds after the last flush (flush() forces one); a line cut short is dropped on load.
"""

from __future__ import annotations

import math
import os
import re
import shutil
import time
import weakref
from pathlib import Path

from diffstir.recording.errors import RecordingError
from diffstir.recording.files import (
    csv_header, format_value, fresh_dir, fsync_dir, metadata_dict, warn, write_metadata,
)
from diffstir.recording.format import (
    COLUMN_UNITS, CSV_NAME, REQUIRED_COLUMNS, YAML_NAME, CupGeometry, DensityMeasurement, RodGeometry, SensorSpec,
)
from diffstir.recording.validate import check_metadata

_COLUMN_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_]*\Z")
IN_PROGRESS = "in progress"
ABANDONED = "the writer was never closed (abandoned, or the program exited without close())"


class _Sink:
    """The open stir.csv and the metadata of a RecordingWriter, apart from it so an abandoned writer can be closed."""

    def __init__(self, path: Path, meta: dict, columns: list[str], flush_interval: float) -> None:
        self.path = path
        self.meta = meta
        self.columns = columns
        self.flush_interval = flush_interval
        self.rows_written = 0
        self.rows_flushed = 0
        self.last_t = -math.inf
        self.file = open(path / CSV_NAME, "a", encoding="utf-8", newline="")
        self.last_flush = time.monotonic()

    def write_meta(self, complete: bool, reason: str | None) -> None:
        write_metadata(self.path, metadata_dict(**self.meta, complete=complete, partial_reason=reason,
                                                where=str(self.path / YAML_NAME)))

    def write_row(self, values: list[float]) -> None:
        self.file.write(",".join(format_value(v) for v in values) + "\n")
        self.rows_written += 1
        self.last_t = values[0]
        if time.monotonic() - self.last_flush >= self.flush_interval:
            self.flush()

    def flush(self) -> None:
        self.file.flush()
        os.fsync(self.file.fileno())
        self.rows_flushed = self.rows_written
        self.last_flush = time.monotonic()

    def close(self, complete: bool, reason: str | None) -> None:
        if self.file.closed:
            return
        self.flush()
        self.file.close()
        self.write_meta(complete, reason)


class RecordingWriter:
    """Write a recording row by row (robot recorder, virtual lab).

    ``path`` must not exist: a writer never overwrites. ``optional_columns`` names the columns after t, x, y,
    force, in order (z, force_x, force_y, raw, or new names, which readers keep as unknown columns); append()
    takes them as keywords. Used as a context manager, an exception inside ``with`` closes the recording with
    complete=False and reason=repr(exc), then propagates. A writer dropped without close() (or left open at
    interpreter exit) is flushed and marked partial; after a hard kill, rows up to the last flush survive.
    """

    def __init__(self, path: str | Path, *, cup: CupGeometry, rod: RodGeometry, sensor: SensorSpec,
                 density: DensityMeasurement | None = None, name: str | None = None, fluid: str | None = None,
                 temperature: float | None = None, optional_columns: tuple[str, ...] = (),
                 flush_interval: float = 1.0, extra_meta: dict | None = None) -> None:
        path = Path(path)
        for message in check_metadata(cup, rod, sensor, density, temperature, str(path / YAML_NAME)):
            warn(message)
        columns = list(REQUIRED_COLUMNS) + list(optional_columns)
        for column in optional_columns:
            if not _COLUMN_NAME.match(column) or columns.count(column) > 1:
                raise RecordingError(f"{path / CSV_NAME}: optional column name {column!r} is repeated, is a "
                                     f"required column, or is not an identifier ([A-Za-z_][A-Za-z0-9_]*)")
        if not (math.isfinite(flush_interval) and flush_interval >= 0):
            raise RecordingError(f"{path}: flush_interval = {flush_interval!r}; expected a non-negative time in s")
        if path.exists() or path.is_symlink():
            raise FileExistsError(f"{path}: already exists; a RecordingWriter never overwrites")
        meta = dict(cup=cup, rod=rod, sensor=sensor, density=density, name=name, fluid=fluid,
                    temperature=temperature, extra_meta=dict(extra_meta or {}))

        # Create both files in a temporary directory and rename it into place: path is a recording or absent.
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = fresh_dir(path.parent, path.name, ".tmp")
        try:
            with open(tmp / CSV_NAME, "w", encoding="utf-8", newline="") as f:
                f.write(csv_header(columns))
                f.flush()
                os.fsync(f.fileno())
            write_metadata(tmp, metadata_dict(**meta, complete=False, partial_reason=IN_PROGRESS,
                                              where=str(path / YAML_NAME)))
            os.rename(tmp, path)
            fsync_dir(path.parent)
        finally:
            if tmp.exists():
                shutil.rmtree(tmp, ignore_errors=True)
        self._sink = _Sink(path, meta, columns, flush_interval)
        self._finalizer = weakref.finalize(self, self._sink.close, False, ABANDONED)

    @property
    def path(self) -> Path:
        """The recording directory."""
        return self._sink.path

    @property
    def rows_written(self) -> int:
        """Rows handed to append()."""
        return self._sink.rows_written

    @property
    def rows_flushed(self) -> int:
        """Rows fsynced to disk: they survive a crash."""
        return self._sink.rows_flushed

    @property
    def closed(self) -> bool:
        """Whether close() has run."""
        return self._sink.file.closed

    def append(self, t: float, x: float, y: float, force: float, **optional: float) -> None:
        """Append one row: time t [s], rod axis x, y [m], sensor ``force`` [N], and every optional column.

        Raises RecordingError, writing nothing, for a missing or unknown column, a non-numeric or non-finite
        value in a known column, or a t that does not increase.
        """
        sink = self._sink
        where = sink.path / CSV_NAME
        if sink.file.closed:
            raise RecordingError(f"{where}: the writer is closed; no more rows can be appended")
        names = sink.columns[len(REQUIRED_COLUMNS):]
        if set(optional) != set(names):
            raise RecordingError(f"{where}: append() got optional columns {sorted(optional)}; this writer's are "
                                 f"{names}")
        row = dict(t=t, x=x, y=y, force=force, **optional)
        values = []
        for column in sink.columns:
            try:
                value = float(row[column])
            except (TypeError, ValueError):
                raise RecordingError(f"{where}: column '{column}' = {row[column]!r} at data row "
                                     f"{sink.rows_written + 1} is not a number; expected "
                                     f"{COLUMN_UNITS.get(column, 'a number')}") from None
            if column in COLUMN_UNITS and not math.isfinite(value):
                raise RecordingError(f"{where}: column '{column}' = {value} at data row {sink.rows_written + 1} "
                                     f"(t = {t} s); expected a finite value in {COLUMN_UNITS[column]}")
            values.append(value)
        if not values[0] > sink.last_t:
            raise RecordingError(f"{where}: column 't' = {values[0]!r} s at data row {sink.rows_written + 1} does "
                                 f"not increase on the previous {sink.last_t!r} s; expected strictly increasing s")
        sink.write_row(values)

    def flush(self) -> None:
        """Flush and fsync stir.csv now: every row appended so far survives a crash."""
        if self._sink.file.closed:
            raise RecordingError(f"{self.path / CSV_NAME}: the writer is closed")
        self._sink.flush()

    def set_density(self, m: DensityMeasurement) -> None:
        """Record the Archimedes measurement; rewrites recording.yaml atomically."""
        sink = self._sink
        if sink.file.closed:
            raise RecordingError(f"{sink.path / YAML_NAME}: the writer is closed; the density can no longer be set")
        for message in check_metadata(sink.meta["cup"], sink.meta["rod"], sink.meta["sensor"], m,
                                      sink.meta["temperature"], str(sink.path / YAML_NAME)):
            warn(message)
        sink.meta["density"] = m
        sink.write_meta(False, IN_PROGRESS)

    def close(self, *, complete: bool = True, reason: str | None = None) -> Path:
        """Flush, fsync and close stir.csv, then mark recording.yaml complete (or partial, with ``reason``).

        Closing again does nothing. Returns the recording directory.
        """
        if complete and reason is not None:
            raise RecordingError(f"{self.path}: close(reason={reason!r}) is only for complete=False")
        self._finalizer.detach()
        self._sink.close(complete, None if complete else (reason or "closed as partial"))
        return self.path

    def __enter__(self) -> RecordingWriter:
        return self

    def __exit__(self, exc_type, exc, tb) -> bool:
        if exc is None:
            self.close()
        else:
            self.close(complete=False, reason=repr(exc))
        return False
