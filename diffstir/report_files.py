"""The JSON and markdown files every report writes (identification, behaviour, mixing, diagnosis, lab truth), how
their values and 95 % intervals are printed, and ``Report``, the one way a result writes itself."""

from __future__ import annotations

import json
import os
from abc import ABC, abstractmethod
from collections.abc import Mapping
from pathlib import Path
from typing import ClassVar

import numpy as np


class Report(ABC):
    """A result that reports itself, the same way for every analysis: ``summary()`` is its JSON (SI units),
    ``report()`` its markdown, ``plots(out)`` writes its figures, ``write(out)`` all three, and a notebook shows
    ``report()`` (``_repr_html_``). A subclass defines ``summary``, ``report`` and, where it draws, ``plots``;
    ``stem`` names its files (``<stem>.json``, ``<stem>.md``)."""

    stem: ClassVar[str] = "report"

    @abstractmethod
    def summary(self) -> dict:
        """The result as JSON-serialisable data, SI units."""

    @abstractmethod
    def report(self) -> str:
        """The result as markdown."""

    def plots(self, out: Path) -> dict[str, Path]:
        """Write the result's figures into ``out``; return their paths by name (none by default)."""
        return {}

    def write(self, out: str | Path) -> dict[str, Path]:
        """Write ``<stem>.json``, ``<stem>.md`` and the plots into ``out`` (created); return the paths by name
        (``json``, ``md`` and each plot's)."""
        paths = write_summary(out, self.stem, self.summary(), self.report())
        paths.update(self.plots(Path(out)))
        return paths

    def _repr_html_(self) -> str:
        import markdown

        return markdown.markdown(self.report(), extensions=["tables"])


def json_default(value):
    """``json.dumps``'s ``default`` for the numpy scalars and arrays a summary may hold."""
    if isinstance(value, (np.floating, np.integer)):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    raise TypeError(f"{type(value).__name__} is not JSON-serialisable")


def finite_or_none(value: float) -> float | None:
    """``value`` for a JSON summary: None where it is not finite (an interval's open end, an unresolved slope)."""
    return value if np.isfinite(value) else None


def to_json(summary: Mapping) -> str:
    """``summary`` as indented JSON text with a final newline."""
    return json.dumps(summary, indent=2, default=json_default) + "\n"


def write_summary(out: str | Path, stem: str, summary: Mapping, markdown: str | None = None) -> dict[str, Path]:
    """Write ``out``/``stem``.json (and ``stem``.md when ``markdown`` is given), creating ``out``; return the
    paths under the keys ``json`` and ``md``."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    paths = {"json": out / f"{stem}.json"}
    paths["json"].write_text(to_json(summary))
    if markdown is not None:
        paths["md"] = out / f"{stem}.md"
        paths["md"].write_text(markdown)
    return paths


def write_text_atomically(path: str | Path, text: str) -> None:
    """Replace ``path`` by ``text`` (UTF-8) in one step: a temporary file in the same folder, fsync, os.replace; a
    failed or interrupted write leaves the old file as it was."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        with open(tmp, "w", encoding="utf-8") as file:
            file.write(text)
            file.flush()
            os.fsync(file.fileno())
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


def interval_summary(ci95: dict[str, tuple[float, float]], identifiable: dict[str, bool]) -> dict:
    """The 95 % intervals of a report, SI by name: [lower, upper] (an open end as null) for an identifiable
    parameter, null for one the recording does not determine (its interval's ends say nothing)."""
    return {k: [finite_or_none(lo), finite_or_none(hi)] if identifiable[k] else None for k, (lo, hi) in ci95.items()}


def format_param(name: str, value: float, unit: str, interval: list | None) -> str:
    """``name = value unit [lower, upper]`` for a table (no unit for a dimensionless one), or "not identifiable"
    in place of the interval."""
    return f"{name} = {value:.4g}{'' if unit == '1' else ' ' + unit} {format_interval(interval)}"


def format_interval(interval: list | None) -> str:
    """A report's 95 % interval for a table: [lower, upper], or "not identifiable" where it is null."""
    return "not identifiable" if interval is None else f"[{format_bound(interval[0])}, {format_bound(interval[1])}]"


def format_bound(value) -> str:
    """An interval end for a table: 3 significant digits, or inf when it is unbounded (None)."""
    return "inf" if value is None else f"{value:.3g}"
