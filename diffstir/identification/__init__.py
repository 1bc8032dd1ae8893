"""Identify a fluid from a stirring recording: fit each law through the simulator (``diffstir.fitting``),
quantify, select, report. ``identify(recording, config=...)`` returns an ``Identification``; ``write_report(result,
out)`` writes report.json, report.md and plots. See docs/identification.md.
"""

from .pipeline import DEFAULT_MODELS, identify
from .report import write_report

__all__ = ["DEFAULT_MODELS", "identify", "write_report"]
