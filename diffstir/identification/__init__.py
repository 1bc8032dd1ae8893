"""Identify a fluid from a stirring recording: fit each law through the simulator (``diffstir.fitting``),
quantify, select, report. ``identify(recording, config=...)`` returns an ``Identification``, whose ``write(out)``
writes report.json, report.md and plots. See docs/identification.md.
"""

from .pipeline import DEFAULT_MODELS, identify

__all__ = ["DEFAULT_MODELS", "identify"]
