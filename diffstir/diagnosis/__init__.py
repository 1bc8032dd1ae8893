"""Diagnose a fit that stays poor: locate the mismatch, name the missing physics, model it, show the fit improve.

``diagnose(recording, identification, config=...)`` returns a ``Diagnosis``; ``write_diagnosis(diag, out)`` writes
diagnosis.json, diagnosis.md and plots; ``needs_diagnosis(identification)`` tells whether a fit's residual is
larger than the noise and structured. See docs/diagnosis.md.
"""

from .base import needs_diagnosis
from .candidates import CANDIDATES
from .pipeline import Diagnosis, diagnose
from .report import write_diagnosis

__all__ = ["CANDIDATES", "Diagnosis", "diagnose", "needs_diagnosis", "write_diagnosis"]
