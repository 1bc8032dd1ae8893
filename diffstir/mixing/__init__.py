"""Mixing analysis: the apparent viscosity of two fluids being stirred together, over time, its plateau and how it
compares with the Lederer-Roegiers blending rule (``rheology.blending``; the paper's Fig. 6). See docs/mixing.md.
"""

from .analysis import Mixing, analyse_mixing
from .settings import MixingSettings
from .track import Approach, fit_approach, time_windows, track_viscosity

__all__ = ["Approach", "Mixing", "MixingSettings", "analyse_mixing", "fit_approach", "time_windows", "track_viscosity"]
