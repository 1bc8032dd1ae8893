"""Diagnose a fit that stays poor: locate the mismatch, name the missing physics, model it, show the fit improve.

``diagnose(recording, identification, config=..., settings=DiagnosisSettings(...))`` returns a ``Diagnosis``, whose
``write(out)`` writes diagnosis.json, diagnosis.md and plots; ``needs_diagnosis(identification)`` tells whether a
fit's residual is larger than the noise and structured. See docs/diagnosis.md.
"""

from .base import needs_diagnosis
from .candidates import CANDIDATES
from .pipeline import Diagnosis, diagnose
from .settings import DiagnosisSettings

__all__ = ["CANDIDATES", "Diagnosis", "DiagnosisSettings", "diagnose", "needs_diagnosis"]
